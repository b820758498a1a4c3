//! Running the methods: each method's loop over its rollouts ([`Runner`]), every rollout
//! through the journal (replayed when recorded), and the board that keeps `metrics.csv` and the
//! progress bar current.

use super::cma::reflect;
use super::hybrid::TrustRegion;
use super::journal::{Journal, Record};
use super::problem::Problem;
use super::rmsprop::RmsState;
use super::sac::Sac;
use super::{report, smoothing, sobol_thetas, Method, Settings};
use crate::skills::Theta;
use crate::util::{write_atomic, SplitMix64};
use anyhow::Context;
use indicatif::ProgressBar;
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::fmt::Write;
use std::path::PathBuf;
use std::sync::Mutex;
use std::time::Instant;

/// The records of a run so far, with progress display and `metrics.csv` kept current.
pub(super) struct Board {
    pub(super) records: Mutex<BTreeMap<(Method, usize), Vec<Record>>>,
    pub(super) bar: ProgressBar,
    pub(super) out: PathBuf,
    pub(super) unit: &'static str,
}

impl Board {
    fn push(&self, r: Record) -> anyhow::Result<()> {
        let mut all = self.records.lock().expect("board lock");
        let list = all.entry((r.method, r.seed)).or_default();
        list.push(r.clone());
        report::sort_rollouts(list);
        let done = list.len();
        // Written under the lock: concurrent rollouts share the temporary file name.
        write_atomic(
            &self.out.join("metrics.csv"),
            report::metrics_csv(&all).as_bytes(),
        )?;
        drop(all);
        self.bar.inc(1);
        self.bar.set_message(format!(
            "{} seed {} epoch {done}: loss {:.4e}, indicator {:.3} {}",
            r.method.name(),
            r.seed,
            r.outcome.loss,
            r.outcome.indicator,
            self.unit
        ));
        Ok(())
    }
}

/// What a rollout computes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Pass {
    /// The forward pass only.
    Forward,
    /// The gradient of the scene's loss.
    Gradient,
    /// The gradient of the scene's loss on another packing of the powder
    /// ([`super::problem::Problem::simulation_repacked`]).
    Repacked { frac: f64, seed: u64 },
    /// The gradient of the carry terms ([`super::problem::Problem::carry_terms`]); the loss
    /// reported is still the scene's.
    Carry,
}

/// Runs rollouts through the journal.
pub(super) struct Runner<'a> {
    pub(super) problem: &'a Problem,
    pub(super) journal: &'a Journal,
    pub(super) board: &'a Board,
    /// When this process started the method, and the method's time carried over from the
    /// processes before it (`Journal::carried_elapsed`).
    pub(super) start: Instant,
    pub(super) carried: f64,
}

