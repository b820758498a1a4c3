//! The demonstration as a warm start (`study demonstration`'s last part): does an optimisation
//! started from Θ_demo reach a lower dose error than one started from a random Θ_init, at the
//! same budget, over paired seeds?
//!
//! 1. **The expert.** A demonstrator shows a skill that works. It stands in here as the best of
//!    [`EXPERT_POINTS`] scrambled Sobol points of [−1, 1]⁵ by dose error: a skill a person
//!    would call good, found without the optimiser under test.
//! 2. **Its demonstration**, made and fitted as the study's others are (a spoon of its own,
//!    two cameras, noise, tremor and a warped pace), gives Θ_demo.
//! 3. **The race.** CMA-ES (the `cmaes` method, its default settings) runs [`SEEDS`] seeds of
//!    [`BUDGET`] rollouts twice: each seed from its random Θ_init, and each from Θ_demo (the
//!    sampling follows the seed either way). Each is scored by the dose error of its
//!    lowest-loss rollout; a one-sided Wilcoxon signed-rank test over the paired seeds asks
//!    whether the warm start's is smaller.
//!
//! Every step keeps its result in `dir` (the races their journals), so a killed run resumes.

use super::demonstration::{cameras, demonstrated, fitted, Setup};
use crate::lab::optim::problem::Problem;
use crate::lab::optim::report::curve;
use crate::lab::optim::study::optimizers::TAPE_BUDGET;
use crate::lab::optim::{self, sobol_thetas, Method};
use crate::lab::stats::wilcoxon_less;
use crate::scene::Scene;
use crate::skills::Theta;
use serde::Serialize;
use std::path::Path;

/// Sobol points the expert's skill is chosen from.
pub const EXPERT_POINTS: usize = 32;
/// Paired seeds of the race.
pub const SEEDS: usize = 10;
/// Rollouts per seed.
pub const BUDGET: usize = 10;

/// The race's outcome.
#[derive(Clone, Debug, Serialize)]
pub struct WarmStart {
    pub expert: Theta,
    /// |dose error| of the expert's skill and of Θ_demo itself, in `unit`.
    pub expert_error: f64,
    pub demo_theta: Theta,
    pub demo_error: f64,
    /// Per seed, the dose error after [`BUDGET`] rollouts from Θ_demo and from Θ_init.
    pub from_demo: Vec<f64>,
    pub from_random: Vec<f64>,
    /// One-sided Wilcoxon p of "from Θ_demo is smaller".
    pub p: Option<f64>,
    pub unit: String,
}

/// The |dose error| of Θ on `problem`.
fn dose_error(problem: &Problem, theta: Theta) -> anyhow::Result<f64> {
    Ok(problem.evaluate(theta, false, true)?.indicator.abs())
}

/// One CMA-ES run of the race in `out`, resumed when it was started before; the dose error of
/// each seed's lowest-loss rollout.
fn race(
    problem: &Problem,
    scene: &Scene,
    out: &Path,
    init: Option<Theta>,
) -> anyhow::Result<Vec<f64>> {
    let settings = optim::Settings {
        first_seed: 0,
        scene_hash: scene.fingerprint(),
        methods: vec![Method::Cmaes],
        epochs: BUDGET,
        seeds: SEEDS,
        rmsprop: Default::default(),
        cmaes: Default::default(),
        sac: Default::default(),
        smoothing: Default::default(),
        hybrid: Default::default(),
        equal_compute: false,
        tape_budget: TAPE_BUDGET,
        init,
    };
    let r = optim::run(
        problem,
        &optim::Options {
            settings,
            out: out.to_path_buf(),
            resume: out.join("settings.json").exists(),
            quiet: true,
        },
    )?;
    // CMA-ES runs forward rollouts only: the backward multiple does not enter.
    Ok((0..SEEDS)
        .map(|k| {
            r.records
                .get(&(Method::Cmaes, k))
                .and_then(|l| curve(l, 0.0).last().map(|p| p.best_indicator.abs()))
                .unwrap_or(f64::NAN)
        })
        .collect())
}

