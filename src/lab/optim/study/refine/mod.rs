//! `powderlab study refine`: trajectory refinement in 6·knots dimensions, the adjoint against
//! CMA-ES and random search at equal compute.
//!
//! Seed `k` refines the skill of its start Θ ([`starts`]: Θ_init(k), or an over-delivering
//! Sobol point) with a residual of `knots` knots per control channel on its transport and pour
//! ([`crate::lab::optim::refine`]); every method starts from `w = 0` (the plain skill). Methods:
//! - **line**: the adjoint's axis, then a bracketed root search of the dose along it (`line`);
//! - **ray**: the same search along random axes, forward only (`ray`, the ablation);
//! - **adam**: Adam (β₁ 0.9, β₂ 0.999, lr [`ADAM_LR`]) on the adjoint `∂L/∂w`, projected to the
//!   box, `⌈budget/(1 + BACKWARD_COST)⌉` gradient rollouts;
//! - **trust**: the adjoint's direction in the hybrid's trust region (a step is kept only if the
//!   loss falls), gradient rollouts at their cost and forward-only trials within the budget;
//! - **cmaes**: the `cmaes` crate from `w = 0`, σ₀ [`CMA_SIGMA0`], its default population for
//!   the dimension, samples reflected into the box, `budget` rollouts;
//! - **random**: `w = 0`, then uniform draws in the box, `budget` rollouts;
//! - **sac**: the benchmark's SAC ([`crate::lab::optim::sac`], its default settings) over `w`, its
//!   first action `w = 0`, `budget` rollouts.
//!
//! Each method's score
//! is the dose error of its rollout of lowest loss within the compute of `budget` forward
//! rollouts (in particle-substeps, a backward pass at `BACKWARD_COST`). Every rollout goes to
//! `rollouts.jsonl` as it finishes and is replayed from there, so a killed study resumes.

mod page;
pub use page::report;

use crate::lab::optim::cma::reflect;
use crate::lab::optim::hybrid::{HybridConfig, TrustRegion};
pub use crate::lab::optim::line::{self, LINE_STEPS};
use crate::lab::optim::problem::Problem;
pub use crate::lab::optim::report::gradient_rollouts;
use crate::lab::optim::report::BACKWARD_COST;
use crate::lab::optim::theta_init;
use crate::lab::stats::mean;
use crate::skills::Theta;
use crate::util::SplitMix64;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::Path;

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
    /// Particle-substeps of the forward pass; a gradient rollout's backward pass is counted
    /// at the multiple the study measures ([`Rollout::cost_at`]).
    pub forward_ps: f64,
    pub wall_s: f64,
    #[serde(default)]
    pub grad: Option<Vec<f64>>,
    /// `target − delivered`, signed (the line method solves it for 0).
    #[serde(default)]
    pub indicator: f64,
}

impl Rollout {
    /// Particle-substeps with a backward pass (if any) at `backward_cost` forward passes.
    pub fn cost_at(&self, backward_cost: f64) -> f64 {
        crate::lab::optim::report::with_backward(
            self.forward_ps,
            self.grad.is_some(),
            backward_cost,
        )
    }
}

/// The backward multiple measured in rollouts of one study
/// ([`crate::lab::optim::report::backward_multiple`]); the planned [`BACKWARD_COST`] where they
/// are not of both kinds.
pub fn measured_backward_cost<'a>(rollouts: impl Iterator<Item = &'a Rollout>) -> f64 {
    crate::lab::optim::report::backward_multiple(rollouts.map(|r| (r.grad.is_some(), r.wall_s)))
        .unwrap_or(BACKWARD_COST)
}

type Key = (usize, String, usize, usize);

/// The rollouts of a study folder, replayed or run.
pub struct Store {
    known: HashMap<Key, Rollout>,
    file: crate::lab::journal::Journal<Rollout>,
    progress: Box<dyn Fn() + Sync>,
}

