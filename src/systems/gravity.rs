//! Stage 7, gravity: `v_i += Δt_sub·g` on every non-empty node.
//!
//! Reads `SimParams`; writes `Grid::velocity`.

use crate::components::*;
use bevy_ecs::prelude::*;
use rayon::prelude::*;

pub fn gravity(params: Res<SimParams>, mut grid: ResMut<Grid>) {
    let dv = params.gravity * params.dt_sub;
    let m_min = params.empty_node_mass;
    let g = &mut *grid;
    g.velocity
        .par_iter_mut()
        .zip(g.mass.par_iter())
        .for_each(|(v, &m)| {
            if m > m_min {
                *v += dv;
            }
        });
}