/// Runs (or resumes) the race of `scene` in `dir`.
pub fn run(scene: &Scene, dir: &Path, setup: &Setup) -> anyhow::Result<WarmStart> {
    crate::util::create_output_dir(dir, "--out")?;
    let problem = Problem::new(scene.clone(), TAPE_BUDGET)?;
    let unit = match scene.task.as_ref().map(|t| &t.target_value) {
        Some(crate::scene::TargetValue::Grams(_)) => "g",
        _ => "particles",
    }
    .to_string();
    // 1. The expert's skill (kept, as the search takes a minute).
    let expert_path = dir.join("expert.json");
    let (expert, expert_error): (Theta, f64) = match std::fs::read_to_string(&expert_path)
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok())
    {
        Some(e) => e,
        None => {
            let mut best = (Theta([0.0; 5]), f64::INFINITY);
            for theta in sobol_thetas(EXPERT_POINTS, 7) {
                let e = dose_error(&problem, theta)?;
                if e < best.1 {
                    best = (theta, e);
                }
            }
            crate::util::write_atomic(&expert_path, serde_json::to_string(&best)?.as_bytes())?;
            best
        }
    };
    // 2. Its demonstration, fitted.
    let d = dir.join("expert_demo");
    let (demo, truth) = demonstrated(
        scene,
        &d,
        expert,
        [1.05, 0.9, 1.1],
        11,
        &cameras(scene, setup)?,
        setup,
    )?;
    let row = fitted(&d.join("track.json"), &demo, scene, &truth)?;
    let demo_error = dose_error(&problem, row.fitted)?;
    // 3. The race.
    // A Θ_demo of its own folder: a rerun that fits Θ otherwise races afresh.
    let tag = crate::util::fnv1a(&format!("{:?}", row.fitted));
    let from_demo = race(
        &problem,
        scene,
        &dir.join(format!("from_demo_{tag}")),
        Some(row.fitted),
    )?;
    let from_random = race(&problem, scene, &dir.join("from_random"), None)?;
    let w = WarmStart {
        expert,
        expert_error,
        demo_theta: row.fitted,
        demo_error,
        p: wilcoxon_less(&from_demo, &from_random),
        from_demo,
        from_random,
        unit,
    };
    Ok(w)
}

/// The page's section.
pub fn report(w: &WarmStart) -> String {
    let f = |t: &[f64; 5]| {
        t.iter()
            .map(|x| format!("{x:.3}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let stats = |v: &[f64]| {
        let n = v.len() as f64;
        let m = v.iter().sum::<f64>() / n;
        let sd = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0).max(1.0)).sqrt();
        (m, sd)
    };
    let ((dm, ds), (rm, rs)) = (stats(&w.from_demo), stats(&w.from_random));
    let wins = w
        .from_demo
        .iter()
        .zip(&w.from_random)
        .filter(|(a, b)| a < b)
        .count();
    let u = &w.unit;
    let mut md = format!(
        "\n## The demonstration as a warm start\n\n\
         An expert's skill (the best of {EXPERT_POINTS} Sobol points by dose error: Θ = ({}), {:.3} {u} off) is demonstrated with a spoon of its own and fitted back: Θ_demo = ({}), {:.3} {u} off. CMA-ES then runs {SEEDS} paired seeds of {BUDGET} rollouts from Θ_demo (`optimize --init fit.json --method cmaes`) and from each seed's random Θ_init.\n\n\
         | start | dose error after {BUDGET} rollouts ({u}), mean ± std | seeds where it is lower |\n|---|---|---|\n\
         | Θ_demo | {dm:.3} ± {ds:.3} | {wins} of {SEEDS} |\n\
         | random Θ_init | {rm:.3} ± {rs:.3} | {} of {SEEDS} |\n\n",
        f(&w.expert),
        w.expert_error,
        f(&w.demo_theta),
        w.demo_error,
        w.from_demo
            .iter()
            .zip(&w.from_random)
            .filter(|(a, b)| b < a)
            .count(),
    );
    md += &match w.p {
        Some(p) => format!(
            "One-sided Wilcoxon signed-rank test of \"from Θ_demo is lower\": p = {p:.4} ({}).\n",
            if p < crate::lab::stats::ALPHA {
                "the warm start wins at the 5 % level"
            } else {
                "not significant at the 5 % level"
            }
        ),
        None => "Every seed ended at the same dose error from both starts: no test.\n".into(),
    };
    md
}
