//! `powderlab study refine`: trajectory refinement in 6, 30 and 96 dimensions, the adjoint
//! against CMA-ES and random search at equal compute.
//!
//! Seed `k` refines the skill of Θ_init(k) with a residual of `knots` knots per control channel
//! on its transport and pour ([`crate::optim::refine`]); every method starts from `w = 0` (the
//! plain skill). Methods:
//! - **adam**: Adam (β₁ 0.9, β₂ 0.999, lr [`ADAM_LR`]) on the adjoint `∂L/∂w`, projected to the
//!   box, `⌈budget/(1 + BACKWARD_COST)⌉` gradient rollouts;
//! - **trust**: the adjoint's direction in the hybrid's trust region (a step is kept only if the
//!   loss falls), gradient rollouts at their cost and forward-only trials within the budget;
//! - **cmaes**: the `cmaes` crate from `w = 0`, σ₀ [`CMA_SIGMA0`], its default population for
//!   the dimension, samples reflected into the box, `budget` rollouts;
//! - **random**: `w = 0`, then uniform draws in the box, `budget` rollouts.
//!
//! SAC is not run: its policy is written for the skill's five parameters. Each method's score
//! is the dose error of its rollout of lowest loss within the compute of `budget` forward
//! rollouts (in particle-substeps, a backward pass at `BACKWARD_COST`). Every rollout goes to
//! `rollouts.jsonl` as it finishes and is replayed from there, so a killed study resumes.

use super::optimizers::wilcoxon_less;
use crate::optim::cma::reflect;
use crate::optim::hybrid::{HybridConfig, TrustRegion};
use crate::optim::problem::Problem;
pub use crate::optim::report::gradient_rollouts;
use crate::optim::report::{mean_std, BACKWARD_COST};
use crate::optim::rmsprop::median;
use crate::optim::theta_init;
use crate::util::SplitMix64;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::io::Write as _;
use std::path::Path;
use std::sync::Mutex;

/// Adam's learning rate on `w` (a tenth of the box's half-width per step).
pub const ADAM_LR: f64 = 0.1;
/// CMA-ES's initial step size on `w`.
pub const CMA_SIGMA0: f64 = 0.3;

/// One finished rollout.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Rollout {
    pub knots: usize,
    pub method: String,
    pub seed: usize,
    pub index: usize,
    pub w: Vec<f64>,
    pub loss: f64,
    pub dose_error: f64,
    /// Particle-substeps, the backward pass at its cost.
    pub cost: f64,
    pub wall_s: f64,
    #[serde(default)]
    pub grad: Option<Vec<f64>>,
}

type Key = (usize, String, usize, usize);

/// The rollouts of a study folder, replayed or run.
pub struct Store {
    known: HashMap<Key, Rollout>,
    file: Mutex<std::fs::File>,
    progress: Box<dyn Fn() + Sync>,
}

impl Store {
    pub fn open(dir: &Path, progress: Box<dyn Fn() + Sync>) -> anyhow::Result<Store> {
        crate::util::create_output_dir(dir, "--out")?;
        let path = dir.join("rollouts.jsonl");
        let mut known = HashMap::new();
        if let Ok(text) = std::fs::read_to_string(&path) {
            // A torn last line (killed mid-write) is dropped.
            for r in text
                .lines()
                .filter_map(|l| serde_json::from_str::<Rollout>(l).ok())
            {
                known.insert((r.knots, r.method.clone(), r.seed, r.index), r);
            }
        }
        let file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)?;
        Ok(Store {
            known,
            file: Mutex::new(file),
            progress,
        })
    }

    /// The rollout of `(knots, method, seed, index)` at `w`: replayed if recorded with bitwise
    /// the same `w`, else run and recorded.
    #[allow(clippy::too_many_arguments)]
    fn get(
        &self,
        problem: &Problem,
        knots: usize,
        method: &str,
        seed: usize,
        index: usize,
        w: &[f64],
        with_grad: bool,
    ) -> anyhow::Result<Rollout> {
        let key = (knots, method.to_string(), seed, index);
        if let Some(r) = self.known.get(&key) {
            if r.w
                .iter()
                .map(|x| x.to_bits())
                .eq(w.iter().map(|x| x.to_bits()))
            {
                (self.progress)();
                return Ok(r.clone());
            }
        }
        let theta = theta_init(seed);
        let res = problem.residual(theta, knots);
        let (o, grad) = problem.evaluate_residual(theta, &res, w, with_grad, true)?;
        let forward = o.particles as f64 * o.steps as f64 * o.substeps as f64;
        let r = Rollout {
            knots,
            method: method.to_string(),
            seed,
            index,
            w: w.to_vec(),
            loss: o.loss,
            dose_error: o.indicator.abs(),
            cost: forward * if with_grad { 1.0 + BACKWARD_COST } else { 1.0 },
            wall_s: o.wall_s,
            grad,
        };
        let mut f = self.file.lock().expect("lock");
        writeln!(f, "{}", serde_json::to_string(&r)?)?;
        f.flush()?;
        drop(f);
        (self.progress)();
        Ok(r)
    }
}

