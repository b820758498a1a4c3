//! `powderlab study calibration`: does calibration through the adjoint recover known parameters
//! from noisy synthetic observations, and does it beat CMA-ES at equal compute?
//!
//! Two recovery cases, each over five true values and paired starts:
//! - **friction angle** from the final pile of a column collapse
//!   (`scenes/calibration_collapse.ron`), seen as a height map with 1 mm noise;
//! - **floor friction** from the final surface of a layer of sand thrown along the floor
//!   (`scenes/calibration_slide.ron`), same noise.
//!
//! For each (true value, start) pair, Adam on the adjoint and CMA-ES on the forward loss get the
//! same compute ([`super::super::optim::report::BACKWARD_COST`] per backward pass); each is
//! scored by the parameter error of its rollout of lowest loss. The starts are uniform in the
//! middle of the search range, drawn from the pair's seed, and shared by both methods. A third
//! case fits friction angle, Young's modulus and floor friction together on the collapse and
//! reports the curvature: which of them one pile pins down.
//!
//! Every rollout goes to `rollouts.jsonl` as it finishes ([`crate::calibrate::Journal`]), so a
//! killed study resumes.

use super::optimizers::wilcoxon_less;
use crate::calibrate::observation::Observed;
use crate::calibrate::plot::{curves_svg, Curve, ADAM, CMAES};
use crate::calibrate::{
    self, params, AdamConfig, Calibration, Eval, Identifiability, Journal, CURVATURE_STEP,
};
use crate::optim::report::mean_std;
use crate::scene::Scene;
use crate::util::SplitMix64;
use rayon::prelude::*;
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
    let settings_path = dir.join("settings.json");
    match std::fs::read_to_string(&settings_path) {
        Ok(t) if serde_json::from_str::<serde_json::Value>(&t).ok() != Some(settings.clone()) => {
            anyhow::bail!(
                "--out {}: holds a calibration study with other observations; delete it or choose another --out",
                dir.parent().unwrap_or(dir).display()
            )
        }
        Ok(_) => {}
        Err(_) => crate::util::write_atomic(&settings_path, settings.to_string().as_bytes())?,
    }
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
                for method in ["adam", "cmaes"] {
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
        let trace = calibrate::adam(&u0, 2.0 * budget, AdamConfig::default(), |i, u, g| {
            shared.eval(&cal, "joint/adam", i, u, g)
        })?;
        let best = trace
            .iter()
            .min_by(|a, b| a.loss.total_cmp(&b.loss))
            .expect("a rollout")
            .clone();
        // The curvature at the truth: what the observation pins down, whatever the optimiser
        // reached.
        let truth: Vec<f64> = cal
            .params
            .iter()
            .zip([30.0, 5.0e4, 0.5])
            .map(|(p, v)| p.to_unit(v))
            .collect();
        let mut k = 0;
        let id = calibrate::identifiability(&cal, &truth, CURVATURE_STEP, |u| {
            let e = shared.eval(&cal, "joint/curvature", k, u, false);
            k += 1;
            e
        })?;
        Some((cal, best, id))
    };
    Ok(Outcome { runs, joint, costs })
}

/// The joint fit: the problem, its best rollout and the curvature there.
pub type Joint = (Calibration, Eval, Identifiability);

/// What [`run`] found.
pub struct Outcome {
    pub runs: Vec<Run>,
    pub joint: Option<Joint>,
    /// Each case's backward cost in forward rollouts.
    pub costs: Vec<f64>,
}

