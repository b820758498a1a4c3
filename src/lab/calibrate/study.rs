//! `powderlab study calibration`: does calibration through the adjoint recover known parameters
//! from noisy synthetic observations, and does it beat CMA-ES at equal compute?
//!
//! Two recovery cases, each over five true values and paired starts:
//! - **friction angle** from the final pile of a column collapse
//!   (`scenes/calibration_collapse.ron`), seen as a height map with 1 mm noise;
//! - **floor friction** from the final surface of a layer of sand thrown along the floor
//!   (`scenes/calibration_slide.ron`), same noise.
//!
//! For each (true value, start) pair, three methods get the same compute (a backward pass counted
//! at its measured cost in forward rollouts): Adam and the trust-region quasi-Newton method
//! ([`crate::lab::calibrate::trust`]) on the adjoint gradient, and CMA-ES on the forward loss. Each is
//! scored by the parameter error of its rollout of lowest loss. The starts are uniform in the
//! middle of the search range, drawn from the pair's seed, and shared by the methods. A third
//! case fits friction angle, Young's modulus and floor friction together on the collapse and
//! reports the curvature: which of them one pile pins down.
//!
//! A fourth case fits one friction angle per layer of a layered bed from the surface seen
//! through its collapse ([`layers`]): a calibration with several parameters.
//!
//! Every rollout goes to `rollouts.jsonl` as it finishes ([`crate::lab::calibrate::Journal`]), so a
//! killed study resumes. The page is written by [`report`].

pub mod layers;
mod report;

use crate::lab::calibrate::observation::Observed;
use crate::lab::calibrate::{
    self, params, AdamConfig, Calibration, Eval, Identifiability, Journal, TrustConfig,
    CURVATURE_STEP,
};
use crate::scene::Scene;
use crate::util::SplitMix64;
use rayon::prelude::*;
pub use report::report;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// Noise on every observed height (m): the 1 mm.
pub const HEIGHT_NOISE: f64 = 1e-3;

/// The camera's pixel, in particle spacings (1.25 mm on the shipped scenes): a depth camera a
/// few decimetres above a lab bench resolves about a millimetre.
pub const PIXEL_PER_SPACING: f64 = 1.0;

/// The observation's pixel on `scene`.
fn pixel(scene: &Scene) -> f64 {
    PIXEL_PER_SPACING * scene.particle_spacing(&scene.bodies[0])
}

/// A recovery case.
pub struct Case {
    pub name: &'static str,
    pub scene: &'static str,
    pub param: &'static str,
    pub truths: [f64; 5],
    /// The starts are uniform in this range.
    pub starts: (f64, f64),
    /// The acceptance's tolerance on the parameter error.
    pub tolerance: f64,
    pub unit: &'static str,
}

pub const CASES: [Case; 2] = [
    Case {
        name: "friction angle from a collapsed column's pile",
        scene: "scenes/calibration_collapse.ron",
        param: "friction_deg",
        truths: [20.0, 26.0, 32.0, 38.0, 45.0],
        starts: (15.0, 50.0),
        tolerance: 1.0,
        unit: "°",
    },
    Case {
        name: "floor friction from a sliding layer's final surface",
        scene: "scenes/calibration_slide.ron",
        param: "floor.friction",
        truths: [0.2, 0.3, 0.4, 0.5, 0.6],
        starts: (0.15, 0.75),
        tolerance: 0.05,
        unit: "",
    },
];

/// The methods compared, as the journal keys them: Adam and the trust-region quasi-Newton
/// method on the adjoint, CMA-ES on the forward loss.
pub const METHODS: [&str; 3] = ["adam", "bfgs", "cmaes"];

/// One (case, truth, start) pair's result for one method.
#[derive(Clone, Debug, Serialize)]
pub struct Run {
    pub case: usize,
    pub truth: f64,
    pub seed: usize,
    pub method: String,
    pub start: f64,
    pub fitted: f64,
    pub error: f64,
    /// (compute so far, parameter error of the best rollout so far).
    pub curve: Vec<(f64, f64)>,
    pub wall_s: f64,
}

