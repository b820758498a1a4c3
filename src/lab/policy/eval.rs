//! The policy on held-out randomised scenes, against a random Θ and the per-scene optimiser.
//!
//! Held-out scene j is drawn from the stream `seed + HELD_OUT_STREAM`, which the dataset never
//! uses. On each:
//! - **optimiser:** `line` on all five parameters ([`line_optimise`]), the lowest-error method
//!   on precise dosing at equal compute (docs/results/optimisation.md), with the full budget:
//!   half of it on the scene's Θ and Sobol points, the rest on the root search of the dose;
//! - **repacked:** the optimiser's Θ on the same scene with another packing seed, one rollout.
//!   No policy sees the grains' packing, so this is the error a policy that knew the optimiser's
//!   answer exactly would still make: what the packing alone costs a one-rollout answer;
//! - **random:** one rollout of a Θ drawn uniformly from the box;
//! - **a policy** (the distilled ensemble, its first member alone, the fine-tuned ensemble): one
//!   rollout of its Θ;
//! - **warm:** `line`'s root search from the distilled policy's Θ with a quarter of the budget
//!   (rounded up), no global phase.
//!
//! Each trial is kept in `dir/scene-J/NAME.json` (a policy's under its [`Policy::fingerprint`]), so
//! a killed run resumes and a new policy reruns only its own trials.

use super::dataset::{cost, draw_scene, forward_equivalents, problem_of, spec_of, Search};
use super::net::Policy;
use crate::lab::optim::line::{self, Budget, Probe};
use crate::lab::optim::problem::{Outcome, Problem};
use crate::scene::randomize::Draw;
use crate::scene::Scene;
use crate::skills::Theta;
use crate::util::SplitMix64;
use anyhow::Context;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Added to the dataset's seed to draw the held-out scenes.
pub const HELD_OUT_STREAM: u64 = 0x4E1D_0075;
/// Added to the packing seed for the `repacked` trial.
pub const REPACK: u64 = 0x9ACC_1465;

/// The trials' names, in the order a table lists them.
pub const METHODS: [&str; 7] = [
    "policy",
    "member",
    "finetuned",
    "random",
    "optimiser",
    "repacked",
    "warm",
];

/// One method on one held-out scene.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Trial {
    pub method: String,
    /// The Θ scored (the search's lowest-loss rollout).
    pub theta: Theta,
    pub loss: f64,
    /// `target − delivered` (g).
    pub indicator: f64,
    /// Forward rollouts spent.
    pub rollouts: f64,
    pub particle_substeps: f64,
    pub wall_s: f64,
}

/// A held-out scene's trials.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SceneEval {
    pub scene: usize,
    pub draw: Draw,
    pub trials: Vec<Trial>,
}

impl SceneEval {
    pub fn get(&self, method: &str) -> Option<&Trial> {
        self.trials.iter().find(|t| t.method == method)
    }
}

/// A policy to evaluate: its name on the page, the network and its fingerprint.
pub struct Candidate<'a> {
    pub name: &'a str,
    pub policy: &'a Policy,
    pub fingerprint: String,
}

/// The held-out comparison's settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalConfig {
    pub scenes: usize,
    /// The first held-out draw: the comparison runs draws `first_draw..first_draw + scenes` of
    /// the held-out stream. Draws below [`DESIGN_DRAWS`] chose the policy's design.
    #[serde(default)]
    pub first_draw: usize,
    /// The per-scene optimiser's full budget (forward rollouts).
    pub budget: usize,
    /// The dataset's seed (the held-out stream is derived from it).
    pub seed: u64,
}

/// The design draws: held-out draws `0..DESIGN_DRAWS` scored successive designs of the policy
/// (its knob head, the dataset's size, the ensemble) and the pour study's variants, which were
/// chosen after seeing those scores. A verdict on fresh data uses draws from here on.
pub const DESIGN_DRAWS: usize = 20;

/// The comparison's folder under the policy study's for held-out draws from `first_draw`
/// (`eval`, or `eval-from-N`).
pub fn dir_name(first_draw: usize) -> String {
    crate::lab::streams::folder("eval", first_draw)
}

