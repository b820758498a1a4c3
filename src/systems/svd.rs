//! Stage 3, SVD: `F_tmp = U·diag(σ)·Vᵀ` per particle (`crate::math::svd::svd3`).
//!
//! Reads `TrialDeformation`; writes `SvdFactors`.

use crate::components::{SvdFactors, TrialDeformation};
use crate::math::svd::svd3;
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
                let d = svd3(*ft);
                *u = d.u;
                *s = d.s;
                *v = d.v;
            });
    }
}