/// The page: per case, the recovery table, Adam against CMA-ES with a paired test, and the
/// joint fit's curvature; and the figure `calibration.svg` in `results`.
pub fn report(
    o: &Outcome,
    command: &str,
    machine: &str,
    budget: f64,
    results: &Path,
) -> anyhow::Result<String> {
    let (runs, joint, costs) = (&o.runs, &o.joint, &o.costs);
    let mut md = format!(
        "# Calibration from observations\n\nRegenerate with `{command}` ({machine}).\n\n\
Synthetic observations: each scene is run at a true parameter value and its final surface is seen \
as a height map (a pixel per particle spacing, 1.25 mm) with {:.0} mm of Gaussian noise on every height. Each \
(true value, start) pair gives Adam on the adjoint and CMA-ES on the forward loss the same compute, \
{budget} forward rollouts (a gradient rollout counts 1 + the backward pass's cost); each is scored \
by the parameter error of its rollout of lowest loss. p is a one-sided Wilcoxon signed-rank test \
over the pairs that Adam's error is lower. The backward pass's cost was measured on each scene \
(one thread, median of three): {} forward rollouts.\n",
        HEIGHT_NOISE * 1e3,
        costs.iter().zip(&CASES).map(|(c, k)| format!("{c:.2} on `{}`", k.scene)).collect::<Vec<_>>().join(", ")
    );
    let mut curves: Vec<(usize, &Run)> = Vec::new();
    for (ci, case) in CASES.iter().enumerate() {
        let of = |m: &str| -> Vec<&Run> {
            let mut v: Vec<&Run> = runs
                .iter()
                .filter(|r| r.case == ci && r.method == m)
                .collect();
            v.sort_by(|a, b| a.truth.total_cmp(&b.truth).then(a.seed.cmp(&b.seed)));
            v
        };
        let (adam, cma) = (of("adam"), of("cmaes"));
        if adam.is_empty() {
            continue;
        }
        md.push_str(&format!(
            "\n## {} (`{}`, `--fit {}`)\n\n| true | start | Adam fitted | Adam error | CMA-ES fitted | CMA-ES error |\n|---|---|---|---|---|---|\n",
            case.name, case.scene, case.param
        ));
        for (a, c) in adam.iter().zip(&cma) {
            md.push_str(&format!(
                "| {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} |\n",
                a.truth, a.start, a.fitted, a.error, c.fitted, c.error
            ));
        }
        let ea: Vec<f64> = adam.iter().map(|r| r.error).collect();
        let ec: Vec<f64> = cma.iter().map(|r| r.error).collect();
        let (ma, sa) = mean_std(&ea);
        let (mc, sc) = mean_std(&ec);
        // Pairs within the tolerance, and true values with every start within it.
        let recovered = |runs: &[&Run]| {
            let pairs = runs.iter().filter(|r| r.error <= case.tolerance).count();
            let truths = case
                .truths
                .iter()
                .filter(|t| {
                    runs.iter()
                        .filter(|r| r.truth == **t)
                        .all(|r| r.error <= case.tolerance)
                })
                .count();
            (pairs, truths)
        };
        let ((pa, ta), (pc, tc)) = (recovered(&adam), recovered(&cma));
        let p = wilcoxon_less(&ea, &ec)
            .map(|p| format!("{p:.3}"))
            .unwrap_or_else(|| "–".into());
        md.push_str(&format!(
            "
Adam: error {ma:.3} ± {sa:.3}{u}, {pa}/{n} pairs within {tol}{u}, {ta}/5 true values with every start within it. CMA-ES: {mc:.3} ± {sc:.3}{u}, {pc}/{n} pairs within {tol}{u}, {tc}/5 true values. Adam lower: p = {p}.\n",
            n = ea.len(),
            tol = case.tolerance,
            u = case.unit
        ));
        md.push_str("\nAt smaller budgets (the error of the best rollout so far, read off each run's curve):\n\n| compute (forward rollouts) | Adam error | CMA-ES error | Adam lower: p |\n|---|---|---|---|\n");
        for b in [10.0, 20.0, budget] {
            let at = |r: &Run| {
                r.curve
                    .iter()
                    .take_while(|p| p.0 <= b + 1e-9)
                    .last()
                    .map_or(f64::NAN, |p| p.1)
            };
            let xa: Vec<f64> = adam.iter().map(|r| at(r)).collect();
            let xc: Vec<f64> = cma.iter().map(|r| at(r)).collect();
            let p = wilcoxon_less(&xa, &xc)
                .map(|p| format!("{p:.3}"))
                .unwrap_or_else(|| "–".into());
            md.push_str(&format!(
                "| {b} | {:.3} ± {:.3} | {:.3} ± {:.3} | {p} |\n",
                mean_std(&xa).0,
                mean_std(&xa).1,
                mean_std(&xc).0,
                mean_std(&xc).1
            ));
        }
        for r in adam.iter().chain(&cma) {
            curves.push((ci, *r));
        }
    }
    if let Some((cal, best, id)) = joint {
        md.push_str(&format!(
            "\n## Which parameters one pile pins down\n\nThe collapse at friction_deg 30, youngs_modulus 5e4 and floor.friction 0.5, fitted jointly by Adam from 36, 1.5e5 and 0.35 ({} forward rollouts of compute; its best loss {:.4e} against {:.4e} at the truth). The curvature is taken at the truth (what the observation can pin down, whatever an optimiser reaches), by central second differences of the loss at {} % of each range, where the loss's roughness averages out. Standard errors from `Cov(u) ≈ (2L*/n) H⁻¹` with n = {} pixels, infinite where the curvature is not positive definite; pinned down when under {} % of the range (of the value, for Young's modulus, searched in decades).\n\n| parameter | true | Adam's fit | std. error | share | pinned down |\n|---|---|---|---|---|---|\n",
            2.0 * budget,
            best.loss,
            id.loss,
            id.step * 100.0,
            cal.residuals,
            calibrate::PINNED_SHARE * 100.0
        ));
        for (i, p) in cal.params.iter().enumerate() {
            md.push_str(&format!(
                "| {} | {:.4} | {:.4} | {:.3e} | {:.1} % | {} |\n",
                p.label,
                p.from_unit(id.at[i]),
                best.values[i],
                id.std_error[i],
                id.relative[i] * 100.0,
                if id.relative[i] < calibrate::PINNED_SHARE {
                    "yes"
                } else {
                    "no"
                }
            ));
        }
        md.push_str(&format!(
            "\nEigenvalues of the curvature in unit coordinates: {}; the eigenvector of the smallest is ({}) in the order above.\n",
            id.eigenvalues.iter().map(|l| format!("{l:.3e}")).collect::<Vec<_>>().join(", "),
            id.eigenvectors.last().map(|v| v.iter().map(|x| format!("{x:.2}")).collect::<Vec<_>>().join(", ")).unwrap_or_default()
        ));
    }
    let mut figure = Vec::new();
    for (ci, r) in &curves {
        let scale = (CASES[*ci].starts.1 - CASES[*ci].starts.0).max(1e-12);
        figure.push(Curve {
            label: format!(
                "{} ({})",
                r.method,
                if *ci == 0 {
                    "friction angle"
                } else {
                    "floor friction"
                }
            ),
            colour: if r.method == "adam" { ADAM } else { CMAES },
            points: r.curve.iter().map(|&(c, e)| (c, e / scale)).collect(),
            faint: *ci == 1,
        });
    }
    curves_svg(
        &results.join("calibration.svg"),
        "parameter error of the best rollout so far, as a share of the start range",
        "compute (forward rollouts)",
        "error / start range",
        &figure,
    )?;
    md.push_str("\n![parameter error against compute](calibration.svg)\n\nBold lines: friction angle; pale lines: floor friction. One line per (true value, start) pair.\n");
    Ok(md)
}
