//! Stage 1, grid reset: `m_i = 0`, `(mv)_i = 0` for every node. The velocity is not reset:
//! P2G, which always follows, writes every node's `v_i` (`(mv)_i/m_i`, or 0 on an empty node)
//! without reading it.
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
}