/// The page's sentence on which stream held-out draws `first..first + count` are.
pub fn stream_text(first: usize, count: usize) -> String {
    crate::lab::streams::Stream {
        noun: "Held-out draws",
        first,
        count,
        design: DESIGN_DRAWS,
        chosen: "the policy's design (its knob head, the dataset's size, the ensemble) and the pour variants",
        flag: "--first-draw",
    }
    .text()
}

impl EvalConfig {
    /// The comparison's folder under the policy study's ([`dir_name`]).
    pub fn dir_name(&self) -> String {
        dir_name(self.first_draw)
    }

    /// The page's sentence on which draws these are ([`stream_text`]).
    pub fn stream_text(&self) -> String {
        stream_text(self.first_draw, self.scenes)
    }

    /// The warm start's budget: a quarter of the full one, rounded up.
    pub fn warm_budget(&self) -> usize {
        self.budget.div_ceil(4)
    }
}

/// One rollout's trial.
fn single(
    problem: &crate::lab::optim::problem::Problem,
    method: &str,
    theta: Theta,
) -> anyhow::Result<Trial> {
    let o = problem.evaluate(theta, false, true)?;
    Ok(Trial {
        method: method.into(),
        theta,
        loss: o.loss,
        indicator: o.indicator,
        rollouts: 1.0,
        particle_substeps: cost(&o),
        wall_s: o.wall_s,
    })
}

/// `line` on `problem` ([`crate::lab::optim::line`]), as `optimize` runs it on one seed: forward
/// rollouts at `x0` and `global − 1` Sobol points (seeded by `seed`); from the lowest-loss one,
/// the root search of the dose (first across the segment to the lowest-loss rollout on the
/// target's other side, if any), with restarts, until `budget` forward rollouts' compute (a
/// backward pass counted at its cost) is spent. With `global` = 0 the search starts at `x0`.
pub fn line_optimise(
    problem: &Problem,
    x0: Theta,
    global: usize,
    budget: usize,
    seed: u64,
) -> anyhow::Result<Search> {
    let mut trace: Vec<(Theta, Outcome)> = Vec::new();
    let run =
        |theta: Theta, grad: bool, trace: &mut Vec<(Theta, Outcome)>| -> anyhow::Result<Probe> {
            let o = problem.evaluate(theta, grad, true)?;
            let p = Probe {
                indicator: o.indicator,
                loss: o.loss,
                grad: o.grad.map(|g| g.to_vec()),
            };
            trace.push((theta, o));
            Ok(p)
        };
    let mut points = vec![x0];
    points.extend(crate::lab::optim::sobol_thetas(
        global.saturating_sub(1),
        seed as u32,
    ));
    for t in points.iter().take(global) {
        run(*t, false, &mut trace)?;
    }
    let lowest = |it: &mut dyn Iterator<Item = &(Theta, Outcome)>| {
        it.min_by(|a, b| a.1.loss.total_cmp(&b.1.loss)).cloned()
    };
    let (start, known, partner) = match lowest(&mut trace.iter()) {
        None => (x0, None, None),
        Some((t, o)) => {
            let f0 = o.indicator;
            let partner = lowest(&mut trace.iter().filter(|(_, p)| p.indicator * f0 < 0.0))
                .map(|(x, p)| (x.to_vec(), p.indicator));
            (t, Some((f0, o.loss)), partner)
        }
    };
    let mut rng = SplitMix64(seed);
    line::search(
        &start[..],
        known,
        partner.as_ref().map(|(x, f)| (&x[..], *f)),
        Budget::restarting(budget.saturating_sub(global) as f64),
        true,
        &mut rng,
        &mut |w, grad| run(Theta(std::array::from_fn(|i| w[i])), grad, &mut trace),
    )?;
    let (theta, best) = lowest(&mut trace.iter()).context("line ran no rollout")?;
    let rollouts = trace.iter().map(|(_, o)| forward_equivalents(o)).sum();
    Ok(Search {
        theta,
        best,
        rollouts,
        particle_substeps: trace.iter().map(|(_, o)| cost(o)).sum(),
        trace,
    })
}

