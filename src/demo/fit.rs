//! Fitting a demonstration (`powderlab demo fit`): the spoon's pose tracked frame by frame
//! ([`track`](super::track)), each frame started from the previous frames' constant-velocity
//! prediction and from the last pose (the better fit kept), and pulled towards the prediction
//! by a smoothness prior; then Θ fitted to the tracked path
//! ([`skill_fit`](super::skill_fit)), the path first resampled at every global step between
//! the frames, so that both sequences the path loss aligns are equally dense.
//!
//! The spoon's shape is the scene's (seed B also fits the shape; here that step is left to a
//! later change, and a demonstrator's different spoon is not yet mapped).

use super::format::Demo;
use super::skill_fit::{fit_theta, join_frames, pose_points};
use super::track::{fit_pose, TrackOptions, View};
use crate::math::pose::Pose;
use crate::rollout::skill_tool;
use crate::scene::{ControlSpec, Scene};
use glam::DVec3;

/// How the fit runs.
#[derive(Clone, Debug)]
pub struct FitOptions {
    pub track: TrackOptions,
    /// The smoothness prior's scale (m): a pose this far from the prediction costs as much
    /// as one wrong pixel.
    pub smoothness: f64,
    /// Adam steps of the Θ fit from each start.
    pub theta_iterations: usize,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            track: TrackOptions::default(),
            smoothness: 0.01,
            theta_iterations: 1500,
        }
    }
}

/// What a fit gives.
#[derive(Clone, Debug)]
pub struct DemoFit {
    /// The tracked pose of each frame.
    pub poses: Vec<Pose>,
    /// Each frame's silhouette loss at the end of its tracking.
    pub silhouette_loss: Vec<f64>,
    pub theta: [f64; 5],
    /// The path loss at Θ (m²).
    pub path_loss: f64,
}

/// Tracks and fits; `progress` is called after each frame with the frames done and the total.
pub fn fit(
    demo: &Demo,
    scene: &Scene,
    opts: &FitOptions,
    mut progress: impl FnMut(usize, usize),
) -> anyhow::Result<DemoFit> {
    let i = skill_tool(scene)?;
    let tool = &scene.colliders[i];
    let Some(spoon) = tool.shape.spoon() else {
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
    let start = Scene::collider_pose(tool);
    let track_opts = TrackOptions {
        prior_weight: 1.0 / (opts.smoothness * opts.smoothness),
        ..opts.track.clone()
    };
    let (mut poses, mut losses): (Vec<Pose>, Vec<f64>) = (Vec::new(), Vec::new());
    for (f, (_, masks)) in demo.frames.iter().enumerate() {
        let views: Vec<View> = demo
            .cameras
            .iter()
            .zip(masks)
            .map(|(camera, mask)| View { camera, mask })
            .collect();
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
        let prior = if poses.is_empty() {
            None
        } else {
            Some(&predicted)
        };
        // From the prediction and from the last pose (a phase's end breaks the prediction);
        // the lower silhouette loss wins.
        let mut t = fit_pose(&views, &spoon, predicted, prior, &track_opts);
        if let Some(last) = poses.last() {
            let u = fit_pose(&views, &spoon, *last, prior, &track_opts);
            if u.loss < t.loss {
                t = u;
            }
        }
        poses.push(t.pose);
        losses.push(t.loss);
        progress(f + 1, demo.frames.len());
    }
    // The tracked path at every global step between the frames.
    let frames: Vec<(usize, Pose)> = demo
        .frames
        .iter()
        .map(|f| f.0)
        .zip(poses.iter().copied())
        .collect();
    let dense = join_frames(&frames);
    let lever = tool.shape.bounding_radius();
    let points: Vec<[DVec3; 2]> = dense.iter().map(|p| pose_points(p, lever)).collect();
    let th = fit_theta(
        sk,
        &[sk.theta, [0.0; 5]],
        &start,
        scene.simulation.dt,
        Scene::tool_bottom(tool),
        lever,
        &points,
        opts.theta_iterations,
    );
    Ok(DemoFit {
        poses,
        silhouette_loss: losses,
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
}

/// Scores a fit against the truth `demo make` wrote.
pub fn score(fit: &DemoFit, truth: &super::make::Truth) -> Score {
    let mut mm: Vec<f64> = Vec::new();
    let mut deg: Vec<f64> = Vec::new();
    for (p, (t, q)) in fit.poses.iter().zip(&truth.poses) {
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
    }
}
