//! `powderlab study demonstration`: synthetic demonstrations of the default scene's skill at
//! five Θ*, each with a demonstrator's spoon of other dimensions, filmed from two cameras with
//! pixel noise, tremor and a warped pace, and fitted back: pose error per frame, shape error
//! and Θ error; and the first demonstration fitted again from its front camera alone. Each
//! demonstration and its track are kept in its folder, so a rerun after a kill resumes, and a
//! rerun fits Θ to the kept tracks again (seconds) without tracking again.

use crate::lab::demo::fit::{fit_skill, score, track, DemoFit, FitOptions, Score, Tracked};
use crate::lab::demo::format;
use crate::lab::demo::make::{make, MakeOptions, Truth};
use crate::lab::demo::shape::dimensions;
use crate::lab::render::silhouette::reshaped;
use crate::lab::render::{self, Camera};
use crate::math::pose::Pose;
use crate::scene::Scene;
use crate::sim::{SimOptions, Simulation};
use crate::skills::Theta;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The Θ* of the study: spread over the box, none at a face.
pub const THETAS: [Theta; 5] = [
    Theta([0.4, -0.3, 0.5, -0.6, 0.2]),
    Theta([-0.5, 0.6, -0.2, 0.7, -0.4]),
    Theta([0.0, 0.0, 0.0, 0.0, 0.0]),
    Theta([0.7, 0.3, -0.6, -0.2, 0.6]),
    Theta([-0.3, -0.7, 0.3, 0.4, -0.7]),
];

/// The demonstrators' spoons: the scene's bowl radius, bowl depth and handle length scaled by
/// these (the third is the scene's own spoon).
pub const SPOON_SCALES: [[f64; 3]; 5] = [
    [1.1, 0.85, 1.15],
    [0.9, 1.15, 0.9],
    [1.0, 1.0, 1.0],
    [1.15, 1.1, 0.85],
    [0.85, 0.9, 1.1],
];

/// One fit's outcome.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Row {
    pub truth: Theta,
    pub fitted: Theta,
    /// The demonstrator's spoon and the fitted one: bowl radius, bowl depth, handle length (m).
    pub spoon_truth: [f64; 3],
    pub spoon_fit: [f64; 3],
    pub shape_pct: [f64; 3],
    /// Views the fit used.
    pub views: usize,
    pub pose_mm: [f64; 2],
    pub pose_deg: [f64; 2],
    pub theta_mean: f64,
    pub theta_max: f64,
    pub frames: usize,
    pub fit_s: f64,
}

/// How the demonstrations are filmed.
pub struct Setup {
    pub size: (u32, u32),
    pub every: usize,
    pub noise: f64,
}

/// What a tracking leaves in its folder, so that a rerun fits Θ again without tracking again.
#[derive(Serialize, Deserialize)]
struct TrackFile {
    poses: Vec<([f64; 3], [f64; 4])>,
    silhouette_loss: Vec<f64>,
    spoon: [f64; 3],
    rounds: Vec<f64>,
    track_s: f64,
}

