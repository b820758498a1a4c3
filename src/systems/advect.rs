//! Stage 11, advect: `x_p += Δt_sub·v_p`.
//!
//! Positions are then kept inside the grid's safe region (`[1, n−2]` cells along each axis, so
//! that every stencil fits in the grid). The domain walls stop particles well before that; the
//! clamp only bounds memory access for a scene with walls thinner than its particle speeds.
//! Reads `Velocity`; writes `Position`; reports non-finite positions to `Health`.

use crate::components::*;
use crate::systems::FiniteWatch;
use bevy_ecs::prelude::*;
use glam::DVec3;
use rayon::prelude::*;

pub fn advect(
    params: Res<SimParams>,
    grid: Res<Grid>,
    mut health: ResMut<Health>,
    mut bodies: Query<(&Body, &mut Position, &Velocity)>,
) {
    let dt = params.dt_sub;
    let lo = grid.origin + DVec3::splat(grid.dx);
    let hi = grid.extent_max() - DVec3::splat(grid.dx);
    for (body, mut x, v) in &mut bodies {
        let watch = FiniteWatch::default();
        x.0.par_iter_mut().zip(v.0.par_iter()).for_each(|(x, v)| {
            let y = *x + *v * dt;
            // A non-finite value must survive the clamp (f64::max would swallow a NaN).
            let finite = y.is_finite();
            *x = if finite { y.clamp(lo, hi) } else { y };
            watch.check(finite);
        });
        if let Some(i) = watch.first_nonfinite_vec(&x.0) {
            health.report(Fault::particle("advect", "x", &body.name, i, x.0[i]));
        }
    }
}