impl Store {
    pub fn open(dir: &Path, progress: Box<dyn Fn() + Sync>) -> anyhow::Result<Store> {
        crate::util::create_output_dir(dir, "--out")?;
        let path = dir.join("rollouts.jsonl");
        // A torn last line (killed mid-write) is cut off.
        let (file, rollouts) = crate::lab::journal::Journal::<Rollout>::open(&path)?;
        let known = rollouts
            .into_iter()
            .map(|r| ((r.knots, r.method.clone(), r.seed, r.index), r))
            .collect();
        Ok(Store {
            known,
            file,
            progress,
        })
    }

    /// The rollout of `(knots, method, seed, index)` at `w`: replayed if recorded with bitwise
    /// the same `w`, else run and recorded.
    #[allow(clippy::too_many_arguments)]
    fn get(
        &self,
        problem: &Problem,
        theta: Theta,
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
        // Knots 0 is the screening's plain skill: one knot with zero weights adds nothing.
        let res = problem.residual(theta, knots.max(1));
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
            forward_ps: forward,
            wall_s: o.wall_s,
            grad,
            indicator: o.indicator,
        };
        self.file.append(&r)?;
        (self.progress)();
        Ok(r)
    }
}

/// One seed's refinement problem: the store, the problem, the dimension, the seed and its
/// start Θ.
struct Ctx<'a> {
    s: &'a Store,
    p: &'a Problem,
    knots: usize,
    seed: usize,
    theta: Theta,
}

impl Ctx<'_> {
    fn get(
        &self,
        method: &str,
        index: usize,
        w: &[f64],
        with_grad: bool,
    ) -> anyhow::Result<Rollout> {
        self.s.get(
            self.p, self.theta, self.knots, method, self.seed, index, w, with_grad,
        )
    }
}

/// The start Θ of each seed. Without `over`, Θ_init(k). With it, the k-th point of the
/// landscape map's Sobol design ([`crate::lab::optim::sobol_thetas`]`(256, 0)`, in order) whose plain
/// skill delivers at least `over` (the target's unit) more than the target: a spoon that carries
/// more than the dose, so that the transport and the pour decide how much of it arrives. The
/// screening rollouts (forward, the plain skill) are recorded as method `screen` and shared by
/// every method; they count against none.
pub fn starts(
    store: &Store,
    problem: &Problem,
    over: Option<f64>,
    seeds: usize,
) -> anyhow::Result<(Vec<Theta>, Option<Screen>)> {
    let Some(over) = over else {
        return Ok(((0..seeds).map(theta_init).collect(), None));
    };
    let points = crate::lab::optim::sobol_thetas(SCREEN_POINTS, 0);
    let mut found = Vec::new();
    let mut screen = Screen {
        over,
        screened: 0,
        reach: 0,
    };
    let batch = rayon::current_num_threads().max(1);
    for (i, chunk) in points.chunks(batch).enumerate() {
        let first = i * batch;
        let rs: Vec<Rollout> = chunk
            .par_iter()
            .enumerate()
            .map(|(j, &t)| store.get(problem, t, 0, "screen", first + j, 0, &[0.0; 6], false))
            .collect::<anyhow::Result<_>>()?;
        for (r, &t) in rs.iter().zip(chunk) {
            if found.len() == seeds {
                break;
            }
            screen.screened += 1;
            screen.reach += usize::from(r.indicator <= 0.0);
            if -r.indicator >= over {
                found.push(t);
            }
        }
        if found.len() == seeds {
            return Ok((found, Some(screen)));
        }
    }
    anyhow::bail!(
        "study refine --over {over}: only {} of the {SCREEN_POINTS} Sobol points deliver {over} more than the target, fewer than --seeds {seeds}; lower --over or --seeds",
        found.len()
    )
}

/// What the screening for over-delivering starts saw, up to the last start it kept.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Screen {
    /// The margin asked for (the target's unit).
    pub over: f64,
    /// Sobol points run.
    pub screened: usize,
    /// Of them, those whose plain skill delivers at least the target: the only ones whose dose
    /// a residual on the transport and pour can reach, since it cannot add to the spoon's load.
    pub reach: usize,
}

/// Sobol points screened for over-delivering starts.
pub const SCREEN_POINTS: usize = 256;

