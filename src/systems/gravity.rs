//! Stage 7, gravity: `v_i += Δt_sub·g` on every non-empty node (in the active part of the grid).
//!
//! Reads `SimParams`; writes `Grid::velocity`.

use crate::components::*;
use bevy_ecs::prelude::*;

pub fn gravity(params: Res<SimParams>, mut grid: ResMut<Grid>) {
    let dv = params.gravity * params.dt_sub;
    let m_min = params.empty_node_mass;
    let g = &mut *grid;
    let nodes = &g.nodes;
    for_active_nodes(&mut g.velocity, g.n, g.active.as_ref(), |idx, v| {
        if nodes[idx].mass > m_min {
            *v += dv;
        }
    });
}
