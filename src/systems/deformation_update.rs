//! Stage 2, deformation update: `F_tmp = (I + Δt_sub·C)·F`.
//!
//! Reads `AffineVelocity`, `DeformationGradient`; writes `TrialDeformation`.

use crate::components::{AffineVelocity, DeformationGradient, SimParams, TrialDeformation};
use bevy_ecs::prelude::*;
use glam::DMat3;
use rayon::prelude::*;

/// `F_tmp = (I + dt·C)·F`.
#[inline(always)]
pub fn trial_deformation(c: DMat3, f: DMat3, dt: f64) -> DMat3 {
    (DMat3::IDENTITY + c * dt) * f
}

pub fn deformation_update(
    params: Res<SimParams>,
    mut bodies: Query<(&AffineVelocity, &DeformationGradient, &mut TrialDeformation)>,
) {
    let dt = params.dt_sub;
    for (c, f, mut ft) in &mut bodies {
        ft.0.par_iter_mut()
            .zip(c.0.par_iter().zip(f.0.par_iter()))
            .for_each(|(ft, (c, f))| *ft = trial_deformation(*c, *f, dt));
    }
}