/// Adam on the adjoint gradient.
fn adam(c: &Ctx, budget: usize) -> anyhow::Result<Vec<Rollout>> {
    let d = 6 * c.knots;
    let n = gradient_rollouts(budget);
    let (b1, b2, eps) = (0.9, 0.999, 1e-8);
    let (mut w, mut m, mut v) = (vec![0.0; d], vec![0.0; d], vec![0.0; d]);
    let mut out = Vec::new();
    for t in 1..=n {
        let r = c.get("adam", t - 1, &w, true)?;
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
/// ([`crate::lab::optim::hybrid`]) on `w`. A gradient rollout at the incumbent gives the direction;
/// the trial `w − r·g/‖g‖` runs forward only and is kept if its loss falls (the radius grows),
/// else the radius shrinks and the next trial reuses the gradient. It stops when the next
/// rollout would pass `budget` forward rollouts' compute, or when the gradient is zero.
fn trust(c: &Ctx, budget: usize) -> anyhow::Result<Vec<Rollout>> {
    let initial = HybridConfig::default().radius;
    let mut tr = TrustRegion { radius: initial };
    let (budget, grad_cost) = (budget as f64 + 1e-9, 1.0 + BACKWARD_COST);
    let mut w = vec![0.0; 6 * c.knots];
    let mut out: Vec<Rollout> = Vec::new();
    let (mut spent, mut incumbent, mut grad) = (0.0, f64::INFINITY, None::<Vec<f64>>);
    loop {
        let Some(g) = &grad else {
            if !out.is_empty() && spent + grad_cost > budget {
                break;
            }
            let r = c.get("trust", out.len(), &w, true)?;
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
        let r = c.get("trust", out.len(), &trial, false)?;
        spent += 1.0;
        if tr.judge(incumbent, r.loss, initial) {
            w = trial;
            grad = None;
        }
        out.push(r);
    }
    Ok(out)
}

/// The adjoint picks the direction, forward rollouts solve for the dose along it
/// ([`crate::lab::optim::line`]): a gradient rollout at `w`, forward trials at `w ± a·u` for `a` in
/// [`LINE_STEPS`], then Illinois regula falsi on the bracket until the budget is spent. Without a
/// bracket, the lowest-loss trial (if lower than `w`'s) becomes the new `w`; if none is lower, it
/// stops.
fn line(c: &Ctx, budget: usize) -> anyhow::Result<Vec<Rollout>> {
    line_search(c, budget, true)
}

/// The line method with a random direction instead of the adjoint's (method `ray`), the
/// ablation that says whether the gradient's direction matters: a forward rollout at `w`, then
/// the same bracketing and root search along a direction of independent normal draws
/// (normalised); without a bracket it moves to the lowest-loss trial if one is lower, and draws
/// a new direction either way.
fn ray(c: &Ctx, budget: usize) -> anyhow::Result<Vec<Rollout>> {
    line_search(c, budget, false)
}

/// [`line`] (`adjoint`) or [`ray`], without restarts (the published figures').
fn line_search(c: &Ctx, budget: usize, adjoint: bool) -> anyhow::Result<Vec<Rollout>> {
    let method = if adjoint { "line" } else { "ray" };
    let mut rng = SplitMix64(0x4A7_0000 + c.seed as u64 * 131 + c.knots as u64);
    let mut out: Vec<Rollout> = Vec::new();
    line::search(
        &vec![0.0; 6 * c.knots],
        None,
        None,
        line::Budget {
            forward_rollouts: budget as f64,
            gradient_cost: 1.0 + BACKWARD_COST,
            restart: false,
            closed: line::CLOSED,
        },
        adjoint,
        &mut rng,
        &mut |w, with_grad| {
            let r = c.get(method, out.len(), w, with_grad)?;
            let p = line::Probe {
                indicator: r.indicator,
                loss: r.loss,
                grad: r.grad.clone(),
            };
            out.push(r);
            Ok(p)
        },
    )?;
    Ok(out)
}

/// Random search: `w = 0`, then uniform draws in the box.
fn random(c: &Ctx, budget: usize) -> anyhow::Result<Vec<Rollout>> {
    let (seed, knots) = (c.seed, c.knots);
    let mut rng = SplitMix64(0x5EED_0000 + seed as u64 * 131 + knots as u64);
    (0..budget)
        .map(|i| {
            let w: Vec<f64> = if i == 0 {
                vec![0.0; 6 * knots]
            } else {
                (0..6 * knots).map(|_| rng.uniform_in(-1.0, 1.0)).collect()
            };
            c.get("random", i, &w, false)
        })
        .collect()
}

/// CMA-ES from `w = 0`, one sample at a time (the sampler's order), `budget` rollouts.
fn cmaes(c: &Ctx, budget: usize) -> anyhow::Result<Vec<Rollout>> {
    let mut out: Vec<Rollout> = Vec::new();
    crate::lab::optim::cma::run_sequential(
        vec![0.0; 6 * c.knots],
        CMA_SIGMA0,
        0xC3A_0000 + c.seed as u64,
        budget,
        |x| {
            let w: Vec<f64> = x.iter().map(|v| reflect(*v)).collect();
            let r = c.get("cmaes", out.len(), &w, false)?;
            let l = r.loss;
            out.push(r);
            Ok(l)
        },
    )?;
    Ok(out)
}

/// SAC from `w = 0` (its first action), one rollout per episode, `budget` rollouts.
fn sac(c: &Ctx, budget: usize) -> anyhow::Result<Vec<Rollout>> {
    let mut agent = crate::lab::optim::sac::Sac::new(
        crate::lab::optim::sac::SacConfig::default(),
        &vec![0.0; 6 * c.knots],
        0x5AC_0000 + c.seed as u64 * 131 + c.knots as u64,
    )?;
    let mut out: Vec<Rollout> = Vec::new();
    for i in 0..budget {
        let w = agent.act()?;
        let r = c.get("sac", i, &w, false)?;
        agent.observe(&w, r.loss)?;
        out.push(r);
    }
    Ok(out)
}

/// The methods, in the page's order.
pub const METHODS: [&str; 7] = ["line", "adam", "trust", "ray", "cmaes", "random", "sac"];

/// The baselines every adjoint method is tested against.
const BASELINES: [&str; 3] = ["cmaes", "random", "sac"];

/// The methods that use the adjoint, each tested against each baseline.
const ADJOINT: [&str; 3] = ["line", "adam", "trust"];

/// One (dimension, method) cell: per seed, the dose error at equal compute.
#[derive(Clone, Debug, Serialize)]
pub struct Cell {
    pub knots: usize,
    pub method: String,
    pub dose: Vec<f64>,
    pub rollouts: f64,
    pub cost: f64,
    /// The backward multiple the scores count (measured in this dimension's rollouts).
    pub backward_cost: f64,
}

/// Runs every dimension, method and seed and scores them at each seed's equal-compute budget
/// (the smallest spend of any method on that seed and dimension).
pub fn run(
    problem: &Problem,
    knots: &[usize],
    starts: &[Theta],
    budget: usize,
    store: &Store,
) -> anyhow::Result<Vec<Cell>> {
    let seeds = starts.len();
    let mut cells = Vec::new();
    for &k in knots {
        let per: Vec<Vec<Vec<Rollout>>> = METHODS
            .iter()
            .map(|m| {
                (0..seeds)
                    .into_par_iter()
                    .map(|seed| {
                        let c = Ctx {
                            s: store,
                            p: problem,
                            knots: k,
                            seed,
                            theta: starts[seed],
                        };
                        match *m {
                            "line" => line(&c, budget),
                            "adam" => adam(&c, budget),
                            "trust" => trust(&c, budget),
                            "cmaes" => cmaes(&c, budget),
                            "ray" => ray(&c, budget),
                            "sac" => sac(&c, budget),
                            _ => random(&c, budget),
                        }
                    })
                    .collect::<anyhow::Result<Vec<_>>>()
            })
            .collect::<anyhow::Result<_>>()?;
        let bc = measured_backward_cost(per.iter().flatten().flatten());
        let spend = |l: &[Rollout]| l.iter().map(|r| r.cost_at(bc)).sum::<f64>();
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
                    if spent + r.cost_at(bc) > budgets[seed] * (1.0 + 1e-12) && used > 0 {
                        break;
                    }
                    spent += r.cost_at(bc);
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
                rollouts: mean(&n),
                cost: mean(&c),
                backward_cost: bc,
            });
        }
    }
    Ok(cells)
}
