//! Adjoint of stage 3, the SVD (`crate::math::svd::svd3_adj`): `F̄_tmp += svd_adj(Ū, σ̄, V̄)`.
//! Exact for distinct singular values; for `|σ_i² − σ_j²| < SVD_ADJ_GAP` the rotational terms
//! are damped (the documented bias, which vanishes for isotropic materials). Consumes
//! `Ū, σ̄, V̄`.

use crate::adjoint::NonFiniteSeen;
use crate::components::*;
use crate::math::svd::{svd3_adj, Svd3};
use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3};
use rayon::prelude::*;

pub fn svd_adjoint(
    seen: Option<Res<NonFiniteSeen>>,
    mut bodies: Query<(&SvdFactors, &mut SvdFactorsAdj, &mut TrialDeformationAdj)>,
) {
    let seen = seen.as_deref();
    for (svd, mut g, mut g_ft) in &mut bodies {
        let g = &mut *g;
        g_ft.0
            .par_iter_mut()
            .zip(
                g.u.par_iter_mut()
                    .zip(g.s.par_iter_mut().zip(g.v.par_iter_mut())),
            )
            .enumerate()
            .for_each(|(i, (gft, (gu, (gs, gv))))| {
                let d = Svd3 {
                    u: svd.u[i],
                    s: svd.s[i],
                    v: svd.v[i],
                };
                *gft += svd3_adj(&d, *gu, *gs, *gv);
                NonFiniteSeen::check(seen, gft.is_finite());
                *gu = DMat3::ZERO;
                *gs = DVec3::ZERO;
                *gv = DMat3::ZERO;
            });
    }
}