/// A journal shared by the parallel runs: lookups and appends under the lock, rollouts outside.
struct Shared<'a> {
    journal: &'a Mutex<Journal>,
    progress: &'a (dyn Fn(f64) + Sync),
}

impl Shared<'_> {
    fn eval(
        &self,
        cal: &Calibration,
        key: &str,
        i: usize,
        u: &[f64],
        grad: bool,
    ) -> anyhow::Result<Eval> {
        if let Some(e) = self.journal.lock().expect("lock").lookup(key, i, u, grad) {
            (self.progress)(e.cost);
            return Ok(e);
        }
        let e = cal.evaluate(u, grad)?;
        self.journal.lock().expect("lock").record(key, i, &e)?;
        (self.progress)(e.cost);
        Ok(e)
    }
}

/// The calibration problem of `case` at `truth`: the synthetic observation (seeded noise) and
/// the scene, whose fitted parameter is then set by the method's start.
fn problem(
    case: &Case,
    truth: f64,
    threads: Option<usize>,
    backward_cost: f64,
) -> anyhow::Result<Calibration> {
    let mut scene = Scene::load(case.scene)?;
    let fit = params::parse(&scene, &[case.param.to_string()], &[]).map_err(anyhow::Error::msg)?;
    fit[0].apply(&mut scene, truth);
    let steps = scene.simulation.steps.unwrap_or(0);
    let seed = (truth * 1e6) as u64 ^ 0xCA11;
    let obs = calibrate::observe(
        &scene,
        steps,
        true,
        pixel(&scene),
        HEIGHT_NOISE,
        seed,
        threads,
    )?;
    let observed = Observed {
        path: PathBuf::from(format!("synthetic {}={truth}", case.param)),
        step: None,
        body: None,
        what: obs,
    };
    let mut cal = Calibration::new(&scene, fit, &[observed], None).map_err(anyhow::Error::msg)?;
    cal.threads = threads;
    cal.backward_cost = backward_cost;
    Ok(cal)
}

/// Each case's backward cost in forward rollouts, measured once on one thread at the middle
/// true value and kept in `dir/backward_cost.json`, so that a resumed study counts as the first
/// run did.
fn backward_costs(dir: &Path) -> anyhow::Result<Vec<f64>> {
    let path = dir.join("backward_cost.json");
    if let Some(v) = std::fs::read_to_string(&path)
        .ok()
        .and_then(|t| serde_json::from_str::<Vec<f64>>(&t).ok())
        .filter(|v| v.len() == CASES.len())
    {
        return Ok(v);
    }
    let mut v = Vec::new();
    for case in &CASES {
        let cal = problem(case, case.truths[2], Some(1), 0.0)?;
        v.push(calibrate::measure_backward_cost(&cal, &cal.start(), 3)?);
    }
    crate::util::write_atomic(&path, serde_json::to_string(&v)?.as_bytes())?;
    Ok(v)
}

/// Keeps `settings` in `dir/name`, or refuses a folder whose journal was made with others (the
/// journal keys rollouts by method, index and point, not by the observation).
fn same_settings(dir: &Path, name: &str, settings: &serde_json::Value) -> anyhow::Result<()> {
    let path = dir.join(name);
    match std::fs::read_to_string(&path) {
        Ok(t) if serde_json::from_str::<serde_json::Value>(&t).ok().as_ref() != Some(settings) => {
            anyhow::bail!(
                "--out {}: holds a calibration study with other observations; delete it or choose another --out",
                dir.parent().unwrap_or(dir).display()
            )
        }
        Ok(_) => Ok(()),
        Err(_) => Ok(crate::util::write_atomic(
            &path,
            settings.to_string().as_bytes(),
        )?),
    }
}

/// The start of pair `seed`: uniform in the case's start range.
pub fn start(case: &Case, truth: f64, seed: usize) -> f64 {
    let mut rng = SplitMix64(0x57A7 + seed as u64 * 7919 + (truth * 1e3) as u64);
    rng.uniform_in(case.starts.0, case.starts.1)
}

