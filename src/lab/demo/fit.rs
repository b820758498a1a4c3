//! Fitting a demonstration (`powderlab demo fit`), in seed B's alternation:
//!
//! 1. the spoon's pose tracked frame by frame ([`track`](super::track)), each frame started
//!    from the previous frames' constant-velocity prediction or from the last pose, whichever
//!    matches the masks better (and from the other too when the fit looks lost), and pulled
//!    towards the prediction by a smoothness prior;
//! 2. the spoon's shape fitted to all frames jointly with their poses
//!    ([`shape`](super::shape); seed B alternates the two, which stalled here);
//! 3. the tracked frames carried over to the robot's spoon through the bowls' frames
//!    ([`spoon_map`](super::spoon_map)), and Θ fitted to them ([`skill_fit`](super::skill_fit)).

use super::format::Demo;
use super::shape::{dimensions, refine};
use super::skill_fit::{fit_theta, pose_points, ThetaFit};
use super::spoon_map::{demonstrated_skill, transfer};
use super::track::{fit_pose, silhouette_loss, TrackOptions, View};
use crate::math::pose::Pose;
use crate::math::sdf::Spoon;
use crate::rollout::skill_tool;
use crate::scene::{ControlSpec, Scene};
use crate::skills::Theta;
use glam::DVec3;

/// How the fit runs.
#[derive(Clone, Debug)]
pub struct FitOptions {
    pub track: TrackOptions,
    /// The smoothness prior's scale (m): a pose this far from the prediction costs as much
    /// as one wrong pixel.
    pub smoothness: f64,
    /// Fit the demonstrator's spoon with the poses; false keeps the scene's spoon.
    pub fit_shape: bool,
    /// τ of the joint fit of the shape and the poses (pixels' footprint, from and to): it
    /// starts where the tracking's first τ level has already pulled each pose in.
    pub refine_tau_px: (f64, f64),
    /// Levenberg–Marquardt steps of the joint fit at each τ.
    pub refine_iterations: usize,
    /// Adam steps of the Θ fit from each start.
    pub theta_iterations: usize,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            // The joint fit polishes every pose afterwards, so tracking stops sooner than
            // the tracker's default.
            track: TrackOptions {
                iterations: 12,
                ..TrackOptions::default()
            },
            smoothness: 0.01,
            fit_shape: true,
            refine_tau_px: (0.5, 0.25),
            refine_iterations: 25,
            theta_iterations: 1500,
        }
    }
}

/// What a fit gives.
#[derive(Clone, Debug)]
pub struct DemoFit {
    pub track: Tracked,
    pub theta: Theta,
    /// The path loss at Θ (m²).
    pub path_loss: f64,
}

/// The frames' views, in the cameras' order.
fn views(demo: &Demo) -> Vec<Vec<View<'_>>> {
    demo.frames
        .iter()
        .map(|(_, masks)| {
            demo.cameras
                .iter()
                .zip(masks)
                .map(|(camera, mask)| View { camera, mask })
                .collect()
        })
        .collect()
}

/// A frame's fit looks lost when its silhouette loss is above this many times the median of
/// the frames' before it (from the third frame on). A tracked frame's loss varies by less than
/// 1.5 times its running median in the study's demonstrations, while a frame that lost the
/// spoon (frames 10 steps apart at 64×48 in `tests/demo_pipeline.rs`) jumped to 8 times it.
pub const LOST_RATIO: f64 = 3.0;

/// Whether a fit of loss `loss` after frames of `losses` looks lost ([`LOST_RATIO`]).
fn looks_lost(loss: f64, losses: &[f64]) -> bool {
    if losses.len() < 3 {
        return false;
    }
    let mut sorted = losses.to_vec();
    sorted.sort_by(f64::total_cmp);
    loss > LOST_RATIO * sorted[sorted.len() / 2]
}