/// Adam on the adjoint gradient.
fn adam(
    s: &Store,
    p: &Problem,
    knots: usize,
    seed: usize,
    budget: usize,
) -> anyhow::Result<Vec<Rollout>> {
    let d = 6 * knots;
    let n = gradient_rollouts(budget);
    let (b1, b2, eps) = (0.9, 0.999, 1e-8);
    let (mut w, mut m, mut v) = (vec![0.0; d], vec![0.0; d], vec![0.0; d]);
    let mut out = Vec::new();
    for t in 1..=n {
        let r = s.get(p, knots, "adam", seed, t - 1, &w, true)?;
        let g = r.grad.clone().unwrap_or_else(|| vec![0.0; d]);
        out.push(r);
        for i in 0..d {
            m[i] = b1 * m[i] + (1.0 - b1) * g[i];
            v[i] = b2 * v[i] + (1.0 - b2) * g[i] * g[i];
            let mh = m[i] / (1.0 - b1.powi(t as i32));
            let vh = v[i] / (1.0 - b2.powi(t as i32));
            w[i] = (w[i] - ADAM_LR * mh / (vh.sqrt() + eps)).clamp(-1.0, 1.0);
        }
    }
    Ok(out)
}

/// The adjoint in a trust region, from the plain skill: the hybrid's local phase
/// ([`crate::optim::hybrid`]) on `w`. A gradient rollout at the incumbent gives the direction;
/// the trial `w − r·g/‖g‖` runs forward only and is kept if its loss falls (the radius grows),
/// else the radius shrinks and the next trial reuses the gradient. It stops when the next
/// rollout would pass `budget` forward rollouts' compute, or when the gradient is zero.
fn trust(
    s: &Store,
    p: &Problem,
    knots: usize,
    seed: usize,
    budget: usize,
) -> anyhow::Result<Vec<Rollout>> {
    let initial = HybridConfig::default().radius;
    let mut tr = TrustRegion { radius: initial };
    let (budget, grad_cost) = (budget as f64 + 1e-9, 1.0 + BACKWARD_COST);
    let mut w = vec![0.0; 6 * knots];
    let mut out: Vec<Rollout> = Vec::new();
    let (mut spent, mut incumbent, mut grad) = (0.0, f64::INFINITY, None::<Vec<f64>>);
    loop {
        let Some(g) = &grad else {
            if !out.is_empty() && spent + grad_cost > budget {
                break;
            }
            let r = s.get(p, knots, "trust", seed, out.len(), &w, true)?;
            spent += grad_cost;
            incumbent = r.loss;
            grad = Some(r.grad.clone().unwrap_or_default());
            out.push(r);
            continue;
        };
        let Some(trial) = tr.propose_in(&w, g) else {
            break;
        };
        if spent + 1.0 > budget {
            break;
        }
        let r = s.get(p, knots, "trust", seed, out.len(), &trial, false)?;
        spent += 1.0;
        if tr.judge(incumbent, r.loss, initial) {
            w = trial;
            grad = None;
        }
        out.push(r);
    }
    Ok(out)
}

/// Random search: `w = 0`, then uniform draws in the box.
fn random(
    s: &Store,
    p: &Problem,
    knots: usize,
    seed: usize,
    budget: usize,
) -> anyhow::Result<Vec<Rollout>> {
    let mut rng = SplitMix64(0x5EED_0000 + seed as u64 * 131 + knots as u64);
    (0..budget)
        .map(|i| {
            let w: Vec<f64> = if i == 0 {
                vec![0.0; 6 * knots]
            } else {
                (0..6 * knots).map(|_| rng.uniform_in(-1.0, 1.0)).collect()
            };
            s.get(p, knots, "random", seed, i, &w, false)
        })
        .collect()
}

/// CMA-ES from `w = 0`, one sample at a time (the sampler's order), `budget` rollouts.
fn cmaes(
    s: &Store,
    p: &Problem,
    knots: usize,
    seed: usize,
    budget: usize,
) -> anyhow::Result<Vec<Rollout>> {
    let mut out: Vec<Rollout> = Vec::new();
    crate::optim::cma::run_sequential(
        vec![0.0; 6 * knots],
        CMA_SIGMA0,
        0xC3A_0000 + seed as u64,
        budget,
        |x| {
            let w: Vec<f64> = x.iter().map(|v| reflect(*v)).collect();
            let r = s.get(p, knots, "cmaes", seed, out.len(), &w, false)?;
            let l = r.loss;
            out.push(r);
            Ok(l)
        },
    )?;
    Ok(out)
}

/// The methods, in the page's order.
pub const METHODS: [&str; 4] = ["adam", "trust", "cmaes", "random"];