fn score(trace: &[Eval], truth: f64) -> (f64, Vec<(f64, f64)>) {
    let (mut c, mut best, mut value) = (0.0, f64::INFINITY, f64::NAN);
    let mut curve = Vec::new();
    for e in trace {
        c += e.cost;
        if e.loss < best {
            best = e.loss;
            value = e.values[0];
        }
        curve.push((c, (value - truth).abs()));
    }
    (value, curve)
}

/// Runs every case, truth, start and method (resuming from `dir/rollouts.jsonl`).
pub fn run(
    dir: &Path,
    seeds: usize,
    budget: f64,
    threads: Option<usize>,
    progress: &(dyn Fn(f64) + Sync),
) -> anyhow::Result<Outcome> {
    crate::util::create_output_dir(dir, "--out")?;
    // The journal keys rollouts by method, index and point, not by the observation: a folder
    // made with other observations is refused rather than replayed.
    let settings = serde_json::json!({
        "noise": HEIGHT_NOISE,
        "pixel_per_spacing": PIXEL_PER_SPACING,
        "scenes": CASES.iter().map(|c| std::fs::read_to_string(c.scene).unwrap_or_default()).collect::<Vec<_>>(),
        "truths": CASES.iter().map(|c| c.truths.to_vec()).collect::<Vec<_>>(),
    });
    same_settings(dir, "settings.json", &settings)?;
    // The layered bed's, apart, so that the single-parameter cases' folder stays valid.
    let layer_settings = serde_json::json!({
        "noise": HEIGHT_NOISE,
        "pixel_per_spacing": PIXEL_PER_SPACING,
        "scene": std::fs::read_to_string(layers::SCENE).unwrap_or_default(),
        "truths": layers::TRUTHS,
        "starts": layers::STARTS,
        "frame_every": layers::FRAME_EVERY,
    });
    same_settings(dir, "settings_layers.json", &layer_settings)?;
    let journal = Mutex::new(Journal::open(&dir.join("rollouts.jsonl"))?);
    let shared = Shared {
        journal: &journal,
        progress,
    };
    let costs = backward_costs(dir)?;
    let mut jobs = Vec::new();
    for (ci, case) in CASES.iter().enumerate() {
        for &truth in &case.truths {
            for seed in 0..seeds {
                for method in METHODS {
                    jobs.push((ci, truth, seed, method));
                }
            }
        }
    }
    let runs = jobs
        .par_iter()
        .map(|&(ci, truth, seed, method)| -> anyhow::Result<Run> {
            let case = &CASES[ci];
            let mut cal = problem(case, truth, threads, costs[ci])?;
            let s = start(case, truth, seed);
            cal.params[0].apply(&mut cal.scene, s);
            let u0 = cal.start();
            let key = format!("{}/{truth}/{seed}/{method}", case.param);
            let t0 = std::time::Instant::now();
            let trace = if method == "adam" {
                calibrate::adam(&u0, budget, AdamConfig::default(), |i, u, g| {
                    shared.eval(&cal, &key, i, u, g)
                })?
            } else if method == "bfgs" {
                calibrate::trust_region(
                    &u0,
                    budget,
                    TrustConfig::for_dims(1),
                    0xCA1 + seed as u64,
                    |i, u, g| shared.eval(&cal, &key, i, u, g),
                )?
            } else {
                calibrate::cmaes(
                    &u0,
                    budget.floor() as usize,
                    0xCA1 + seed as u64,
                    |i, u, g| shared.eval(&cal, &key, i, u, g),
                )?
            };
            let (fitted, curve) = score(&trace, truth);
            Ok(Run {
                case: ci,
                truth,
                seed,
                method: method.into(),
                start: s,
                fitted,
                error: (fitted - truth).abs(),
                curve,
                wall_s: t0.elapsed().as_secs_f64(),
            })
        })
        .collect::<anyhow::Result<Vec<Run>>>()?;
    // The joint fit and its curvature: one pile, three parameters.
    let joint = {
        let mut scene = Scene::load(CASES[0].scene)?;
        let names: Vec<String> = ["friction_deg", "youngs_modulus", "floor.friction"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        let fit = params::parse(&scene, &names, &[]).map_err(anyhow::Error::msg)?;
        let steps = scene.simulation.steps.unwrap_or(0);
        let obs = calibrate::observe(&scene, steps, true, pixel(&scene), HEIGHT_NOISE, 7, None)?;
        let observed = Observed {
            path: PathBuf::from("synthetic joint"),
            step: None,
            body: None,
            what: obs,
        };
        // Start off the truth in every parameter.
        fit[0].apply(&mut scene, 36.0);
        fit[1].apply(&mut scene, 1.5e5);
        fit[2].apply(&mut scene, 0.35);
        let mut cal =
            Calibration::new(&scene, fit, &[observed], None).map_err(anyhow::Error::msg)?;
        // It runs alone after the pairs: on every worker.
        cal.threads = None;
        cal.backward_cost = costs[0];
        let u0 = cal.start();
        let trace = calibrate::trust_region(
            &u0,
            2.0 * budget,
            TrustConfig::for_dims(cal.params.len()),
            0xCA1,
            |i, u, g| shared.eval(&cal, "joint/bfgs", i, u, g),
        )?;
        let best = calibrate::lowest(&trace).expect("a rollout").clone();
        // The curvature at the truth: what the observation pins down, whatever the optimiser
        // reached.
        let truth = cal.to_unit(&[30.0, 5.0e4, 0.5]);
        let mut k = 0;
        let id = calibrate::identifiability(&cal, &truth, CURVATURE_STEP, |u| {
            let e = shared.eval(&cal, "joint/curvature", k, u, false);
            k += 1;
            e
        })?;
        Some((cal, best, id))
    };
    // The loss's grain: gradient rollouts every 0.1° across two degrees below a true 26°.
    let grain = {
        let cal = problem(&CASES[0], GRAIN.0, None, costs[0])?;
        let mut pts = Vec::new();
        for k in 0..GRAIN.3 {
            let v = GRAIN.1 + (GRAIN.2 - GRAIN.1) * k as f64 / (GRAIN.3 - 1) as f64;
            let u = [cal.params[0].to_unit(v)];
            let e = shared.eval(&cal, "grain", k, &u, true)?;
            // Per degree, not per unit coordinate.
            let g = e.grad.as_ref().map_or(f64::NAN, |g| g[0]) / cal.params[0].dvalue_du(u[0]);
            pts.push((v, e.loss, g));
        }
        pts
    };
    // The layered bed: its own backward cost (kept apart, so that the single-parameter cases
    // replay as they ran).
    let layer_cost = {
        let path = dir.join("backward_cost_layers.json");
        match std::fs::read_to_string(&path)
            .ok()
            .and_then(|t| serde_json::from_str::<f64>(&t).ok())
        {
            Some(c) => c,
            None => {
                let (cal, _, _) = layers::problem(0, Some(1), 0.0)?;
                let c = calibrate::measure_backward_cost(&cal, &cal.start(), 3)?;
                crate::util::write_atomic(&path, serde_json::to_string(&c)?.as_bytes())?;
                c
            }
        }
    };
    let layers = layers::run(
        &shared,
        layers::PAIRS_PER_SEED * seeds,
        budget,
        threads,
        layer_cost,
    )?;
    Ok(Outcome {
        runs,
        joint,
        costs,
        grain,
        layers,
    })
}

/// The joint fit: the problem, its best rollout and the curvature there.
pub type Joint = (Calibration, Eval, Identifiability);

/// What [`run`] found.
pub struct Outcome {
    pub runs: Vec<Run>,
    pub joint: Option<Joint>,
    /// Each case's backward cost in forward rollouts.
    pub costs: Vec<f64>,
    /// The collapse's loss at [`GRAIN`]'s points: (friction angle, loss, ∂L/∂φ per degree).
    pub grain: Vec<(f64, f64, f64)>,
    /// The layered bed's runs and curvature.
    pub layers: layers::LayerOutcome,
}

/// The sweep that shows the collapse's loss at grain scale: (true friction angle, from, to,
/// points), gradient rollouts at every point.
pub const GRAIN: (f64, f64, f64, usize) = (26.0, 23.0, 25.0, 21);

/// Calibration methods on synthetic observations (calibration.md).
pub struct CalibrationStudy;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub common: crate::lab::study::args::Common,
    #[command(flatten)]
    pub paired: crate::lab::study::args::Paired,
    #[command(flatten)]
    pub page: crate::lab::study::args::Page,
    #[arg(long, value_parser = crate::scene::threads_arg)]
    pub threads: Option<usize>,
}
crate::study_settings!(Args);

