//! Stage 6, tool move: every kinematic tool advances by `u/N_sub`, where `u` is its 6-D control
//! (translation, rotation vector) for the current global step; its rigid velocity over the
//! substep is `u/Δt`. Containers never move.
//!
//! Reads `Clock`, `SimParams`, `Control`; writes `ColliderPose`.

use crate::components::*;
use bevy_ecs::prelude::*;
use glam::DVec3;

/// The pose displacement and velocities of one substep for the step control `u`.
#[inline]
pub fn substep_motion(u: [f64; 6], dt: f64, substeps: usize) -> (DVec3, DVec3, DVec3, DVec3) {
    let t = DVec3::new(u[0], u[1], u[2]);
    let r = DVec3::new(u[3], u[4], u[5]);
    let n = substeps as f64;
    (t / n, r / n, t / dt, r / dt)
}

pub fn tool_move(
    params: Res<SimParams>,
    clock: Res<Clock>,
    mut tools: Query<(&Control, &mut ColliderPose)>,
) {
    for (control, mut pose) in &mut tools {
        let u = control
            .per_step
            .get(clock.step)
            .copied()
            .unwrap_or([0.0; 6]);
        let (dt_, dr, lin, ang) = substep_motion(u, params.dt, params.substeps);
        pose.pose = pose.pose.displaced(dt_, dr);
        pose.linear = lin;
        pose.angular = ang;
    }
}
