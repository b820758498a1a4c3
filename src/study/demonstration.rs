//! `powderlab study demonstration`: synthetic demonstrations of the default scene's skill at
//! five Θ*, filmed from two cameras with pixel noise, tremor and a warped pace, and fitted
//! back: pose error per frame and Θ error. Each Θ*'s result is kept in its folder, so a rerun
//! after a kill resumes.

use crate::demo::fit::{fit, score, FitOptions, Score};
use crate::demo::format;
use crate::demo::make::{make, MakeOptions, Truth};
use crate::render::{self, Camera};
use crate::scene::Scene;
use crate::sim::{SimOptions, Simulation};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The Θ* of the study: spread over the box, none at a face.
pub const THETAS: [[f64; 5]; 5] = [
    [0.4, -0.3, 0.5, -0.6, 0.2],
    [-0.5, 0.6, -0.2, 0.7, -0.4],
    [0.0, 0.0, 0.0, 0.0, 0.0],
    [0.7, 0.3, -0.6, -0.2, 0.6],
    [-0.3, -0.7, 0.3, 0.4, -0.7],
];

/// One Θ*'s outcome.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Row {
    pub truth: [f64; 5],
    pub fitted: [f64; 5],
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

/// Runs (or resumes) the study of `scene` in `dir`.
pub fn run(
    scene: &Scene,
    dir: &Path,
    setup: &Setup,
    progress: &dyn Fn(usize),
) -> anyhow::Result<Vec<Row>> {
    let mut sim = Simulation::new(scene, &SimOptions::default())?;
    let (lo, hi) = render::scene_box(&mut sim);
    let cameras = vec![
        Camera::framing_at("front", lo, hi, setup.size.0, setup.size.1, 20.0),
        Camera::framing_at("side", lo, hi, setup.size.0, setup.size.1, 100.0),
    ];
    let mut rows = Vec::new();
    for (k, theta) in THETAS.iter().enumerate() {
        let d = dir.join(format!("theta{k}"));
        let done = d.join("result.json");
        if let Ok(text) = std::fs::read_to_string(&done) {
            if let Ok(row) = serde_json::from_str::<Row>(&text) {
                rows.push(row);
                progress(k + 1);
                continue;
            }
        }
        crate::util::create_output_dir(&d, "--out")?;
        let opts = MakeOptions {
            theta: *theta,
            cameras: cameras.clone(),
            every: setup.every,
            tremor: 0.0003,
            warp: 0.3,
            noise: setup.noise,
            masks: true,
            seed: 1 + k as u64,
        };
        let truth: Truth = make(scene, &opts, &d, |_, _| {})?;
        let demo = format::load(&d).map_err(anyhow::Error::msg)?;
        let t0 = std::time::Instant::now();
        let f = fit(&demo, scene, &FitOptions::default(), |_, _| {})?;
        let s: Score = score(&f, &truth);
        let row = Row {
            truth: *theta,
            fitted: f.theta,
            pose_mm: s.pose_mm,
            pose_deg: s.pose_deg,
            theta_mean: s.theta_mean,
            theta_max: s.theta_max,
            frames: demo.frames.len(),
            fit_s: t0.elapsed().as_secs_f64(),
        };
        crate::util::write_atomic(&done, serde_json::to_string_pretty(&row)?.as_bytes())?;
        rows.push(row);
        progress(k + 1);
    }
    Ok(rows)
}

/// The results page.
pub fn report(rows: &[Row], scene: &str, setup: &Setup, command: &str, machine: &str) -> String {
    let mut md = format!(
        "# Learning the skill from a demonstration\n\nRegenerate with `{command}` ({machine}).\n\n\
         Synthetic demonstrations of `{scene}`'s skill at five Θ*: a hand follows the skill's path with its own pace (warp 0.3) and a 0.3 mm tremor, the powder moves under its spoon, and two cameras (front and side, {}×{} pixels) film a frame every {} steps with Gaussian pixel noise σ = {}. The masks mark the spoon, and powder as unknown (it may hide the spoon). `demo fit` tracks the spoon's pose in every frame and fits Θ to the tracked path. The spoon's shape is the scene's (not fitted).\n\n\
         | Θ* | Θ_demo | Θ error, mean | largest | pose error median | 95th percentile | frames | fit (s) |\n|---|---|---|---|---|---|---|---|\n",
        setup.size.0, setup.size.1, setup.every, setup.noise
    );
    let f = |t: &[f64; 5]| {
        t.iter()
            .map(|x| format!("{x:.3}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    for r in rows {
        md += &format!(
            "| {} | {} | {:.4} | {:.4} | {:.2} mm, {:.2}° | {:.2} mm, {:.2}° | {} | {:.0} |\n",
            f(&r.truth),
            f(&r.fitted),
            r.theta_mean,
            r.theta_max,
            r.pose_mm[0],
            r.pose_deg[0],
            r.pose_mm[1],
            r.pose_deg[1],
            r.frames,
            r.fit_s
        );
    }
    let n = rows.len().max(1) as f64;
    let mean = rows.iter().map(|r| r.theta_mean).sum::<f64>() / n;
    let worst = rows.iter().map(|r| r.theta_max).fold(0.0, f64::max);
    md += &format!(
        "\nOver the five: Θ error {mean:.4} on average per component (the target is at most 0.05: {}), {worst:.4} at worst.\n",
        if mean <= 0.05 { "met" } else { "missed" }
    );
    md
}
