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
//! ([`crate::calibrate::trust`]) on the adjoint gradient, and CMA-ES on the forward loss. Each is
//! scored by the parameter error of its rollout of lowest loss. The starts are uniform in the
//! middle of the search range, drawn from the pair's seed, and shared by the methods. A third
//! case fits friction angle, Young's modulus and floor friction together on the collapse and
//! reports the curvature: which of them one pile pins down.
//!
//! Every rollout goes to `rollouts.jsonl` as it finishes ([`crate::calibrate::Journal`]), so a
//! killed study resumes.

use super::optimizers::wilcoxon_less;
use crate::calibrate::observation::Observed;
use crate::calibrate::plot::{colour, curves_svg, Curve};
use crate::calibrate::{
    self, params, AdamConfig, Calibration, Eval, Identifiability, Journal, TrustConfig,
    CURVATURE_STEP,
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

/// The methods compared, as the journal keys them: Adam and the trust-region quasi-Newton
/// method on the adjoint, CMA-ES on the forward loss.
pub const METHODS: [&str; 3] = ["adam", "bfgs", "cmaes"];

/// How the page names a method.
fn title(method: &str) -> &'static str {
    match method {
        "adam" => "Adam",
        "bfgs" => "BFGS",
        _ => "CMA-ES",
    }
}

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

