//! Adjoint of stage 11, `x′ = clamp(x + Δt·v)`: `x̄` passes through and `v̄ += Δt·x̄′`, per axis,
//! except where the safe-region clamp acted, where both are zero (one-sided: the clamp is a
//! kink, reached only by particles a scene's walls failed to stop). Exact elsewhere.

use crate::adjoint::NonFiniteSeen;
use crate::components::*;
use bevy_ecs::prelude::*;
use glam::DVec3;
use rayon::prelude::*;

pub fn advect_adjoint(
    params: Res<SimParams>,
    grid: Res<Grid>,
    seen: Option<Res<NonFiniteSeen>>,
    mut bodies: Query<(&Position, &Velocity, &mut PositionAdj, &mut VelocityAdj)>,
) {
    let seen = seen.as_deref();
    let dt = params.dt_sub;
    let lo = grid.origin + DVec3::splat(grid.dx);
    let hi = grid.extent_max() - DVec3::splat(grid.dx);
    for (x, v, mut gx, mut gv) in &mut bodies {
        gx.0.par_iter_mut()
            .zip(gv.0.par_iter_mut())
            .enumerate()
            .for_each(|(i, (gx, gv))| {
                let y = x.0[i] + v.0[i] * dt;
                let free = DVec3::select(y.cmpgt(lo) & y.cmplt(hi), DVec3::ONE, DVec3::ZERO);
                *gx *= free;
                *gv += *gx * dt;
                NonFiniteSeen::check(seen, gx.is_finite() && gv.is_finite());
            });
    }
}
