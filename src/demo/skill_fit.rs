//! Fitting the skill parameters Θ to a tracked tool path (seed B's last step before the
//! physics): Θ → per-step controls ([`SkillSpec::controls`]) → the tool's poses → a path loss
//! against the tracked poses, differentiated back through the same chain
//! ([`trajectory_adj`], then [`SkillSpec::controls_adj`]).
//!
//! **The path loss** compares paths, not timings: each pose stands for two points, its origin
//! (the bowl's centre) and a point a lever away along the tool's local x (the handle's
//! direction), so an angle counts as lever × angle in metres; the loss is the dynamic-time-
//! warping distance between the tracked poses' point pairs and the skill's ([`dtw`]). A hand's
//! own timing and pauses then do not matter, while the order of the motion does (a symmetric
//! Chamfer distance did not: a shallower scoop and a lower lift share the vertical line of the
//! descent and left Θ 0.26 off). The skill's timing follows from Θ and the scene's speeds, so it
//! is not a free parameter here.

use crate::adjoint::tool_move::left_jacobian;
use crate::math::pose::{quat_from_rotation_vector, Pose};
use crate::skills::SkillSpec;
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

/// Tracked poses at frames `(global step, pose)`, in order, joined by straight lines (lerp and
/// slerp) into one pose per global step from the first frame to the last.
pub fn join_frames(frames: &[(usize, Pose)]) -> Vec<Pose> {
    let mut out = Vec::new();
    for w in frames.windows(2) {
        let ((k0, a), (k1, b)) = (w[0], w[1]);
        for k in k0..k1.max(k0 + 1) {
            let s = (k - k0) as f64 / (k1 - k0).max(1) as f64;
            out.push(Pose {
                translation: a.translation.lerp(b.translation, s),
                rotation: a.rotation.slerp(b.rotation, s),
            });
        }
    }
    out.extend(frames.last().map(|f| f.1));
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

/// The dynamic-time-warping distance between two sequences of point pairs (each pair one 6-D
/// point): the mean squared distance along the cheapest monotone alignment of the two, which
/// keeps their order and both ends, and its gradient with respect to the second sequence (the
/// alignment held fixed; it is piecewise constant in the points).
pub fn dtw(demo: &[[DVec3; 2]], skill: &[[DVec3; 2]]) -> (f64, Vec<[DVec3; 2]>) {
    let d2 = |a: &[DVec3; 2], b: &[DVec3; 2]| {
        (a[0] - b[0]).length_squared() + (a[1] - b[1]).length_squared()
    };
    let (n, m) = (demo.len(), skill.len());
    let mut g = vec![[DVec3::ZERO; 2]; m];
    if n == 0 || m == 0 {
        return (0.0, g);
    }
    // cost[i][j]: the cheapest alignment of demo[..=i] with skill[..=j].
    let mut cost = vec![f64::INFINITY; n * m];
    for i in 0..n {
        for j in 0..m {
            let prev = match (i, j) {
                (0, 0) => 0.0,
                (0, _) => cost[j - 1],
                (_, 0) => cost[(i - 1) * m],
                _ => cost[(i - 1) * m + j - 1]
                    .min(cost[(i - 1) * m + j])
                    .min(cost[i * m + j - 1]),
            };
            cost[i * m + j] = prev + d2(&demo[i], &skill[j]);
        }
    }
    // Back along the alignment, preferring the diagonal on ties.
    let mut path = vec![(n - 1, m - 1)];
    let (mut i, mut j) = (n - 1, m - 1);
    while (i, j) != (0, 0) {
        (i, j) = if i == 0 {
            (0, j - 1)
        } else if j == 0 {
            (i - 1, 0)
        } else {
            let c = |a: usize, b: usize| cost[a * m + b];
            let diag = c(i - 1, j - 1);
            if diag <= c(i - 1, j) && diag <= c(i, j - 1) {
                (i - 1, j - 1)
            } else if c(i - 1, j) <= c(i, j - 1) {
                (i - 1, j)
            } else {
                (i, j - 1)
            }
        };
        path.push((i, j));
    }
    let len = path.len() as f64;
    for &(i, j) in &path {
        for k in 0..2 {
            g[j][k] += 2.0 * (skill[j][k] - demo[i][k]) / len;
        }
    }
    (cost[n * m - 1] / len, g)
}

/// The path loss of Θ against the tracked poses and `∂loss/∂Θ` (straight-through in the
/// phases' step counts, as everywhere else).
pub fn path_loss(
    skill: &SkillSpec,
    theta: [f64; 5],
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
    let (loss, g_points) = dtw(demo, &points);
    let g_u = trajectory_adj(&poses, &controls, lever, &g_points);
    (loss, sk.controls_adj(dt, bottom_y, &g_u))
}

/// What [`fit_theta`] gives.
#[derive(Clone, Debug)]
pub struct ThetaFit {
    pub theta: [f64; 5],
    /// The path loss at Θ (m²).
    pub loss: f64,
}

/// Fits Θ to the tracked poses by Adam in [−1, 1]⁵ (projected), from each of `starts`, and
/// keeps the lowest path loss.
#[allow(clippy::too_many_arguments)]
pub fn fit_theta(
    skill: &SkillSpec,
    starts: &[[f64; 5]],
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
        theta: [f64; 5],
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
        let demo = track(&sk, [0.4, -0.3, 0.5, -0.6, 0.2], &start, dt, bottom, lever);
        let theta = [0.1, 0.2, -0.1, 0.3, -0.2];
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
        for truth in [[0.4, -0.3, 0.5, -0.6, 0.2], [-0.7, 0.6, -0.2, 0.8, -0.5]] {
            let demo = track(&sk, truth, &start, dt, bottom, lever);
            let fit = fit_theta(&sk, &[[0.0; 5]], &start, dt, bottom, lever, &demo, 1500);
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
    use crate::scene::{ControlSpec, Scene};

    /// The Θ fitted to g(Θ*)'s exact poses filmed every `every` steps and joined by straight
    /// lines, as `demo fit` joins its frames.
    fn fitted(every: usize) -> ([f64; 5], [f64; 5]) {
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
        let truth = [0.4, -0.3, 0.5, -0.6, 0.2];
        let (u, _) = SkillSpec {
            theta: truth,
            ..sk.clone()
        }
        .controls(dt, bottom);
        let poses = trajectory(&start, &u);
        let last = poses.len() - 1;
        let frames: Vec<(usize, Pose)> = (0..=last)
            .filter(|k| k % every == 0 || *k == last)
            .map(|k| (k, poses[k]))
            .collect();
        let joined = join_frames(&frames);
        let points: Vec<[DVec3; 2]> = joined.iter().map(|p| pose_points(p, lever)).collect();
        let starts = [sk.theta, [0.0; 5]];
        let fit = fit_theta(sk, &starts, &start, dt, bottom, lever, &points, 1500);
        (fit.theta, truth)
    }

    /// The scoop's bottom lasts a few steps: frames 3 steps apart (33 Hz at Δt = 10 ms) see it
    /// and Θ comes back within 0.02; frames 8 steps apart miss it, and the straight lines that
    /// join them make the fitted scoop shallower (the study's missed target, docs/design.md).
    #[test]
    fn frames_must_be_dense_enough_to_see_the_scoops_bottom() {
        let (dense, truth) = fitted(3);
        for k in 0..5 {
            assert!((dense[k] - truth[k]).abs() < 0.02, "every 3: {dense:?}");
        }
        let (sparse, _) = fitted(8);
        assert!(truth[0] - sparse[0] > 0.2, "every 8: {sparse:?}");
    }
}
