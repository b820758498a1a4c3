//! Adjoint of stage 2, `F_tmp = (I + Δt·C)·F`:
//!
//! ```text
//! C̄ += Δt·F̄_tmp·Fᵀ,    F̄ += (I + Δt·C)ᵀ·F̄_tmp
//! ```
//!
//! with `C`, `F` the substep-start values. Exact. Consumes `F̄_tmp`.

use crate::adjoint::NonFiniteSeen;
use crate::components::*;
use bevy_ecs::prelude::*;
use glam::DMat3;
use rayon::prelude::*;

/// Adjoint of `trial_deformation`: returns `(C̄, F̄)` contributions.
#[inline(always)]
pub fn trial_deformation_adj(c: DMat3, f: DMat3, dt: f64, g_ft: DMat3) -> (DMat3, DMat3) {
    (
        g_ft * f.transpose() * dt,
        (DMat3::IDENTITY + c * dt).transpose() * g_ft,
    )
}

pub fn deformation_update_adjoint(
    params: Res<SimParams>,
    seen: Option<Res<NonFiniteSeen>>,
    mut bodies: Query<(
        &SubstepStart,
        &mut TrialDeformationAdj,
        &mut AffineVelocityAdj,
        &mut DeformationGradientAdj,
    )>,
) {
    let seen = seen.as_deref();
    let dt = params.dt_sub;
    for (start, mut g_ft, mut g_c, mut g_f) in &mut bodies {
        g_c.0
            .par_iter_mut()
            .zip(g_f.0.par_iter_mut())
            .zip(g_ft.0.par_iter_mut())
            .enumerate()
            .for_each(|(i, ((gc, gf), gft))| {
                let (dc, df) = trial_deformation_adj(start.c[i], start.f[i], dt, *gft);
                *gc += dc;
                *gf += df;
                NonFiniteSeen::check(seen, gc.is_finite() && gf.is_finite());
                *gft = DMat3::ZERO;
            });
    }
}
