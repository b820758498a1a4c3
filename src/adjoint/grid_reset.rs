//! Adjoint of stage 1, grid reset. The forward zeroes the grid, so no gradient flows through
//! it; the adjoint zeroes the grid adjoints so the previous substep starts clean. Exact.

use crate::components::GridAdj;
use bevy_ecs::prelude::*;
use glam::DVec3;
use rayon::prelude::*;

pub fn grid_reset_adjoint(mut adj: ResMut<GridAdj>) {
    let a = &mut *adj;
    a.mass.par_iter_mut().for_each(|m| *m = 0.0);
    a.momentum.par_iter_mut().for_each(|p| *p = DVec3::ZERO);
    a.velocity.par_iter_mut().for_each(|v| *v = DVec3::ZERO);
}
