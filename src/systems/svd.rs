//! Stage 3, SVD: `F_tmp = U·diag(σ)·Vᵀ` per particle (`crate::math::svd::svd3_warm`).
//!
//! The Jacobi iteration starts from the particle's `V` of the previous substep (`F` changes by
//! `Δt·C·F` per substep), which saves most sweeps; the decomposition does not depend on it.
//! Particles go through in groups of `LANES` (`svd3_warm_lanes`, bitwise equal to one at a
//! time), the last short group one at a time.
//!
//! Reads `TrialDeformation`; writes `SvdFactors`.

use crate::components::{SvdFactors, TrialDeformation};
use crate::math::svd::{svd3_warm, svd3_warm_lanes, LANES};
use bevy_ecs::prelude::*;
use rayon::prelude::*;

pub fn svd(mut bodies: Query<(&TrialDeformation, &mut SvdFactors)>) {
    for (ft, mut f) in &mut bodies {
        let f = &mut *f;
        ft.0.par_chunks(LANES)
            .zip(f.u.par_chunks_mut(LANES))
            .zip(f.s.par_chunks_mut(LANES).zip(f.v.par_chunks_mut(LANES)))
            .for_each(|((ft, u), (s, v))| match <&[_; LANES]>::try_from(ft) {
                Ok(ft4) => {
                    let v0: [_; LANES] = std::array::from_fn(|l| v[l]);
                    for (l, d) in svd3_warm_lanes(ft4, &v0).into_iter().enumerate() {
                        (u[l], s[l], v[l]) = (d.u, d.s, d.v);
                    }
                }
                Err(_) => {
                    for i in 0..ft.len() {
                        let d = svd3_warm(ft[i], v[i]);
                        (u[i], s[i], v[i]) = (d.u, d.s, d.v);
                    }
                }
            });
    }
}
