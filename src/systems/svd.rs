//! Stage 3, SVD: `F_tmp = U·diag(σ)·Vᵀ` per particle (`crate::math::svd::svd3_warm`).
//!
//! The Jacobi iteration starts from the particle's `V` of the previous substep (`F` changes by
//! `Δt·C·F` per substep), which saves most sweeps; the decomposition does not depend on it.
//!
//! Reads `TrialDeformation`; writes `SvdFactors`.

use crate::components::{SvdFactors, TrialDeformation};
use crate::math::svd::svd3_warm;
use bevy_ecs::prelude::*;
use rayon::prelude::*;

pub fn svd(mut bodies: Query<(&TrialDeformation, &mut SvdFactors)>) {
    for (ft, mut f) in &mut bodies {
        let f = &mut *f;
        ft.0.par_iter()
            .zip(
                f.u.par_iter_mut()
                    .zip(f.s.par_iter_mut().zip(f.v.par_iter_mut())),
            )
            .for_each(|(ft, (u, (s, v)))| {
                let d = svd3_warm(*ft, *v);
                *u = d.u;
                *s = d.s;
                *v = d.v;
            });
    }
}
