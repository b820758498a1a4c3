//! Stage 3, SVD: `F_tmp = U·diag(σ)·Vᵀ` per particle (`crate::math::svd::svd3_warm`).
//!
//! The Jacobi iteration starts from the particle's `V` of the previous substep (`F` changes by
//! `Δt·C·F` per substep), which saves most sweeps; the decomposition does not depend on it.
//! Particles go through in groups of `LANES` (`svd3_warm_lanes`, bitwise equal to one at a
//! time), or of `LANES_F32` in f32 where the scene asks for it (`simulation.svd: F32`,
//! `svd3_warm_lanes_f32`); each particle's factors depend on its own `F_tmp` and `V` only, so
//! the grouping, and the thread count, change no bit.
//!
//! Reads `TrialDeformation`, `SimParams`; writes `SvdFactors`.

use crate::components::{Precision, SimParams, SvdFactors, TrialDeformation};
use crate::math::svd::{svd3_warm_group, svd3_warm_lanes, svd3_warm_lanes_f32, Kernel};
use bevy_ecs::prelude::*;
use glam::DMat3;
use rayon::prelude::*;

pub fn svd(params: Res<SimParams>, mut bodies: Query<(&TrialDeformation, &mut SvdFactors)>) {
    for (ft, mut f) in &mut bodies {
        match params.svd {
            Precision::F64 => decompose(&ft.0, &mut f, svd3_warm_lanes),
            Precision::F32 => decompose(&ft.0, &mut f, svd3_warm_lanes_f32),
        }
    }
}

/// Decomposes `ft` in groups of `N` through `kernel`.
fn decompose<const N: usize>(ft: &[DMat3], f: &mut SvdFactors, kernel: Kernel<N>) {
    ft.par_chunks(N)
        .zip(f.u.par_chunks_mut(N))
        .zip(f.s.par_chunks_mut(N).zip(f.v.par_chunks_mut(N)))
        .for_each(|((ft, u), (s, v))| {
            // The warm starts are read in place, before the group's results overwrite them.
            for (l, d) in svd3_warm_group(kernel, ft, v).enumerate() {
                (u[l], s[l], v[l]) = (d.u, d.s, d.v);
            }
        });
}