impl crate::lab::study::Study for CalibrationStudy {
    const NAME: &'static str = "calibration";
    const ABOUT: &'static str = "Calibration methods on synthetic observations (calibration.md)";
    type Args = Args;
    type Outcome = Outcome;

    /// Recovery of known parameters from noisy synthetic observations, Adam and BFGS on the
    /// adjoint against CMA-ES at equal compute.
    fn run(a: &Args, ctx: crate::lab::study::Ctx) -> anyhow::Result<Outcome> {
        use crate::sim::announce_work;
        if a.paired.seeds == 0 || a.paired.budget == 0 {
            anyhow::bail!("study calibration: --seeds and --budget must be at least 1");
        }
        let budget = a.paired.budget as f64;
        let runs = CASES.len() * 5 * a.paired.seeds * METHODS.len();
        // The pairs, the joint fit and its curvature, and the grain sweep's gradient rollouts.
        let total = runs as f64 * budget + 2.0 * budget + 6.0 * 3.4 + GRAIN.3 as f64 * 3.4;
        for case in &CASES {
            announce_work(Path::new(case.scene), total / CASES.len() as f64)?;
        }
        // The layered bed: its pairs (and each pair's rollout at the truth) and its curvature.
        let layered = {
            use layers as l;
            let pairs = (l::PAIRS_PER_SEED * a.paired.seeds) as f64;
            let k = l::LAYERS as f64;
            pairs * l::METHODS.len() as f64 * (l::BUDGET_FACTOR * budget + 1.0) + 1.0 + 2.0 * k * k
        };
        announce_work(Path::new(layers::SCENE), layered)?;
        let pb = ctx.bar((total + layered).ceil() as u64);
        let pb2 = pb.clone();
        let done = Mutex::new(0.0f64);
        let progress = move |c: f64| {
            let mut d = done.lock().expect("lock");
            *d += c;
            pb2.set_position(d.round() as u64);
        };
        crate::lab::study::start_workers(a.threads.unwrap_or(0))?;
        // Each rollout runs on one thread; the pairs run side by side.
        let outcome = run(
            &a.common.out.join("calibration"),
            a.paired.seeds,
            budget,
            Some(1),
            &progress,
        )?;
        pb.finish_and_clear();
        Ok(outcome)
    }

    fn page(
        a: &Args,
        outcome: Outcome,
        _: crate::lab::study::Ctx,
    ) -> anyhow::Result<crate::lab::study::Report> {
        let budget = a.paired.budget as f64;
        let command = format!(
            "powderlab study calibration --seeds {} --budget {}",
            a.paired.seeds, a.paired.budget
        );
        crate::util::create_output_dir(&a.page.results, "--results")?;
        let machine = crate::lab::study::machine();
        let mut md = report(&outcome, &command, &machine, budget, &a.page.results)?;
        md.push_str(&layers::report(&outcome.layers, budget, &a.page.results)?);
        crate::lab::study::write_page(&a.page.results, "calibration.md", &md)?;
        Ok(crate::lab::study::Report {
            text: md,
            wrote: "calibration.md, calibration.svg and calibration_layers.svg".into(),
            dir: a.page.results.clone(),
            json: serde_json::json!({ "runs": outcome.runs, "layers": outcome.layers.runs }),
            failed: false,
        })
    }
}
