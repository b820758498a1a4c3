//! Fitting the skill parameters Θ to a tracked tool path (seed B's last step before the
//! physics): Θ → per-step controls ([`SkillSpec::controls`]) → the tool's poses → a path loss
//! against the tracked poses, differentiated back through the same chain
//! ([`trajectory_adj`], then [`SkillSpec::controls_adj`]).
//!
//! **The path loss** compares paths, not timings: each pose stands for two points, its origin
//! (the bowl's centre) and a point a lever away along the tool's local x (the handle's
//! direction), so an angle counts as lever × angle in metres; the loss is the mean squared
//! distance of the tracked frames from the skill's path along an order-keeping alignment
//! ([`align`]). A hand's own timing and pauses then do not matter, while the order of the
//! motion does (a symmetric Chamfer distance did not: a shallower scoop and a lower lift share
//! the vertical line of the descent and left Θ 0.26 off). The skill's timing follows from Θ and the scene's speeds, so it
//! is not a free parameter here.

use crate::adjoint::tool_move::left_jacobian;
use crate::math::pose::{quat_from_rotation_vector, Pose};
use crate::skills::SkillSpec;
use crate::skills::Theta;
use glam::{DMat3, DVec3};

/// A pose as the path loss sees it: its origin and a point `lever` along its local x.
pub fn pose_points(p: &Pose, lever: f64) -> [DVec3; 2] {
    [p.translation, p.to_world(DVec3::X * lever)]
}

/// The tool's pose at the start of each global step and after the last: `pose_{k+1}` is
/// `pose_k` displaced by control `k`. (Within a step the substeps rotate about one axis, so
/// they compose to the step's whole rotation.)
pub fn trajectory(start: &Pose, controls: &[[f64; 6]]) -> Vec<Pose> {
    let mut out = Vec::with_capacity(controls.len() + 1);
    out.push(*start);
    for u in controls {
        let p = out
            .last()
            .expect("at least the start")
            .displaced(DVec3::new(u[0], u[1], u[2]), DVec3::new(u[3], u[4], u[5]));
        out.push(p);
    }
    out
}

/// The adjoint of [`trajectory`] followed by [`pose_points`]: `∂L/∂u` per step from `∂L/∂`
/// each pose's two points. With world-frame rotation perturbations (`δR = [δθ]×R`),
/// `R_{k+1} = exp(r_k)·R_k` gives `δθ_{k+1} = exp(r_k)·δθ_k + J_l(r_k)·δr_k`.
pub fn trajectory_adj(
    poses: &[Pose],
    controls: &[[f64; 6]],
    lever: f64,
    g_points: &[[DVec3; 2]],
) -> Vec<[f64; 6]> {
    let mut g_u = vec![[0.0; 6]; controls.len()];
    let (mut t_bar, mut th_bar) = (DVec3::ZERO, DVec3::ZERO);
    for k in (0..poses.len()).rev() {
        let [g0, g1] = g_points[k];
        let arm = poses[k].rotation * (DVec3::X * lever);
        t_bar += g0 + g1;
        th_bar += arm.cross(g1);
        if k == 0 {
            break;
        }
        // Control k − 1 took pose k − 1 to pose k.
        let u = controls[k - 1];
        let r = DVec3::new(u[3], u[4], u[5]);
        let gr = left_jacobian(r).transpose() * th_bar;
        g_u[k - 1] = [t_bar.x, t_bar.y, t_bar.z, gr.x, gr.y, gr.z];
        th_bar = DMat3::from_quat(quat_from_rotation_vector(r)).transpose() * th_bar;
    }
    g_u
}

