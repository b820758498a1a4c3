//! Adjoint of stage 1, grid reset. The forward zeroes the grid, so no gradient flows through
//! it; the adjoint zeroes the grid velocity adjoint so the previous substep starts clean. Exact.
//! The mass and momentum adjoints need no reset: the P2G adjoint sets them from the velocity
//! adjoint each substep before anything reads them.

use crate::components::GridAdj;
use bevy_ecs::prelude::*;
use glam::DVec3;
use rayon::prelude::*;

pub fn grid_reset_adjoint(mut adj: ResMut<GridAdj>) {
    adj.velocity.par_iter_mut().for_each(|v| *v = DVec3::ZERO);
}