/// A fit's row: the track read back from `path` when an earlier run wrote it (else tracked
/// and written there), and Θ fitted to it.
pub(crate) fn fitted(
    path: &Path,
    demo: &format::Demo,
    scene: &Scene,
    truth: &Truth,
) -> anyhow::Result<Row> {
    let robot = robot_spoon(scene)?;
    let opts = FitOptions::default();
    let kept = std::fs::read_to_string(path)
        .ok()
        .and_then(|t| serde_json::from_str::<TrackFile>(&t).ok())
        .filter(|t| t.poses.len() == demo.frames.len());
    let (tracked, track_s) = match kept {
        Some(t) => {
            let d = dimensions(&robot);
            let tracked = Tracked {
                poses: t
                    .poses
                    .iter()
                    .map(|(x, q)| Pose {
                        translation: glam::DVec3::from_array(*x),
                        rotation: glam::DQuat::from_array(*q),
                    })
                    .collect(),
                silhouette_loss: t.silhouette_loss,
                spoon: reshaped(&robot, std::array::from_fn(|k| t.spoon[k] - d[k])),
                rounds: t.rounds,
            };
            (tracked, t.track_s)
        }
        None => {
            let t0 = std::time::Instant::now();
            let tracked = track(demo, scene, &opts, |_, _| {})?;
            let track_s = t0.elapsed().as_secs_f64();
            let file = TrackFile {
                poses: tracked
                    .poses
                    .iter()
                    .map(|p| (p.translation.to_array(), p.rotation.to_array()))
                    .collect(),
                silhouette_loss: tracked.silhouette_loss.clone(),
                spoon: dimensions(&tracked.spoon),
                rounds: tracked.rounds.clone(),
                track_s,
            };
            crate::util::write_atomic(path, serde_json::to_string(&file)?.as_bytes())?;
            (tracked, track_s)
        }
    };
    let t0 = std::time::Instant::now();
    let th = fit_skill(&tracked, scene, &opts)?;
    let f = DemoFit {
        track: tracked,
        theta: th.theta,
        path_loss: th.loss,
    };
    let s: Score = score(&f, truth, &robot);
    Ok(Row {
        truth: truth.theta,
        fitted: f.theta,
        spoon_truth: truth.spoon.unwrap_or_else(|| dimensions(&robot)),
        spoon_fit: dimensions(&f.track.spoon),
        shape_pct: s.shape_pct,
        views: demo.cameras.len(),
        pose_mm: s.pose_mm,
        pose_deg: s.pose_deg,
        theta_mean: s.theta_mean,
        theta_max: s.theta_max,
        frames: demo.frames.len(),
        fit_s: track_s + t0.elapsed().as_secs_f64(),
    })
}

/// The demonstration as its first `n` cameras alone filmed it.
fn first_views(demo: &format::Demo, n: usize) -> format::Demo {
    format::Demo {
        dir: demo.dir.clone(),
        fps: demo.fps,
        cameras: demo.cameras[..n].to_vec(),
        frames: demo
            .frames
            .iter()
            .map(|(k, m)| (*k, m[..n].to_vec()))
            .collect(),
        images: demo.images.iter().map(|i| i[..n].to_vec()).collect(),
    }
}

/// The study's two cameras, framing `scene` from the front and the side.
pub fn cameras(scene: &Scene, setup: &Setup) -> anyhow::Result<Vec<Camera>> {
    let mut sim = Simulation::new(scene, &SimOptions::default())?;
    let (lo, hi) = render::scene_box(&mut sim);
    Ok(vec![
        Camera::framing_at("front", lo, hi, setup.size.0, setup.size.1, 20.0),
        Camera::framing_at("side", lo, hi, setup.size.0, setup.size.1, 100.0),
    ])
}

/// The robot's spoon: the scene's skill tool.
fn robot_spoon(scene: &Scene) -> anyhow::Result<crate::math::sdf::Spoon> {
    scene.colliders[crate::rollout::skill_tool(scene)?]
        .shape
        .spoon()
        .ok_or_else(|| anyhow::anyhow!("the study's scene tracks a spoon"))
}

/// A demonstration of `theta` in `d` with the robot's spoon scaled by `scale` and filming
/// seed `seed`: read back when an earlier run made it (its truth.json is written last), else
/// made. Returns it and its truth.
pub(crate) fn demonstrated(
    scene: &Scene,
    d: &Path,
    theta: Theta,
    scale: [f64; 3],
    seed: u64,
    cameras: &[Camera],
    setup: &Setup,
) -> anyhow::Result<(format::Demo, Truth)> {
    let made = std::fs::read_to_string(d.join("truth.json"))
        .ok()
        .and_then(|t| serde_json::from_str::<Truth>(&t).ok());
    let truth = match made {
        Some(t) => t,
        None => {
            crate::util::create_output_dir(d, "--out")?;
            let robot = robot_spoon(scene)?;
            let spoon = reshaped(
                &robot,
                std::array::from_fn(|j| (scale[j] - 1.0) * dimensions(&robot)[j]),
            );
            let opts = MakeOptions {
                theta,
                cameras: cameras.to_vec(),
                every: setup.every,
                tremor: 0.0003,
                warp: 0.3,
                noise: setup.noise,
                masks: true,
                seed,
                spoon: Some(spoon),
            };
            make(scene, &opts, d, |_, _| {})?
        }
    };
    Ok((format::load(d).map_err(anyhow::Error::msg)?, truth))
}