/// Tracks every frame, the first from the scene's `start`.
fn track_all(
    demo: &Demo,
    frames: &[Vec<View>],
    spoon: &Spoon,
    start: Pose,
    opts: &TrackOptions,
    progress: &mut dyn FnMut(),
) -> (Vec<Pose>, Vec<f64>) {
    let (mut poses, mut losses): (Vec<Pose>, Vec<f64>) = (Vec::new(), Vec::new());
    for (f, views) in frames.iter().enumerate() {
        // Constant velocity from the last two frames, per unit of frame index.
        let predicted = match poses.as_slice() {
            [] => start,
            [p] => *p,
            [.., a, b] => {
                let (ia, ib, ic) = (
                    demo.frames[f - 2].0 as f64,
                    demo.frames[f - 1].0 as f64,
                    demo.frames[f].0 as f64,
                );
                let s = (ic - ib) / (ib - ia).max(1.0);
                let dr = (b.rotation * a.rotation.inverse()).to_scaled_axis() * s;
                b.displaced((b.translation - a.translation) * s, dr)
            }
        };
        let prior = (!poses.is_empty()).then_some(&predicted);
        // From the prediction or from the last pose (a phase's end breaks the prediction),
        // whichever matches the masks better at the first τ; and from the other one too when
        // that fit looks lost.
        let (mut t, other) = match poses.last() {
            Some(last) => {
                let px = opts.tau_px.0;
                let at = |p: &Pose| silhouette_loss(views, spoon, p, px);
                let (a, b) = if at(last) < at(&predicted) {
                    (*last, predicted)
                } else {
                    (predicted, *last)
                };
                (fit_pose(views, spoon, a, prior, opts), Some(b))
            }
            None => (fit_pose(views, spoon, predicted, prior, opts), None),
        };
        if let Some(b) = other {
            if looks_lost(t.loss, &losses) {
                let u = fit_pose(views, spoon, b, prior, opts);
                if u.loss < t.loss {
                    t = u;
                }
            }
        }
        poses.push(t.pose);
        losses.push(t.loss);
        progress();
    }
    (poses, losses)
}

/// What the tracking gives (steps 1–2).
#[derive(Clone, Debug)]
pub struct Tracked {
    /// The tracked pose of each frame (the demonstrator's spoon).
    pub poses: Vec<Pose>,
    /// Each frame's silhouette loss at the end.
    pub silhouette_loss: Vec<f64>,
    /// The demonstrator's spoon (fitted, or the scene's).
    pub spoon: Spoon,
    /// The total silhouette loss after the tracking, and after the joint fit of the shape and
    /// the poses.
    pub rounds: Vec<f64>,
}

/// The scene's skill spoon and its skill.
fn robot(scene: &Scene) -> anyhow::Result<(usize, Spoon, &crate::skills::SkillSpec)> {
    let i = skill_tool(scene)?;
    let tool = &scene.colliders[i];
    let Some(robot) = tool.shape.spoon() else {
        anyhow::bail!(
            "{}: colliders[{i}] ('{}') is a {}: demo fit tracks a spoon",
            scene.path.display(),
            tool.name,
            tool.shape.name()
        );
    };
    let Some(ControlSpec::Skill(sk)) = &tool.control else {
        unreachable!("skill_tool found a Skill control")
    };
    Ok((i, robot, sk))
}

/// Tracks the spoon and fits its shape (steps 1–2); `progress` is called after each tracked
/// frame with the frames done and their number.
pub fn track(
    demo: &Demo,
    scene: &Scene,
    opts: &FitOptions,
    mut progress: impl FnMut(usize, usize),
) -> anyhow::Result<Tracked> {
    let (i, robot, _) = robot(scene)?;
    let start = Scene::collider_pose(&scene.colliders[i]);
    let track_opts = TrackOptions {
        prior_weight: 1.0 / (opts.smoothness * opts.smoothness),
        ..opts.track.clone()
    };
    let frames = views(demo);
    let total = frames.len();
    let mut done = 0;
    let mut tick = || {
        done += 1;
        progress(done, total);
    };
    let (poses, losses) = track_all(demo, &frames, &robot, start, &track_opts, &mut tick);
    let mut rounds = vec![losses.iter().sum::<f64>()];
    let (spoon, poses, losses) = if opts.fit_shape {
        let r = refine(
            &frames,
            robot,
            &poses,
            opts.refine_tau_px,
            opts.refine_iterations,
        );
        rounds.push(r.losses.iter().sum());
        (r.spoon, r.poses, r.losses)
    } else {
        (robot, poses, losses)
    };
    Ok(Tracked {
        poses,
        silhouette_loss: losses,
        spoon,
        rounds,
    })
}

