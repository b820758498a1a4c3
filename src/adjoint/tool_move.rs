//! Adjoint of stage 6, tool move. With `u = (u_t, u_r)` the current step's control and
//! `a = u_r/N_sub`: `t′ = t + u_t/N_sub`, `R′ = exp(a)·R`, `v_lin = u_t/Δt`, `ω = u_r/Δt`.
//! With rotations as world-frame perturbations `δR = [δθ]×·R`,
//! `δθ′ = exp(a)·δθ + J_l(a)·δa`, so
//!
//! ```text
//! t̄ passes through;  θ̄ = exp(a)ᵀ·θ̄′;
//! ū_t += t̄/N_sub + v̄_lin/Δt;  ū_r += J_l(a)ᵀ·θ̄′/N_sub + ω̄/Δt
//! ```
//!
//! with `J_l` the left Jacobian of SO(3). Exact. Consumes `v̄_lin` and `ω̄`.

use crate::adjoint::grid_collision::ColliderAdj;
use crate::components::*;
use crate::math::pose::quat_from_rotation_vector;
use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3};

/// `∂L/∂u` per global step of a tool's control sequence.
#[derive(Component, Clone, Debug, Default)]
pub struct ControlAdj(pub Vec<[f64; 6]>);

#[inline]
fn skew(a: DVec3) -> DMat3 {
    DMat3::from_cols(
        DVec3::new(0.0, a.z, -a.y),
        DVec3::new(-a.z, 0.0, a.x),
        DVec3::new(a.y, -a.x, 0.0),
    )
}

/// Left Jacobian of SO(3): `J_l(a) = I + (1 − cos θ)/θ²·[a]× + (θ − sin θ)/θ³·[a]×²`, θ = ‖a‖
/// (series below θ = 1e-4, where the closed form loses digits).
pub fn left_jacobian(a: DVec3) -> DMat3 {
    let th = a.length();
    let (c1, c2) = if th < 1e-4 {
        (0.5 - th * th / 24.0, 1.0 / 6.0 - th * th / 120.0)
    } else {
        (
            (1.0 - th.cos()) / (th * th),
            (th - th.sin()) / (th * th * th),
        )
    };
    let k = skew(a);
    DMat3::IDENTITY + k * c1 + k * k * c2
}

pub fn tool_move_adjoint(
    params: Res<SimParams>,
    clock: Res<Clock>,
    mut tools: Query<(&Control, &mut ColliderAdj, &mut ControlAdj)>,
) {
    for (control, mut a, mut g) in &mut tools {
        let Some(u) = control.per_step.get(clock.step) else {
            // Past the end of the controls the tool holds still: nothing depends on u.
            a.linear = DVec3::ZERO;
            a.angular = DVec3::ZERO;
            continue;
        };
        let n = params.substeps as f64;
        let rv = DVec3::new(u[3], u[4], u[5]) / n;
        let e = DMat3::from_quat(quat_from_rotation_vector(rv));
        let g_t = a.translation / n + a.linear / params.dt;
        let g_r = left_jacobian(rv).transpose() * a.rotation / n + a.angular / params.dt;
        a.rotation = e.transpose() * a.rotation;
        let gu = &mut g.0[clock.step];
        for k in 0..3 {
            gu[k] += g_t[k];
            gu[3 + k] += g_r[k];
        }
        a.linear = DVec3::ZERO;
        a.angular = DVec3::ZERO;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `exp(a + δa)·exp(a)ᵀ ≈ I + [J_l(a)·δa]×`: central differences in f64.
    #[test]
    fn left_jacobian_matches_central_differences() {
        const EPS: f64 = 1e-6;
        for a in [
            DVec3::new(0.3, -0.2, 0.5),
            DVec3::new(1e-6, 2e-6, 0.0),
            DVec3::new(2.0, 0.1, -1.0),
        ] {
            let j = left_jacobian(a);
            for k in 0..3 {
                let mut d = DVec3::ZERO;
                d[k] = EPS;
                let rp = DMat3::from_quat(quat_from_rotation_vector(a + d));
                let rm = DMat3::from_quat(quat_from_rotation_vector(a - d));
                let r0 = DMat3::from_quat(quat_from_rotation_vector(a));
                let w = (rp - rm) * r0.transpose() * (0.5 / EPS);
                // w is skew: read the axial vector.
                let axial = DVec3::new(
                    w.y_axis.z - w.z_axis.y,
                    w.z_axis.x - w.x_axis.z,
                    w.x_axis.y - w.y_axis.x,
                ) * 0.5;
                assert!(
                    (axial - j.col(k)).length() < 1e-8,
                    "a {a:?} column {k}: {axial:?} vs {:?}",
                    j.col(k)
                );
            }
        }
    }
}