/// The compute after which a run's best-so-far error stays within `tol`: the first point of
/// `curve` (compute, error) from which every later error is within it; `None` if the last is not.
pub fn settled(curve: &[(f64, f64)], tol: f64) -> Option<f64> {
    let mut at = None;
    for &(c, e) in curve.iter().rev() {
        if e <= tol {
            at = Some(c);
        } else {
            break;
        }
    }
    at
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
    Ok(Outcome {
        runs,
        joint,
        costs,
        grain,
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
}

/// The sweep that shows the collapse's loss at grain scale: (true friction angle, from, to,
/// points), gradient rollouts at every point.
pub const GRAIN: (f64, f64, f64, usize) = (26.0, 23.0, 25.0, 21);

/// What a sweep `(x, loss, dL/dx)` says of the loss's grain.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grain {
    /// Interior points lower than both neighbours.
    pub minima: usize,
    /// Interior points whose gradient has the sign of their neighbours' central difference.
    pub agree_local: usize,
    /// Points whose gradient has the sign of the secant over the whole sweep.
    pub agree_secant: usize,
    /// That secant, per unit of x.
    pub secant: f64,
    /// The largest rise a walk down the secant meets: `(rise, from x, to x)`, the loss going up
    /// from `from` to `to` although the sweep as a whole goes down.
    pub barrier: (f64, f64, f64),
}

/// The [`Grain`] of a sweep of at least three points, in order of x.
pub fn grain_summary(pts: &[(f64, f64, f64)]) -> Grain {
    let minima = pts
        .windows(3)
        .filter(|w| w[1].1 < w[0].1 && w[1].1 < w[2].1)
        .count();
    let agree_local = pts
        .windows(3)
        .filter(|w| w[1].2.signum() == (w[2].1 - w[0].1).signum())
        .count();
    let (first, last) = (pts[0], pts[pts.len() - 1]);
    let secant = (last.1 - first.1) / (last.0 - first.0);
    let agree_secant = pts
        .iter()
        .filter(|p| p.2.signum() == secant.signum())
        .count();
    // Walk in the direction the loss falls overall; the rise above the lowest point so far.
    let walk: Vec<&(f64, f64, f64)> = if secant <= 0.0 {
        pts.iter().collect()
    } else {
        pts.iter().rev().collect()
    };
    let mut low = walk[0];
    let mut barrier = (0.0, low.0, low.0);
    for p in walk {
        if p.1 < low.1 {
            low = p;
        } else if p.1 - low.1 > barrier.0 {
            barrier = (p.1 - low.1, low.0, p.0);
        }
    }
    Grain {
        minima,
        agree_local,
        agree_secant,
        secant,
        barrier,
    }
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
    let grain = grain_summary(&o.grain);
    let mut md = format!(
        "# Calibration from observations\n\nRegenerate with `{command}` ({machine}).\n\n\
Synthetic observations: each scene is run at a true parameter value and its final surface is seen \
as a height map (a pixel per particle spacing, 1.25 mm) with {:.0} mm of Gaussian noise on every height. Each \
(true value, start) pair gives three methods the same compute: Adam on the adjoint gradient (normalised \
gradient descent, as DPSI uses), BFGS (a bounded trust-region quasi-Newton method on the adjoint gradient, after a scan of \
four forward rollouts per parameter; `src/calibrate/trust.rs`) and CMA-ES on the forward loss: \
{budget} forward rollouts (a gradient rollout counts 1 + the backward pass's cost); each is scored \
by the parameter error of its rollout of lowest loss. p is a one-sided Wilcoxon signed-rank test \
over the pairs that a gradient method's error is lower than CMA-ES's. The backward pass's cost was measured on each scene \
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
        let by: Vec<Vec<&Run>> = METHODS.iter().map(|m| of(m)).collect();
        if by.iter().any(|v| v.is_empty()) {
            continue;
        }
        md.push_str(&format!(
            "\n## {} (`{}`, `--fit {}`)\n\n| true | start |{}\n|---|---|{}\n",
            case.name,
            case.scene,
            case.param,
            METHODS
                .iter()
                .map(|m| format!(" {0} fitted | {0} error |", title(m)))
                .collect::<String>(),
            "---|---|".repeat(METHODS.len())
        ));
        for (k, a) in by[0].iter().enumerate() {
            md.push_str(&format!("| {} | {:.3} |", a.truth, a.start));
            for runs in &by {
                md.push_str(&format!(" {:.3} | {:.3} |", runs[k].fitted, runs[k].error));
            }
            md.push('\n');
        }
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
        let cma = by.last().expect("CMA-ES is the last method");
        let ec: Vec<f64> = cma.iter().map(|r| r.error).collect();
        md.push('\n');
        for (m, runs) in METHODS.iter().zip(&by) {
            let e: Vec<f64> = runs.iter().map(|r| r.error).collect();
            let (mean, sd) = mean_std(&e);
            let (pairs, truths) = recovered(runs);
            md.push_str(&format!(
                "- {}: error {mean:.3} ± {sd:.3}{u}, {pairs}/{n} pairs within {tol}{u}, {truths}/5 true values with every start within it",
                title(m),
                n = e.len(),
                tol = case.tolerance,
                u = case.unit
            ));
            if *m != "cmaes" {
                let p = wilcoxon_less(&e, &ec)
                    .map(|p| format!("{p:.3}"))
                    .unwrap_or_else(|| "–".into());
                md.push_str(&format!("; lower than CMA-ES's: p = {p}"));
            }
            md.push_str(".\n");
        }
        md.push_str(&format!(
            "\nAt smaller budgets (the error of the best rollout so far, read off each run's curve; p: lower than CMA-ES's):\n\n| compute (forward rollouts) |{}\n|---|{}\n",
            METHODS
                .iter()
                .map(|m| if *m == "cmaes" {
                    format!(" {} error |", title(m))
                } else {
                    format!(" {0} error | {0}: p |", title(m))
                })
                .collect::<String>(),
            "---|".repeat(2 * METHODS.len() - 1)
        ));
        for b in [10.0, 20.0, budget] {
            let at = |r: &Run| {
                r.curve
                    .iter()
                    .take_while(|p| p.0 <= b + 1e-9)
                    .last()
                    .map_or(f64::NAN, |p| p.1)
            };
            let xc: Vec<f64> = cma.iter().map(|r| at(r)).collect();
            md.push_str(&format!("| {b} |"));
            for (m, runs) in METHODS.iter().zip(&by) {
                let x: Vec<f64> = runs.iter().map(|r| at(r)).collect();
                let (mean, sd) = mean_std(&x);
                md.push_str(&format!(" {mean:.3} ± {sd:.3} |"));
                if *m != "cmaes" {
                    let p = wilcoxon_less(&x, &xc)
                        .map(|p| format!("{p:.3}"))
                        .unwrap_or_else(|| "–".into());
                    md.push_str(&format!(" {p} |"));
                }
            }
            md.push('\n');
        }
        md.push_str(&format!(
            "\nCompute until the best rollout stays within {tol}{u} of the truth, median over the pairs that get there:",
            tol = case.tolerance,
            u = case.unit
        ));
        for (k, (m, runs)) in METHODS.iter().zip(&by).enumerate() {
            let reached: Vec<f64> = runs
                .iter()
                .filter_map(|r| settled(&r.curve, case.tolerance))
                .collect();
            md.push_str(&format!(
                "{} {} {} ({}/{} pairs)",
                if k == 0 { "" } else { ";" },
                title(m),
                if reached.is_empty() {
                    "–".to_string()
                } else {
                    format!("{:.1}", crate::optim::rmsprop::median(&reached))
                },
                reached.len(),
                runs.len()
            ));
        }
        md.push_str(".\n");
        for runs in &by {
            for r in runs {
                curves.push((ci, *r));
            }
        }
    }
    if let Some((cal, best, id)) = joint {
        md.push_str(&format!(
            "\n## Which parameters one pile pins down\n\nThe collapse at friction_deg 30, youngs_modulus 5e4 and floor.friction 0.5, fitted jointly by BFGS from 36, 1.5e5 and 0.35 ({} forward rollouts of compute; its best loss {:.4e} against {:.4e} at the truth). The curvature is taken at the truth (what the observation can pin down, whatever an optimiser reaches), by central second differences of the loss at {} % of each range, where the loss's roughness averages out. Standard errors from `Cov(u) ≈ (2L*/n) H⁻¹` with n = {} pixels, infinite where the curvature is not positive definite; pinned down when under {} % of the range (of the value, for Young's modulus, searched in decades).\n\n| parameter | true | BFGS's fit | std. error | share | pinned down |\n|---|---|---|---|---|---|\n",
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
            colour: colour(&r.method),
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
    md.push_str(&format!(
        "\n## The loss's grain\n\nThe collapse's loss for a true {:.0}° (the pairs' observation), a gradient rollout every {:.1}° from {:.0}° to {:.0}°. Over the sweep the loss falls by {:.1} % (secant {:.3e} per degree), but not monotonically: it has {} interior local minima, and walking down the secant a local method meets a rise of {:.1} % of the loss there, from {:.1}° to {:.1}°. The adjoint gradient follows the loss it differentiates: it has the sign of its neighbours' central difference at {} of {} interior points, and the secant's sign at {} of {}. A descent stops at the first such rise wider than its region; a search that spreads its rollouts over degrees does not see it. This is why the trust region stops shrinking at [`MIN_RADIUS`](../../src/calibrate/trust.rs) (0.5°) and spends what is left in another basin.\n\n| friction (°) | loss | ∂L/∂φ (per degree) |\n|---|---|---|\n",
        GRAIN.0,
        (GRAIN.2 - GRAIN.1) / (GRAIN.3 - 1) as f64,
        GRAIN.1,
        GRAIN.2,
        100.0 * (o.grain[0].1 - o.grain[o.grain.len() - 1].1) / o.grain[0].1,
        grain.secant,
        grain.minima,
        100.0 * grain.barrier.0
            / o.grain
                .iter()
                .find(|p| p.0 == grain.barrier.1)
                .map_or(f64::NAN, |p| p.1),
        grain.barrier.1,
        grain.barrier.2,
        grain.agree_local,
        o.grain.len() - 2,
        grain.agree_secant,
        o.grain.len()
    ));
    for (v, l, g) in &o.grain {
        md.push_str(&format!("| {v:.1} | {l:.4e} | {g:.3e} |\n"));
    }
    md.push_str("\n![parameter error against compute](calibration.svg)\n\nBold lines: friction angle; pale lines: floor friction. One line per (true value, start) pair.\n");
    Ok(md)
}

#[cfg(test)]
mod tests {
    use super::settled;

    #[test]
    fn the_grain_summary_counts_minima_agreement_and_the_barrier() {
        // Falls overall, with a bump from x = 1 (4.0) to x = 2 (4.5).
        let pts = [
            (0.0, 5.0, -1.0),
            (1.0, 4.0, 0.5),
            (2.0, 4.5, -2.0),
            (3.0, 3.0, -1.0),
            (4.0, 1.0, -0.1),
        ];
        let g = super::grain_summary(&pts);
        assert_eq!((g.minima, g.agree_secant, g.secant), (1, 4, -1.0));
        // Central differences at 1, 2, 3: −0.5, −0.5, −1.75; gradients 0.5, −2, −1.
        assert_eq!(g.agree_local, 2);
        assert_eq!(g.barrier, (0.5, 1.0, 2.0));
    }

    #[test]
    fn a_run_settles_where_its_error_enters_the_tolerance_for_good() {
        let c = [(1.0, 5.0), (2.0, 0.5), (3.0, 2.0), (4.0, 0.8), (5.0, 0.3)];
        assert_eq!(settled(&c, 1.0), Some(4.0));
        assert_eq!(settled(&c, 0.1), None);
        assert_eq!(settled(&c, 10.0), Some(1.0));
    }
}
