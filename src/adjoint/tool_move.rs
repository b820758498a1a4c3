//! Adjoint of stage 6, tool move: `t′ = t + u_t/N_sub`, `v_lin = u_t/Δt` for the current
//! step's control `u`. So `t̄` passes through, and `ū_t += t̄′/N_sub + v̄_lin/Δt`; `v̄_lin` is
//! consumed. Exact. Rotating tools are refused by the backward driver (their rotation-vector
//! exponential has no adjoint yet).

use crate::adjoint::grid_collision::ColliderAdj;
use crate::components::*;
use bevy_ecs::prelude::*;
use glam::DVec3;

/// `∂L/∂u` per global step of a tool's control sequence.
#[derive(Component, Clone, Debug, Default)]
pub struct ControlAdj(pub Vec<[f64; 6]>);

pub fn tool_move_adjoint(
    params: Res<SimParams>,
    clock: Res<Clock>,
    mut tools: Query<(&Control, &mut ColliderAdj, &mut ControlAdj)>,
) {
    for (control, mut a, mut g) in &mut tools {
        if clock.step >= control.per_step.len() {
            // Past the end of the controls the tool holds still: nothing depends on u.
            a.linear = DVec3::ZERO;
            continue;
        }
        let du = a.translation / params.substeps as f64 + a.linear / params.dt;
        let gu = &mut g.0[clock.step];
        gu[0] += du.x;
        gu[1] += du.y;
        gu[2] += du.z;
        a.linear = DVec3::ZERO;
    }
}