/// Runs (or resumes) the study of `scene` in `dir`: a row per Θ* (two views), then Θ*₀'s
/// demonstration from one view.
pub fn run(
    scene: &Scene,
    dir: &Path,
    setup: &Setup,
    progress: &dyn Fn(usize),
) -> anyhow::Result<Vec<Row>> {
    let cameras = cameras(scene, setup)?;
    let mut rows = Vec::new();
    for (k, theta) in THETAS.iter().enumerate() {
        let d = dir.join(format!("theta{k}"));
        let (demo, truth) = demonstrated(
            scene,
            &d,
            *theta,
            SPOON_SCALES[k],
            1 + k as u64,
            &cameras,
            setup,
        )?;
        rows.push(fitted(&d.join("track.json"), &demo, scene, &truth)?);
        if k == 0 {
            rows.push(fitted(
                &d.join("track_one_view.json"),
                &first_views(&demo, 1),
                scene,
                &truth,
            )?);
        }
        progress(k + 1);
    }
    Ok(rows)
}

/// The results page.
pub fn report(rows: &[Row], scene: &str, setup: &Setup, command: &str, machine: &str) -> String {
    let mut md = format!(
        "# Learning the skill from a demonstration\n\nRegenerate with `{command}` ({machine}).\n\n\
         Synthetic demonstrations of `{scene}`'s skill at five Θ*. A hand follows the skill's path with its own pace (warp 0.3) and a 0.3 mm tremor, holding a spoon of its own (the scene's bowl radius, bowl depth and handle length scaled by 0.85–1.15; the third is the scene's spoon), carried over through the bowls' frames with the scoop depth scaled by the bowl depth. The powder moves under its spoon, and two cameras (front and side, {}×{} pixels) film a frame every {} steps with Gaussian pixel noise σ = {}. The masks mark the spoon, and powder as unknown (it may hide the spoon). `demo fit` tracks the spoon's pose in every frame, fits its shape jointly with every frame's pose, carries the frames over to the scene's spoon and fits Θ to them. The tracks are kept in the study's folder: a rerun fits Θ again without tracking again. Fit seconds are the tracking's and the Θ fit's, on this machine.\n\n\
         | Θ* | Θ_demo | Θ error, mean | largest | pose error median | 95th percentile | shape error (bowl radius, depth, handle) | frames | fit (s) |\n|---|---|---|---|---|---|---|---|---|\n",
        setup.size.0, setup.size.1, setup.every, setup.noise
    );
    let f = |t: &[f64; 5]| {
        t.iter()
            .map(|x| format!("{x:.3}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let two: Vec<&Row> = rows.iter().filter(|r| r.views == 2).collect();
    // The cells both tables share: pose error (median, 95th percentile) and shape error.
    let errors = |r: &Row| {
        format!(
            "{:.2} mm, {:.2}° | {:.2} mm, {:.2}° | {:.1} %, {:.1} %, {:.1} %",
            r.pose_mm[0],
            r.pose_deg[0],
            r.pose_mm[1],
            r.pose_deg[1],
            r.shape_pct[0],
            r.shape_pct[1],
            r.shape_pct[2]
        )
    };
    for r in &two {
        md += &format!(
            "| {} | {} | {:.4} | {:.4} | {} | {} | {:.0} |\n",
            f(&r.truth),
            f(&r.fitted),
            r.theta_mean,
            r.theta_max,
            errors(r),
            r.frames,
            r.fit_s
        );
    }
    let n = two.len().max(1) as f64;
    let mean = two.iter().map(|r| r.theta_mean).sum::<f64>() / n;
    let worst = two.iter().map(|r| r.theta_max).fold(0.0, f64::max);
    let shape = two.iter().flat_map(|r| r.shape_pct).sum::<f64>() / (3.0 * n);
    md += &format!(
        "\nOver the five: Θ error {mean:.4} on average per component (the target is at most 0.05: {}), {worst:.4} at worst; shape error {shape:.1} % on average.\n",
        if mean <= 0.05 { "met" } else { "missed" }
    );
    md += "\n## One view against two\n\nThe first demonstration fitted from its front camera alone, and from both.\n\n\
           | views | pose error median | 95th percentile | shape error (bowl radius, depth, handle) | Θ error, mean | fit (s) |\n|---|---|---|---|---|---|\n";
    let first = rows.first().map(|r| r.truth);
    for r in rows.iter().filter(|r| Some(r.truth) == first) {
        md += &format!(
            "| {} | {} | {:.4} | {:.0} |\n",
            r.views,
            errors(r),
            r.theta_mean,
            r.fit_s
        );
    }
    md
}
