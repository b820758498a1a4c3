//! Stage 3, SVD: `F_tmp = U·diag(σ)·Vᵀ` per particle (`crate::math::svd::svd3_warm`).
//!
//! The Jacobi iteration starts from the particle's `V` of the previous substep (`F` changes by
//! `Δt·C·F` per substep), which saves most sweeps; the decomposition does not depend on it.
//! Particles go through in groups of `LANES` (`svd3_warm_group`: the lane kernel, bitwise equal
//! to one at a time; the last short group one at a time).
//!
//! Reads `TrialDeformation`; writes `SvdFactors`.

use crate::components::{SvdFactors, TrialDeformation};
use crate::math::svd::{svd3_warm_group, LANES};
use bevy_ecs::prelude::*;
use glam::DMat3;
use rayon::prelude::*;

pub fn svd(mut bodies: Query<(&TrialDeformation, &mut SvdFactors)>) {
    for (ft, mut f) in &mut bodies {
        let f = &mut *f;
        ft.0.par_chunks(LANES)
            .zip(f.u.par_chunks_mut(LANES))
            .zip(f.s.par_chunks_mut(LANES).zip(f.v.par_chunks_mut(LANES)))
            .for_each(|((ft, u), (s, v))| {
                // The warm starts are read before the group's results overwrite them.
                let mut v0 = [DMat3::IDENTITY; LANES];
                v0[..v.len()].copy_from_slice(v);
                svd3_warm_group(ft, &v0[..v.len()], |l, d| {
                    (u[l], s[l], v[l]) = (d.u, d.s, d.v);
                });
            });
    }
}