/// A search's trial.
fn searched(
    method: &str,
    search: impl FnOnce() -> anyhow::Result<Search>,
) -> anyhow::Result<Trial> {
    let t0 = std::time::Instant::now();
    let s = search()?;
    Ok(Trial {
        method: method.into(),
        theta: s.theta,
        loss: s.best.loss,
        indicator: s.best.indicator,
        rollouts: s.rollouts,
        particle_substeps: s.particle_substeps,
        wall_s: t0.elapsed().as_secs_f64(),
    })
}

/// Runs (or resumes) the comparison in `dir`. Without candidates it runs only the optimiser
/// and random Θ, which need no policy. `progress(done)` hears of each finished scene.
pub fn run(
    base: &Scene,
    cfg: &EvalConfig,
    dir: &Path,
    candidates: &[Candidate],
    progress: &(dyn Fn(usize) + Sync),
) -> anyhow::Result<Vec<SceneEval>> {
    crate::util::create_output_dir(dir, "--dir")?;
    let cfg_path = dir.join("eval-config.json");
    let hash = base.fingerprint();
    let stamp = serde_json::json!({ "config": cfg, "scene_hash": hash });
    super::file::stamped(&cfg_path, &stamp, "an evaluation", "--dir")?;
    let spec = spec_of(base)?;
    let done = std::sync::atomic::AtomicUsize::new(0);
    (cfg.first_draw..cfg.first_draw + cfg.scenes)
        .into_par_iter()
        .map(|j| {
            let d = draw_scene(spec, base, cfg.seed.wrapping_add(HELD_OUT_STREAM), j);
            let (problem, f) = problem_of(base, &d)?;
            let sd = dir.join(format!("scene-{j}"));
            std::fs::create_dir_all(&sd)?;
            // The global phase's share of the budget, as `optimize` spends it.
            let share = crate::lab::optim::hybrid::HybridConfig::default().global;
            let global = (share * cfg.budget as f64).floor() as usize;
            let optimiser = super::file::kept(
                &sd.join("optimiser.json"),
                |_| true,
                || {
                    searched("optimiser", || {
                        line_optimise(
                            &problem,
                            problem.scene_theta(),
                            global.max(1),
                            cfg.budget,
                            1_000_000 + j as u64,
                        )
                    })
                },
            )?;
            let repacked = super::file::kept(
                &sd.join("repacked.json"),
                |_| true,
                || {
                    let other = Draw {
                        packing_seed: d.packing_seed.wrapping_add(REPACK),
                        ..d.clone()
                    };
                    single(&problem_of(base, &other)?.0, "repacked", optimiser.theta)
                },
            )?;
            let mut trials = vec![
                optimiser,
                repacked,
                super::file::kept(
                    &sd.join("random.json"),
                    |_| true,
                    || {
                        let mut rng = SplitMix64(0x5EED_0000 ^ j as u64);
                        single(
                            &problem,
                            "random",
                            Theta(std::array::from_fn(|_| rng.uniform_in(-1.0, 1.0))),
                        )
                    },
                )?,
            ];
            for (k, c) in candidates.iter().enumerate() {
                let theta = c.policy.theta(&problem, &d, &f)?;
                trials.push(super::file::kept(
                    &sd.join(format!("{}-{}.json", c.name, c.fingerprint)),
                    |_| true,
                    || single(&problem, c.name, theta),
                )?);
                if k == 0 {
                    trials.push(super::file::kept(
                        &sd.join(format!("warm-{}.json", c.fingerprint)),
                        |_| true,
                        || {
                            searched("warm", || {
                                line_optimise(
                                    &problem,
                                    theta,
                                    0,
                                    cfg.warm_budget(),
                                    2_000_000 + j as u64,
                                )
                            })
                        },
                    )?);
                }
            }
            progress(done.fetch_add(1, std::sync::atomic::Ordering::SeqCst) + 1);
            Ok(SceneEval {
                scene: j,
                draw: d,
                trials,
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()
        .with_context(|| format!("evaluating in {}", dir.display()))
}

/// A method's dose errors |indicator| over the scenes, in scene order.
pub fn errors(rows: &[SceneEval], method: &str) -> Vec<f64> {
    rows.iter()
        .filter_map(|r| r.get(method).map(|t| t.indicator.abs()))
        .collect()
}
