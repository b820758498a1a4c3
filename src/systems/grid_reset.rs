//! Stage 1, grid reset: `m_i = 0`, `(mv)_i = 0`, `v_i = 0` for every node.
//!
//! Reads nothing; writes `Grid`.

use crate::components::Grid;
use bevy_ecs::prelude::*;
use glam::DVec3;
use rayon::prelude::*;

pub fn grid_reset(mut grid: ResMut<Grid>) {
    let g = &mut *grid;
    g.mass.par_iter_mut().for_each(|m| *m = 0.0);
    g.momentum.par_iter_mut().for_each(|p| *p = DVec3::ZERO);
    g.velocity.par_iter_mut().for_each(|v| *v = DVec3::ZERO);
}