/// The methods that use the adjoint, each tested against each baseline.
const ADJOINT: [&str; 2] = ["adam", "trust"];

/// One (dimension, method) cell: per seed, the dose error at equal compute.
#[derive(Clone, Debug, Serialize)]
pub struct Cell {
    pub knots: usize,
    pub method: String,
    pub dose: Vec<f64>,
    pub rollouts: f64,
    pub cost: f64,
}

/// Runs every dimension, method and seed and scores them at each seed's equal-compute budget
/// (the smallest spend of any method on that seed and dimension).
pub fn run(
    problem: &Problem,
    knots: &[usize],
    seeds: usize,
    budget: usize,
    store: &Store,
) -> anyhow::Result<Vec<Cell>> {
    let mut cells = Vec::new();
    for &k in knots {
        let per: Vec<Vec<Vec<Rollout>>> = METHODS
            .iter()
            .map(|m| {
                (0..seeds)
                    .into_par_iter()
                    .map(|seed| match *m {
                        "adam" => adam(store, problem, k, seed, budget),
                        "trust" => trust(store, problem, k, seed, budget),
                        "cmaes" => cmaes(store, problem, k, seed, budget),
                        _ => random(store, problem, k, seed, budget),
                    })
                    .collect::<anyhow::Result<Vec<_>>>()
            })
            .collect::<anyhow::Result<_>>()?;
        let spend = |l: &[Rollout]| l.iter().map(|r| r.cost).sum::<f64>();
        let budgets: Vec<f64> = (0..seeds)
            .map(|seed| {
                per.iter()
                    .map(|m| spend(&m[seed]))
                    .fold(f64::INFINITY, f64::min)
            })
            .collect();
        for (m, runs) in METHODS.iter().zip(&per) {
            let mut dose = Vec::new();
            let (mut n, mut c) = (Vec::new(), Vec::new());
            for (seed, l) in runs.iter().enumerate() {
                let mut spent = 0.0;
                let mut best: Option<&Rollout> = None;
                let mut used = 0;
                for r in l {
                    if spent + r.cost > budgets[seed] * (1.0 + 1e-12) && used > 0 {
                        break;
                    }
                    spent += r.cost;
                    used += 1;
                    if best.is_none_or(|b| r.loss < b.loss) {
                        best = Some(r);
                    }
                }
                dose.push(best.map_or(f64::NAN, |b| b.dose_error));
                n.push(used as f64);
                c.push(spent);
            }
            cells.push(Cell {
                knots: k,
                method: m.to_string(),
                dose,
                rollouts: mean_std(&n).0,
                cost: mean_std(&c).0,
            });
        }
    }
    Ok(cells)
}

/// The page.
pub fn report(cells: &[Cell], command: &str, unit: &str, budget: usize) -> String {
    use std::fmt::Write;
    let mut s = String::from(
        "# Trajectory refinement: the adjoint against CMA-ES and random search by dimension\n\n",
    );
    let _ = writeln!(s, "Regenerate: `{command}`  ");
    let _ = writeln!(s, "Machine: {}.\n", super::optimizers::machine());
    let _ = writeln!(
        s,
        "Seed k refines the skill of Θ_init(k) with residuals on its transport and pour (6 channels × knots parameters, `optim::refine`); every method starts from the plain skill and gets the compute of {budget} forward rollouts (a backward pass at {BACKWARD_COST}×). adam: Adam (lr {ADAM_LR}) on the adjoint gradient; trust: the adjoint's direction in a trust region that keeps a step only if the loss falls (the hybrid's local phase); cmaes: CMA-ES (σ₀ {CMA_SIGMA0}); random: uniform draws in the box. Score: dose error ({unit}) of the lowest-loss rollout within each seed's equal-compute budget. p: one-sided exact Wilcoxon signed-rank over the paired seeds that the adjoint method's dose error is smaller than the baseline's (ties dropped). SAC is not run (its policy is written for five parameters).\n"
    );
    s.push_str("| parameters | method | dose error mean ± std | median | p < cmaes | p < random | rollouts | G particle-substeps |\n|---|---|---|---|---|---|---|---|\n");
    for c in cells {
        let (m, sd) = mean_std(&c.dose);
        let p = |base: &str| {
            let b = cells
                .iter()
                .find(|b| b.knots == c.knots && b.method == base);
            match b {
                Some(b) if ADJOINT.contains(&c.method.as_str()) => {
                    wilcoxon_less(&c.dose, &b.dose).map_or("tie".to_string(), |p| format!("{p:.3}"))
                }
                _ => "–".to_string(),
            }
        };
        let _ = writeln!(
            s,
            "| {} | {} | {m:.3} ± {sd:.3} | {:.3} | {} | {} | {:.1} | {:.2} |",
            6 * c.knots,
            c.method,
            median(&c.dose),
            p("cmaes"),
            p("random"),
            c.rollouts,
            c.cost / 1e9
        );
    }
    s
}