/// Fits Θ to a track (step 3): the tracked frames carried over to the scene's spoon. The path
/// loss aligns them in order and ignores their timing, so the frames' steps are not needed.
pub fn fit_skill(tracked: &Tracked, scene: &Scene, opts: &FitOptions) -> anyhow::Result<ThetaFit> {
    let (i, robot, sk) = robot(scene)?;
    let tool = &scene.colliders[i];
    // The tracked frames, carried over to the robot's spoon.
    let lever = tool.shape.bounding_radius();
    let points: Vec<[DVec3; 2]> = tracked
        .poses
        .iter()
        .map(|p| pose_points(&transfer(p, &tracked.spoon, &robot), lever))
        .collect();
    Ok(fit_theta(
        &demonstrated_skill(sk, &robot, &tracked.spoon),
        &[sk.theta, Theta([0.0; 5])],
        &Scene::collider_pose(tool),
        scene.simulation.dt,
        Scene::tool_bottom(tool),
        lever,
        &points,
        opts.theta_iterations,
    ))
}

/// Tracks and fits; `progress` is called after each tracked frame with the frames done and
/// their number.
pub fn fit(
    demo: &Demo,
    scene: &Scene,
    opts: &FitOptions,
    progress: impl FnMut(usize, usize),
) -> anyhow::Result<DemoFit> {
    let t = track(demo, scene, opts, progress)?;
    let th = fit_skill(&t, scene, opts)?;
    Ok(DemoFit {
        track: t,
        theta: th.theta,
        path_loss: th.loss,
    })
}

/// A fit's errors against a synthetic demonstration's truth.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Score {
    /// Pose error over the frames: median and 95th percentile, translation (mm) and angle (°).
    pub pose_mm: [f64; 2],
    pub pose_deg: [f64; 2],
    /// |Θ − Θ*| in the [−1, 1] units: mean over the components, and the largest.
    pub theta_mean: f64,
    pub theta_max: f64,
    /// |fitted − true| / true per spoon dimension (bowl radius, bowl depth, handle length), %.
    pub shape_pct: [f64; 3],
}

/// Scores a fit against the truth `demo make` wrote; `scene_spoon` is the demonstrator's when
/// the truth names none.
pub fn score(fit: &DemoFit, truth: &super::make::Truth, scene_spoon: &Spoon) -> Score {
    let shape = truth.spoon.unwrap_or_else(|| dimensions(scene_spoon));
    let mut mm: Vec<f64> = Vec::new();
    let mut deg: Vec<f64> = Vec::new();
    for (p, (t, q)) in fit.track.poses.iter().zip(&truth.poses) {
        let q = glam::DQuat::from_array(*q);
        mm.push(1e3 * (p.translation - DVec3::from_array(*t)).length());
        deg.push(
            (p.rotation * q.inverse())
                .to_scaled_axis()
                .length()
                .to_degrees(),
        );
    }
    let quantiles = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        let at = |q: f64| v[((q * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)];
        [at(0.5), at(0.95)]
    };
    let errs: Vec<f64> = fit
        .theta
        .iter()
        .zip(&truth.theta)
        .map(|(a, b)| (a - b).abs())
        .collect();
    Score {
        pose_mm: quantiles(&mut mm),
        pose_deg: quantiles(&mut deg),
        theta_mean: errs.iter().sum::<f64>() / 5.0,
        theta_max: errs.iter().copied().fold(0.0, f64::max),
        shape_pct: std::array::from_fn(|k| {
            100.0 * (dimensions(&fit.track.spoon)[k] - shape[k]).abs() / shape[k]
        }),
    }
}