/// The nearest point to `a` on the segment `p → q` of 6-D points: its parameter `t ∈ [0, 1]`
/// and squared distance.
fn nearest_on_segment(a: &[DVec3; 2], p: &[DVec3; 2], q: &[DVec3; 2]) -> (f64, f64) {
    let d = [q[0] - p[0], q[1] - p[1]];
    let dd = d[0].length_squared() + d[1].length_squared();
    let t = if dd > 0.0 {
        (((a[0] - p[0]).dot(d[0]) + (a[1] - p[1]).dot(d[1])) / dd).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let e = [p[0] + t * d[0] - a[0], p[1] + t * d[1] - a[1]];
    (t, e[0].length_squared() + e[1].length_squared())
}

/// The path distance of tracked frames (point pairs, each one 6-D point) from a skill's
/// polyline through its steps' point pairs, and its gradient with respect to the polyline's
/// vertices: the mean squared distance of each frame from its segment, along the cheapest
/// alignment of frames to segments that keeps their order (a frame's segment is never before
/// the last frame's), with the first frame on the first segment and the last at the last
/// vertex. The alignment is held fixed in the gradient (it is piecewise constant in the
/// points); so is each frame's nearest point on its segment (the envelope theorem).
///
/// Frames to *segments*, and only the frames aligned: a hand's frames fall between the skill's
/// steps and arrive at their own pace, so every frame is charged its distance from the path,
/// while the skill's steps between two frames are not charged at all. (A symmetric dynamic
/// time warping between steps and the frames joined by straight lines charged the skill's
/// steps at the scoop's bottom for their distance from the straight line that cut its corner,
/// and fitted the scoop 0.3–0.5 too shallow on frames 4–8 steps apart: docs/design.md.)
pub fn align(frames: &[[DVec3; 2]], skill: &[[DVec3; 2]]) -> (f64, Vec<[DVec3; 2]>) {
    let (n, m) = (frames.len(), skill.len());
    let mut g = vec![[DVec3::ZERO; 2]; m];
    if n == 0 || m == 0 {
        return (0.0, g);
    }
    // Segment j joins vertex j to vertex j + 1 (a single vertex is a segment of length 0);
    // the last frame is held to the last vertex.
    let segs = (m - 1).max(1);
    let near = |i: usize, j: usize| {
        if i == n - 1 && n > 1 {
            let v = &skill[m - 1];
            let d2 =
                (frames[i][0] - v[0]).length_squared() + (frames[i][1] - v[1]).length_squared();
            return (m - 1, 1.0, d2);
        }
        let q = (j + 1).min(m - 1);
        let (t, d2) = nearest_on_segment(&frames[i], &skill[j], &skill[q]);
        (j, t, d2)
    };
    // cost[j]: the cheapest alignment of frames[..=i] with frame i on segment j; back[i][j]:
    // frame i − 1's segment on it.
    let mut cost: Vec<f64> = (0..segs)
        .map(|j| if j == 0 { near(0, 0).2 } else { f64::INFINITY })
        .collect();
    let mut back = vec![vec![0usize; segs]; n];
    for (i, back_i) in back.iter_mut().enumerate().skip(1) {
        // The running minimum of the previous row over segments ≤ j.
        let (mut best, mut arg) = (f64::INFINITY, 0);
        let mut next = vec![f64::INFINITY; segs];
        for j in 0..segs {
            if cost[j] < best {
                (best, arg) = (cost[j], j);
            }
            back_i[j] = arg;
            next[j] = best + near(i, j).2;
        }
        cost = next;
    }
    // The last frame is at the last vertex whatever its segment; take the cheapest.
    let mut j = (0..segs)
        .min_by(|&a, &b| cost[a].total_cmp(&cost[b]))
        .expect("a segment");
    let total = cost[j];
    for i in (0..n).rev() {
        let (a, t, _) = near(i, j);
        let q = (a + 1).min(m - 1);
        for k in 0..2 {
            let p = skill[a][k] + t * (skill[q][k] - skill[a][k]);
            let e = 2.0 * (p - frames[i][k]) / n as f64;
            g[a][k] += (1.0 - t) * e;
            g[q][k] += t * e;
        }
        j = back[i][j];
    }
    (total / n as f64, g)
}

/// The path loss of Θ against the tracked poses and `∂loss/∂Θ` (straight-through in the
/// phases' step counts, as everywhere else).
pub fn path_loss(
    skill: &SkillSpec,
    theta: Theta,
    start: &Pose,
    dt: f64,
    bottom_y: f64,
    lever: f64,
    demo: &[[DVec3; 2]],
) -> (f64, [f64; 5]) {
    let sk = SkillSpec {
        theta,
        ..skill.clone()
    };
    let (controls, _) = sk.controls(dt, bottom_y);
    let poses = trajectory(start, &controls);
    let points: Vec<[DVec3; 2]> = poses.iter().map(|p| pose_points(p, lever)).collect();
    let (loss, g_points) = align(demo, &points);
    let g_u = trajectory_adj(&poses, &controls, lever, &g_points);
    (loss, sk.controls_adj(dt, bottom_y, &g_u))
}

/// What [`fit_theta`] gives.
#[derive(Clone, Debug)]
pub struct ThetaFit {
    pub theta: Theta,
    /// The path loss at Θ (m²).
    pub loss: f64,
}

/// Fits Θ to the tracked poses by Adam in [−1, 1]⁵ (projected), from each of `starts`, and
/// keeps the lowest path loss.
#[allow(clippy::too_many_arguments)]
pub fn fit_theta(
    skill: &SkillSpec,
    starts: &[Theta],
    start_pose: &Pose,
    dt: f64,
    bottom_y: f64,
    lever: f64,
    demo: &[[DVec3; 2]],
    iterations: usize,
) -> ThetaFit {
    let (lr, b1, b2) = (0.05, 0.9, 0.999);
    let mut best = ThetaFit {
        theta: skill.theta,
        loss: f64::INFINITY,
    };
    for s in starts {
        let mut theta = *s;
        let (mut m, mut v) = ([0.0; 5], [0.0; 5]);
        for it in 1..=iterations {
            let (loss, g) = path_loss(skill, theta, start_pose, dt, bottom_y, lever, demo);
            if loss < best.loss {
                best = ThetaFit { theta, loss };
            }
            // The step shrinks over the run so that the last steps settle.
            let rate = lr * (1.0 - (it - 1) as f64 / iterations as f64).max(0.05);
            for k in 0..5 {
                m[k] = b1 * m[k] + (1.0 - b1) * g[k];
                v[k] = b2 * v[k] + (1.0 - b2) * g[k] * g[k];
                let mh = m[k] / (1.0 - b1.powi(it as i32));
                let vh = v[k] / (1.0 - b2.powi(it as i32));
                theta[k] = (theta[k] - rate * mh / (vh.sqrt() + 1e-12)).clamp(-1.0, 1.0);
            }
        }
        let (loss, _) = path_loss(skill, theta, start_pose, dt, bottom_y, lever, demo);
        if loss < best.loss {
            best = ThetaFit { theta, loss };
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{ControlSpec, Scene};

    fn tiny() -> (SkillSpec, Pose, f64, f64, f64) {
        let scene = Scene::load(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/tests/scenes/tiny_transport.ron"
        ))
        .unwrap();
        let tool = scene.colliders.iter().find(|c| c.name == "spoon").unwrap();
        let Some(ControlSpec::Skill(sk)) = &tool.control else {
            panic!("a skill")
        };
        let lever = tool.shape.bounding_radius();
        (
            sk.clone(),
            Scene::collider_pose(tool),
            scene.simulation.dt,
            Scene::tool_bottom(tool),
            lever,
        )
    }

    fn track(
        sk: &SkillSpec,
        theta: Theta,
        start: &Pose,
        dt: f64,
        bottom: f64,
        lever: f64,
    ) -> Vec<[DVec3; 2]> {
        let sk = SkillSpec {
            theta,
            ..sk.clone()
        };
        let (u, _) = sk.controls(dt, bottom);
        trajectory(start, &u)
            .iter()
            .map(|p| pose_points(p, lever))
            .collect()
    }

    /// Central differences in f64 at ε = 1e-7 in Θ (no phase's step count changes): the
    /// adjoint agrees to 1e-5 relative where the alignment does not switch.
    const PATH_TOL: f64 = 1e-5;

    #[test]
    fn path_gradient_matches_central_differences() {
        let (sk, start, dt, bottom, lever) = tiny();
        let demo = track(
            &sk,
            Theta([0.4, -0.3, 0.5, -0.6, 0.2]),
            &start,
            dt,
            bottom,
            lever,
        );
        let theta = Theta([0.1, 0.2, -0.1, 0.3, -0.2]);
        let (_, g) = path_loss(&sk, theta, &start, dt, bottom, lever, &demo);
        let eps = 1e-7;
        for k in 0..5 {
            let at = |e: f64| {
                let mut t = theta;
                t[k] += e;
                path_loss(&sk, t, &start, dt, bottom, lever, &demo).0
            };
            let fd = (at(eps) - at(-eps)) / (2.0 * eps);
            assert!(
                (fd - g[k]).abs() <= PATH_TOL * fd.abs().max(g[k].abs()).max(1e-12),
                "θ[{k}]: adjoint {} against {fd}",
                g[k]
            );
        }
    }

    #[test]
    fn recovers_theta_from_an_exact_track() {
        let (sk, start, dt, bottom, lever) = tiny();
        for truth in [
            Theta([0.4, -0.3, 0.5, -0.6, 0.2]),
            Theta([-0.7, 0.6, -0.2, 0.8, -0.5]),
        ] {
            let demo = track(&sk, truth, &start, dt, bottom, lever);
            let fit = fit_theta(
                &sk,
                &[Theta([0.0; 5])],
                &start,
                dt,
                bottom,
                lever,
                &demo,
                1500,
            );
            let worst = fit
                .theta
                .iter()
                .zip(truth)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            assert!(
                worst < 0.05,
                "fitted {:?} for {truth:?} (loss {:e})",
                fit.theta,
                fit.loss
            );
        }
    }
}
#[cfg(test)]
mod frame_rate {
    use super::*;
    use crate::lab::demo::make::hand_motion;
    use crate::scene::{ControlSpec, Scene};

    /// The Θ fitted to a hand's exact poses along g(Θ*) at its own pace (`warp`) with a
    /// tremor, filmed every `every` steps.
    fn fitted(every: usize, warp: f64, tremor: f64) -> (Theta, Theta) {
        let scene = Scene::load(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/scenes/powder_transport.ron"
        ))
        .unwrap();
        let tool = &scene.colliders[crate::rollout::skill_tool(&scene).unwrap()];
        let Some(ControlSpec::Skill(sk)) = &tool.control else {
            panic!("a skill")
        };
        let (lever, start) = (tool.shape.bounding_radius(), Scene::collider_pose(tool));
        let (dt, bottom) = (scene.simulation.dt, Scene::tool_bottom(tool));
        let truth = Theta([0.4, -0.3, 0.5, -0.6, 0.2]);
        let (u, _) = SkillSpec {
            theta: truth,
            ..sk.clone()
        }
        .controls(dt, bottom);
        let hand = hand_motion(&trajectory(&start, &u), warp, tremor, lever, 1);
        let last = hand.len() - 1;
        let points: Vec<[DVec3; 2]> = (0..=last)
            .filter(|k| k % every == 0 || *k == last)
            .map(|k| pose_points(&hand[k], lever))
            .collect();
        let starts = [sk.theta, Theta([0.0; 5])];
        let fit = fit_theta(sk, &starts, &start, dt, bottom, lever, &points, 1500);
        (fit.theta, truth)
    }

    /// Frames of a hand at its own pace with a tremor, 8 steps apart (12.5 frames per second
    /// at Δt = 10 ms) and 12 apart: Θ comes back within 0.01 and 0.06. (Joined by straight
    /// lines and aligned by a symmetric time warping, frames 8 apart fitted the scoop depth 0.5
    /// too shallow.)
    #[test]
    fn a_hand_filmed_at_its_own_pace_gives_theta_back() {
        for (every, tol) in [(8, 0.01), (12, 0.06)] {
            let (fit, truth) = fitted(every, 0.3, 0.0003);
            for k in 0..5 {
                assert!(
                    (fit[k] - truth[k]).abs() < tol,
                    "every {every}: {fit:?} against {truth:?}"
                );
            }
        }
    }
}