impl Runner<'_> {
    /// One rollout: replayed from the journal if recorded, else simulated and recorded.
    fn rollout(
        &self,
        method: Method,
        seed: usize,
        batch: usize,
        theta: Theta,
        pass: Pass,
    ) -> anyhow::Result<Record> {
        let r = match self.journal.replay(method, seed, batch, &theta) {
            Some(r) => r,
            None => {
                let o = match pass {
                    Pass::Forward => self.problem.evaluate(theta, false, true)?,
                    Pass::Gradient => self.problem.evaluate(theta, true, true)?,
                    Pass::Repacked { frac, seed } => {
                        self.problem.evaluate_repacked(theta, true, frac, seed)?
                    }
                    Pass::Carry => self.problem.evaluate_carry(theta, true)?.0,
                };
                let r = Record {
                    method,
                    seed,
                    batch,
                    theta,
                    outcome: o,
                    method_elapsed_s: Some(self.carried + self.start.elapsed().as_secs_f64()),
                };
                self.journal.append(&r)?;
                r
            }
        };
        self.board.push(r.clone())?;
        Ok(r)
    }

    /// RMSprop with the curriculum on the adjoint gradient: `grad` (the paper's method) on the
    /// scene's loss throughout; `carry` on the carry terms while the curriculum moves only the
    /// scoop parameters, then on the scene's loss.
    pub(super) fn descend(&self, s: &Settings, method: Method) -> anyhow::Result<()> {
        let rms = s.rmsprop_for(method);
        let mut states: Vec<RmsState> = (0..s.seeds)
            .map(|k| RmsState {
                theta: s.start(k),
                mean_square: [0.0; 5],
            })
            .collect();
        let mut norms: Vec<Vec<f64>> = vec![Vec::new(); s.seeds];
        for epoch in 1..=s.epochs_for(method) {
            let pass = if method == Method::Carry && epoch <= rms.switch_epoch {
                Pass::Carry
            } else {
                Pass::Gradient
            };
            let recs: Vec<Record> = states
                .par_iter()
                .enumerate()
                .map(|(k, st)| self.rollout(method, k, epoch - 1, st.theta, pass))
                .collect::<anyhow::Result<_>>()?;
            for ((st, r), h) in states.iter_mut().zip(&recs).zip(&mut norms) {
                let g = r
                    .outcome
                    .grad
                    .context("a grad rollout without its gradient")?;
                let g = rms.clip(g, epoch, h);
                rms.step(st, g, epoch);
            }
        }
        Ok(())
    }

    pub(super) fn smoothed(&self, s: &Settings) -> anyhow::Result<()> {
        let (n, sigma) = (s.smoothing.samples.max(2), s.smoothing.sigma);
        let rms = s.rmsprop_for(Method::Smoothed);
        let mut states: Vec<RmsState> = (0..s.seeds)
            .map(|k| RmsState {
                theta: s.start(k),
                mean_square: [0.0; 5],
            })
            .collect();
        let mut rngs: Vec<SplitMix64> = (0..s.seeds)
            .map(|k| SplitMix64(s.method_seed(Method::Smoothed, k)))
            .collect();
        for step in 1..=s.epochs_for(Method::Smoothed) / n {
            // Θ + σξ for every seed and sample, clamped to the box; ξ is recomputed from the
            // clamped point so the zeroth-order estimate uses the Θ that ran.
            let jobs: Vec<(usize, Theta, [f64; 5])> = states
                .iter()
                .zip(&mut rngs)
                .enumerate()
                .flat_map(|(k, (st, rng))| {
                    (0..n)
                        .map(|_| {
                            let t = Theta(std::array::from_fn(|i| {
                                (st.theta[i] + sigma * rng.normal()).clamp(-1.0, 1.0)
                            }));
                            let xi = std::array::from_fn(|i| (t[i] - st.theta[i]) / sigma);
                            (k, t, xi)
                        })
                        .collect::<Vec<_>>()
                })
                .collect();
            let recs: Vec<Record> = jobs
                .par_iter()
                .enumerate()
                .map(|(i, &(k, t, _))| {
                    // Sample j of seed k's step has a packing of its own (the jobs hold each
                    // seed's n samples in a row).
                    let pass = if s.smoothing.packing > 0.0 {
                        Pass::Repacked {
                            frac: s.smoothing.packing,
                            seed: s.method_seed(Method::Smoothed, k)
                                ^ (((step * n + i % n) as u64) << 40),
                        }
                    } else {
                        Pass::Gradient
                    };
                    self.rollout(Method::Smoothed, k, step - 1, t, pass)
                })
                .collect::<anyhow::Result<_>>()?;
            for (k, st) in states.iter_mut().enumerate() {
                let samples: Vec<smoothing::Sample> = jobs
                    .iter()
                    .zip(&recs)
                    .filter(|((j, _, _), _)| *j == k)
                    .map(|((_, _, xi), r)| {
                        Ok(smoothing::Sample {
                            xi: *xi,
                            loss: r.outcome.loss,
                            grad: r
                                .outcome
                                .grad
                                .context("a smoothed rollout without its gradient")?,
                        })
                    })
                    .collect::<anyhow::Result<_>>()?;
                let (g, _) = smoothing::alpha_order(&samples, sigma);
                // The curriculum frees θ_t and θ_p after the same rollouts as grad's.
                rms.step(st, g, step * n);
            }
        }
        Ok(())
    }

    pub(super) fn sac(&self, s: &Settings) -> anyhow::Result<()> {
        let mut agents: Vec<Sac> = (0..s.seeds)
            .map(|k| Sac::new(s.sac, &s.start(k)[..], s.method_seed(Method::Sac, k)))
            .collect::<candle_core::Result<_>>()?;
        // The temperature and the reward's standardisation, per seed and episode.
        let mut log = String::from("seed,episode,alpha,loss_mean,loss_std\n");
        for episode in 0..s.epochs {
            let actions: Vec<Theta> = agents
                .iter_mut()
                .map(|a| a.act().map(|v| Theta(std::array::from_fn(|i| v[i]))))
                .collect::<candle_core::Result<_>>()?;
            let recs: Vec<Record> = actions
                .par_iter()
                .enumerate()
                .map(|(k, th)| self.rollout(Method::Sac, k, episode, *th, Pass::Forward))
                .collect::<anyhow::Result<_>>()?;
            agents
                .par_iter_mut()
                .zip(recs.par_iter())
                .try_for_each(|(a, r)| a.observe(&r.theta[..], r.outcome.loss))?;
            for (k, a) in agents.iter().enumerate() {
                let (alpha, mean, std) = a.stats()?;
                let _ = writeln!(log, "{k},{},{alpha},{mean},{std}", episode + 1);
            }
            write_atomic(&self.board.out.join("sac.csv"), log.as_bytes())?;
        }
        Ok(())
    }

    pub(super) fn random(&self, s: &Settings) -> anyhow::Result<()> {
        let jobs: Vec<(usize, usize, Theta)> = (0..s.seeds)
            .flat_map(|k| {
                let mut rng = SplitMix64(s.method_seed(Method::Random, k));
                (0..s.epochs).map(move |i| {
                    let th = if i == 0 {
                        s.start(k)
                    } else {
                        Theta(std::array::from_fn(|_| rng.uniform_in(-1.0, 1.0)))
                    };
                    (k, i, th)
                })
            })
            .collect();
        jobs.par_iter()
            .map(|&(k, i, th)| {
                self.rollout(Method::Random, k, i, th, Pass::Forward)
                    .map(|_| ())
            })
            .collect::<anyhow::Result<()>>()
    }

    pub(super) fn cmaes(&self, s: &Settings) -> anyhow::Result<()> {
        let lambda = s.cmaes.population.max(2);
        let generations = s.epochs.div_ceil(lambda);
        let failure: Mutex<Option<anyhow::Error>> = Mutex::new(None);
        // Per seed: the generation being evaluated and how many rollouts it may still run.
        let gens: Vec<Mutex<(usize, usize)>> = (0..s.seeds).map(|_| Mutex::new((0, 0))).collect();
        let objectives: Vec<_> = (0..s.seeds)
            .map(|k| {
                let (gens, failure) = (&gens, &failure);
                move |x: &cmaes::DVector<f64>| -> f64 {
                    let th = Theta(std::array::from_fn(|i| reflect(x[i])));
                    let generation = {
                        let mut g = gens[k].lock().expect("lock");
                        if g.1 == 0 {
                            // Past the budget in a last, partial generation: not run.
                            return f64::MAX;
                        }
                        g.1 -= 1;
                        g.0
                    };
                    match self.rollout(Method::Cmaes, k, generation, th, Pass::Forward) {
                        Ok(r) => r.outcome.loss,
                        Err(e) => {
                            failure.lock().expect("lock").get_or_insert(e);
                            f64::NAN
                        }
                    }
                }
            })
            .collect();
        let mut states: Vec<_> = objectives
            .iter()
            .enumerate()
            .map(|(k, f)| {
                cmaes::CMAESOptions::new(s.start(k).to_vec(), s.cmaes.sigma0)
                    .population_size(lambda)
                    .seed(s.method_seed(Method::Cmaes, k))
                    .build(f)
                    .map_err(|e| anyhow::anyhow!("CMA-ES options: {e:?}"))
            })
            .collect::<anyhow::Result<_>>()?;
        for generation in 0..generations {
            let budget = (s.epochs - generation * lambda).min(lambda);
            for g in &gens {
                *g.lock().expect("lock") = (generation, budget);
            }
            // A termination criterion of the crate (e.g. a flat objective) ends nothing here:
            // the method gets its whole budget, like the others.
            states.par_iter_mut().for_each(|st| {
                let _ = if budget == lambda {
                    st.next_parallel()
                } else {
                    // A partial generation runs in the sampler's order, so which samples fit
                    // the budget does not depend on the threads.
                    st.next()
                };
            });
            if let Some(e) = failure.lock().expect("lock").take() {
                return Err(e);
            }
        }
        Ok(())
    }

    /// The forward-only global phase of the hybrid, `line` and `ray`: Θ_init, then the hybrid's
    /// Owen-scrambled Sobol points (the same for the three methods, so they differ only in
    /// what follows), the first `global` of them run as `method`. Returns how many ran, every
    /// seed's points (the unused ones are the hybrid's spares) and the rollouts.
    fn global_phase(&self, s: &Settings, method: Method) -> anyhow::Result<GlobalPhase> {
        let global = ((s.hybrid.global * s.epochs as f64).floor() as usize).clamp(1, s.epochs);
        let points: Vec<Vec<Theta>> = (0..s.seeds)
            .map(|k| {
                let mut v = vec![s.start(k)];
                v.extend(sobol_thetas(
                    s.epochs - 1,
                    s.method_seed(Method::Hybrid, k) as u32,
                ));
                v
            })
            .collect();
        let jobs: Vec<(usize, usize, Theta)> = points
            .iter()
            .enumerate()
            .flat_map(|(k, p)| {
                p.iter()
                    .take(global)
                    .enumerate()
                    .map(move |(i, t)| (k, i, *t))
            })
            .collect();
        let found = jobs
            .par_iter()
            .map(|&(k, i, t)| self.rollout(method, k, i, t, Pass::Forward))
            .collect::<anyhow::Result<_>>()?;
        Ok(GlobalPhase {
            ran: global,
            points,
            found,
        })
    }

    /// `line` or `ray` ([`super::line`]): the hybrid's global phase, then the root search from
    /// its lowest-loss point, with restarts, within the compute of `epochs` forward rollouts.
    /// Where the global phase both over- and under-delivered, the search first closes the
    /// segment from that point to the lowest-loss rollout on the target's other side. A rollout's
    /// batch is its place in the seed's sequence.
    pub(super) fn line(&self, s: &Settings, method: Method) -> anyhow::Result<()> {
        let GlobalPhase {
            ran: global, found, ..
        } = self.global_phase(s, method)?;
        let budget = super::line::Budget::restarting((s.epochs - global) as f64);
        (0..s.seeds).into_par_iter().try_for_each(|k| {
            let start = lowest(&found, k).context("the global phase ran nothing")?;
            let f0 = start.outcome.indicator;
            let partner = lowest(found.iter().filter(|r| r.outcome.indicator * f0 < 0.0), k);
            let mut rng = SplitMix64(s.method_seed(method, k));
            let mut batch = global;
            super::line::search(
                &start.theta[..],
                Some((f0, start.outcome.loss)),
                partner.map(|r| (&r.theta[..], r.outcome.indicator)),
                budget,
                method == Method::Line,
                &mut rng,
                &mut |w, with_grad| {
                    let theta = Theta(std::array::from_fn(|i| w[i]));
                    let pass = if with_grad {
                        Pass::Gradient
                    } else {
                        Pass::Forward
                    };
                    let r = self.rollout(method, k, batch, theta, pass)?;
                    batch += 1;
                    Ok(super::line::Probe {
                        indicator: r.outcome.indicator,
                        loss: r.outcome.loss,
                        grad: r.outcome.grad.map(|g| g.to_vec()),
                    })
                },
            )
        })
    }

    /// The hybrid ([`super::hybrid`]): Sobol points, then a trust region along the adjoint
    /// gradient from the best of them, within the compute of `epochs` forward rollouts.
    pub(super) fn hybrid(&self, s: &Settings) -> anyhow::Result<()> {
        let budget = s.epochs as f64;
        let GlobalPhase {
            ran: global,
            points,
            found,
        } = self.global_phase(s, Method::Hybrid)?;
        let grad_cost = 1.0 + report::BACKWARD_COST;
        (0..s.seeds).into_par_iter().try_for_each(|k| {
            let inc = lowest(&found, k).context("the hybrid's global phase ran nothing")?;
            let mut inc = (inc.theta, inc.outcome.loss);
            let mut spent = global as f64;
            let mut batch = global;
            let mut tr = TrustRegion {
                radius: s.hybrid.radius,
            };
            let mut grad: Option<[f64; 5]> = None;
            // Sobol points not used by the global phase: where the gradient gives no direction
            // (all zero), the rest of the budget continues the search instead of idling.
            let mut spare = points[k].iter().copied().skip(global);
            loop {
                let trial = match grad {
                    None => {
                        if spent + grad_cost > budget + 1e-9 {
                            break;
                        }
                        let r = self.rollout(Method::Hybrid, k, batch, inc.0, Pass::Gradient)?;
                        batch += 1;
                        spent += grad_cost;
                        grad = Some(
                            r.outcome
                                .grad
                                .context("a hybrid gradient rollout without its gradient")?,
                        );
                        continue;
                    }
                    Some(g) => tr.propose(inc.0, g),
                };
                if spent + 1.0 > budget + 1e-9 {
                    break;
                }
                let (trial, searched) = match trial {
                    Some(t) => (t, false),
                    None => match spare.next() {
                        Some(t) => (t, true),
                        None => break,
                    },
                };
                let r = self.rollout(Method::Hybrid, k, batch, trial, Pass::Forward)?;
                batch += 1;
                spent += 1.0;
                let better = if searched {
                    r.outcome.loss < inc.1
                } else {
                    tr.judge(inc.1, r.outcome.loss, s.hybrid.radius)
                };
                if better {
                    inc = (trial, r.outcome.loss);
                    grad = None;
                }
            }
            Ok(())
        })
    }
}

/// What a forward-only global phase ran.
struct GlobalPhase {
    /// Points run per seed.
    ran: usize,
    /// Every seed's points, the unused ones included.
    points: Vec<Vec<Theta>>,
    found: Vec<Record>,
}

/// Seed `k`'s lowest-loss rollout of `found` (the first of equal losses, in order).
fn lowest<'a>(found: impl IntoIterator<Item = &'a Record>, k: usize) -> Option<&'a Record> {
    found
        .into_iter()
        .filter(|r| r.seed == k)
        .fold(None::<&Record>, |b, r| match b {
            Some(b) if b.outcome.loss <= r.outcome.loss => Some(b),
            _ => Some(r),
        })
}
