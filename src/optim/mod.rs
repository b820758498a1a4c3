//! `powderlab optimize`: skill optimisation of the transport task (docs/design.md §5), by gradient
//! descent through the simulation and by three baselines given the same rollout budget.
//!
//! - **grad**: RMSprop (β = 0.9, lr = 0.05, ε = 1e-8) on `∂L/∂Θ` from the adjoint pass, with the
//!   curriculum (epochs 1–15 move only θ_d, θ_s, θ_l) and the projection back to [−1, 1]
//!   ([`rmsprop`]). One rollout with its backward pass per epoch.
//! - **cmaes**: CMA-ES from the same Θ_init ([`cma`]).
//! - **sac**: soft actor-critic over Θ, one rollout per episode, reward `−L` ([`sac`]).
//! - **random**: Θ_init, then uniform draws in [−1, 1]⁵.
//!
//! **Budget.** Every method gets `epochs` rollouts per seed; the x-axis of the results is the
//! number of rollouts so far ("epoch"). What a method has found after `k` rollouts is its
//! rollout of lowest loss among the first `k` (the loss is what every method can see; the
//! indicator is the task's score of that rollout). For grad this need not be its latest iterate:
//! on the transport scene the loss is rough at RMSprop's step size (see `docs/results/skill_optimisation.md`).
//!
//! **Seeds.** Seed `k` draws Θ_init uniformly in [−1, 1]⁵ from a fixed generator
//! ([`theta_init`]); every method starts seed `k` from the same Θ_init, and the methods' own
//! random draws come from generators seeded from `k` too.
//!
//! **Parallel rollouts.** Rollouts that do not depend on each other run side by side on the
//! worker pool: the seeds of grad and sac (one rollout each per epoch), a whole CMA-ES
//! generation of every seed, every draw of random search. Each rollout's systems run in the
//! same pool, so a worker with nothing else to do helps a running rollout; the numbers do not
//! depend on the number of threads.
//!
//! **Outputs** (in `--out DIR`, each written atomically): `metrics.csv`, `summary.json`,
//! `indicator.svg`, `best.rrd`, `sac.csv` (SAC's temperature and reward scale per episode), plus
//! `journal.jsonl` and `settings.json`, which `--resume` uses
//! ([`journal`]).

pub mod cma;
pub mod journal;
pub mod plot;
pub mod problem;
pub mod report;
pub mod rmsprop;
pub mod sac;

use crate::util::{write_atomic, SplitMix64};
use anyhow::{bail, Context};
use cma::{reflect, CmaConfig};
use indicatif::{ProgressBar, ProgressStyle};
use journal::{Journal, Record};
use problem::Problem;
use rayon::prelude::*;
use rmsprop::{RmsProp, RmsState};
use sac::{Sac, SacConfig};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt::Write;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Instant;

/// An optimisation method.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    Grad,
    Cmaes,
    Sac,
    Random,
}

impl Method {
    pub const ALL: [Method; 4] = [Method::Grad, Method::Cmaes, Method::Sac, Method::Random];

    pub fn name(self) -> &'static str {
        match self {
            Method::Grad => "grad",
            Method::Cmaes => "cmaes",
            Method::Sac => "sac",
            Method::Random => "random",
        }
    }

    /// Parses a method name, or `all`.
    pub fn parse_list(s: &str) -> Option<Vec<Method>> {
        if s == "all" {
            return Some(Method::ALL.to_vec());
        }
        Method::ALL.iter().find(|m| m.name() == s).map(|m| vec![*m])
    }
}

/// Everything that fixes the numbers of a run; `--resume` refuses a run whose settings differ.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Settings {
    /// FNV-1a hash of the scene file's text.
    pub scene_hash: String,
    pub methods: Vec<Method>,
    /// Rollouts per seed and method.
    pub epochs: usize,
    pub seeds: usize,
    pub rmsprop: RmsProp,
    pub cmaes: CmaConfig,
    pub sac: SacConfig,
    /// Memory budget of a backward pass's tape (bytes).
    pub tape_budget: usize,
}

/// How to run.
#[derive(Clone, Debug)]
pub struct Options {
    pub settings: Settings,
    pub out: PathBuf,
    pub resume: bool,
    /// No progress bars.
    pub quiet: bool,
}

/// FNV-1a, 64 bits: a stable fingerprint of the scene text.
pub fn fnv1a(text: &str) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in text.bytes() {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("{h:016x}")
}

/// Θ_init of seed `k`: uniform in [−1, 1]⁵.
pub fn theta_init(k: usize) -> [f64; 5] {
    let mut rng = SplitMix64(0x7E7A_1A17 + k as u64);
    std::array::from_fn(|_| rng.uniform_in(-1.0, 1.0))
}

/// Seed of a method's own generator for seed `k`.
fn method_seed(m: Method, k: usize) -> u64 {
    ((m as u64 + 1) << 32) + k as u64
}

/// The records of a run so far, with progress display and `metrics.csv` kept current.
struct Board {
    records: Mutex<BTreeMap<(Method, usize), Vec<Record>>>,
    bar: ProgressBar,
    out: PathBuf,
    unit: &'static str,
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

/// Runs rollouts through the journal.
struct Runner<'a> {
    problem: &'a Problem,
    journal: &'a Journal,
    board: &'a Board,
    /// When this process started the method, and the method's time carried over from the
    /// processes before it (`Journal::carried_elapsed`).
    start: Instant,
    carried: f64,
}

impl Runner<'_> {
    /// One rollout: replayed from the journal if recorded, else simulated and recorded.
    fn rollout(
        &self,
        method: Method,
        seed: usize,
        batch: usize,
        theta: [f64; 5],
        with_grad: bool,
    ) -> anyhow::Result<Record> {
        let r = match self.journal.replay(method, seed, batch, &theta) {
            Some(r) => r,
            None => {
                let o = self.problem.evaluate(theta, with_grad, true)?;
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

    fn grad(&self, s: &Settings) -> anyhow::Result<()> {
        let mut states: Vec<RmsState> = (0..s.seeds)
            .map(|k| RmsState {
                theta: theta_init(k),
                mean_square: [0.0; 5],
            })
            .collect();
        let mut norms: Vec<Vec<f64>> = vec![Vec::new(); s.seeds];
        for epoch in 1..=s.epochs {
            let recs: Vec<Record> = states
                .par_iter()
                .enumerate()
                .map(|(k, st)| self.rollout(Method::Grad, k, epoch - 1, st.theta, true))
                .collect::<anyhow::Result<_>>()?;
            for ((st, r), h) in states.iter_mut().zip(&recs).zip(&mut norms) {
                let g = r
                    .outcome
                    .grad
                    .context("a grad rollout without its gradient")?;
                let g = s.rmsprop.clip(g, epoch, h);
                s.rmsprop.step(st, g, epoch);
            }
        }
        Ok(())
    }

    fn sac(&self, s: &Settings) -> anyhow::Result<()> {
        let mut agents: Vec<Sac> = (0..s.seeds)
            .map(|k| Sac::new(s.sac, theta_init(k), method_seed(Method::Sac, k)))
            .collect::<candle_core::Result<_>>()?;
        // The temperature and the reward's standardisation, per seed and episode.
        let mut log = String::from("seed,episode,alpha,loss_mean,loss_std\n");
        for episode in 0..s.epochs {
            let actions: Vec<[f64; 5]> = agents
                .iter_mut()
                .map(|a| a.act())
                .collect::<candle_core::Result<_>>()?;
            let recs: Vec<Record> = actions
                .par_iter()
                .enumerate()
                .map(|(k, th)| self.rollout(Method::Sac, k, episode, *th, false))
                .collect::<anyhow::Result<_>>()?;
            agents
                .par_iter_mut()
                .zip(recs.par_iter())
                .try_for_each(|(a, r)| a.observe(r.theta, r.outcome.loss))?;
            for (k, a) in agents.iter().enumerate() {
                let (alpha, mean, std) = a.stats()?;
                let _ = writeln!(log, "{k},{},{alpha},{mean},{std}", episode + 1);
            }
            write_atomic(&self.board.out.join("sac.csv"), log.as_bytes())?;
        }
        Ok(())
    }

    fn random(&self, s: &Settings) -> anyhow::Result<()> {
        let jobs: Vec<(usize, usize, [f64; 5])> = (0..s.seeds)
            .flat_map(|k| {
                let mut rng = SplitMix64(method_seed(Method::Random, k));
                (0..s.epochs).map(move |i| {
                    let th = if i == 0 {
                        theta_init(k)
                    } else {
                        std::array::from_fn(|_| rng.uniform_in(-1.0, 1.0))
                    };
                    (k, i, th)
                })
            })
            .collect();
        jobs.par_iter()
            .map(|&(k, i, th)| self.rollout(Method::Random, k, i, th, false).map(|_| ()))
            .collect::<anyhow::Result<()>>()
    }

    fn cmaes(&self, s: &Settings) -> anyhow::Result<()> {
        let lambda = s.cmaes.population.max(2);
        let generations = s.epochs.div_ceil(lambda);
        let failure: Mutex<Option<anyhow::Error>> = Mutex::new(None);
        // Per seed: the generation being evaluated and how many rollouts it may still run.
        let gens: Vec<Mutex<(usize, usize)>> = (0..s.seeds).map(|_| Mutex::new((0, 0))).collect();
        let objectives: Vec<_> = (0..s.seeds)
            .map(|k| {
                let (gens, failure) = (&gens, &failure);
                move |x: &cmaes::DVector<f64>| -> f64 {
                    let th: [f64; 5] = std::array::from_fn(|i| reflect(x[i]));
                    let generation = {
                        let mut g = gens[k].lock().expect("lock");
                        if g.1 == 0 {
                            // Past the budget in a last, partial generation: not run.
                            return f64::MAX;
                        }
                        g.1 -= 1;
                        g.0
                    };
                    match self.rollout(Method::Cmaes, k, generation, th, false) {
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
                cmaes::CMAESOptions::new(theta_init(k).to_vec(), s.cmaes.sigma0)
                    .population_size(lambda)
                    .seed(method_seed(Method::Cmaes, k))
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
}

/// What `run` reports.
#[derive(Clone, Debug, Serialize)]
pub struct RunSummary {
    pub summary: serde_json::Value,
    pub replayed: usize,
    pub ran: usize,
}

/// Runs the optimisation described by `opts` on `problem`.
pub fn run(problem: &Problem, opts: &Options) -> anyhow::Result<RunSummary> {
    let s = &opts.settings;
    if s.epochs == 0 || s.seeds == 0 {
        bail!("--epochs and --seeds must be at least 1");
    }
    crate::util::create_output_dir(&opts.out, "--out")?;
    let settings_path = opts.out.join("settings.json");
    let journal_path = opts.out.join("journal.jsonl");
    if opts.resume {
        let text = std::fs::read_to_string(&settings_path).with_context(|| {
            format!(
                "--resume: {} is not a run directory (no settings.json)",
                opts.out.display()
            )
        })?;
        let old: Settings = serde_json::from_str(&text)
            .with_context(|| format!("reading {}", settings_path.display()))?;
        if &old != s {
            bail!(
                "--resume: the run in {} used other settings or another scene file ({}); rerun with the same scene and options, or choose another --out",
                opts.out.display(),
                settings_path.display()
            );
        }
    } else if journal_path.exists() {
        bail!(
            "{} already holds a run: pass --resume to continue it, or choose another --out",
            opts.out.display()
        );
    }
    write_atomic(&settings_path, serde_json::to_string_pretty(s)?.as_bytes())?;
    let journal = Journal::open(&journal_path, opts.resume)?;
    let unit = match problem.target {
        crate::scene::TargetValue::Particles(_) => "particles",
        crate::scene::TargetValue::Grams(_) => "g",
    };
    let bar = if opts.quiet {
        ProgressBar::hidden()
    } else {
        let pb = ProgressBar::new((s.methods.len() * s.epochs * s.seeds) as u64);
        pb.set_style(
            ProgressStyle::with_template(
                "{elapsed_precise} [{bar:30}] {pos}/{len} rollouts  {msg}",
            )
            .expect("static template")
            .progress_chars("=> "),
        );
        pb
    };
    let board = Board {
        records: Mutex::new(BTreeMap::new()),
        bar,
        out: opts.out.clone(),
        unit,
    };
    // Each method's time, over every process that ran it: what the journal carries plus this
    // process's time (a method replayed whole from the journal adds about nothing).
    let mut elapsed = BTreeMap::new();
    for &m in &s.methods {
        let runner = Runner {
            problem,
            journal: &journal,
            board: &board,
            start: Instant::now(),
            carried: journal.carried_elapsed(m),
        };
        match m {
            Method::Grad => runner.grad(s)?,
            Method::Cmaes => runner.cmaes(s)?,
            Method::Sac => runner.sac(s)?,
            Method::Random => runner.random(s)?,
        }
        elapsed.insert(m, runner.carried + runner.start.elapsed().as_secs_f64());
    }
    board.bar.finish_and_clear();
    let records = board.records.into_inner().expect("board lock");
    let (replayed, ran) = journal.counts();
    let summary = report::summary(problem, s, &records, &elapsed, replayed, ran);
    write_atomic(
        &opts.out.join("summary.json"),
        serde_json::to_string_pretty(&summary)?.as_bytes(),
    )?;
    plot::indicator_svg(
        &opts.out.join("indicator.svg"),
        &records,
        s.epochs,
        unit,
        problem_target_value(problem),
    )?;
    record_best(problem, &records, &opts.out.join("best.rrd"))?;
    Ok(RunSummary {
        summary,
        replayed,
        ran,
    })
}

fn problem_target_value(p: &Problem) -> f64 {
    match p.target {
        crate::scene::TargetValue::Particles(n) => n,
        crate::scene::TargetValue::Grams(g) => g,
    }
}

/// Records the rollout of lowest loss in Rerun, with each method's and seed's loss and
/// indicator per epoch as scalar series on the `epoch` timeline.
#[cfg(feature = "rerun")]
fn record_best(
    problem: &Problem,
    records: &BTreeMap<(Method, usize), Vec<Record>>,
    path: &Path,
) -> anyhow::Result<()> {
    let Some(best) = records
        .values()
        .flatten()
        .min_by(|a, b| a.outcome.loss.total_cmp(&b.outcome.loss))
    else {
        return Ok(());
    };
    let mut sim = problem.simulation(best.theta, false)?;
    let mut rec = crate::record::Recorder::for_scene(path, &mut sim.world, &problem.scene)?;
    for ((m, seed), list) in records {
        let base = format!("optimize/{}/seed{seed}", m.name());
        rec.series(
            &format!("{base}/loss"),
            "epoch",
            list.iter().map(|r| r.outcome.loss),
        )?;
        rec.series(
            &format!("{base}/indicator"),
            "epoch",
            list.iter().map(|r| r.outcome.indicator),
        )?;
    }
    rec.frame(&mut sim.world)?;
    for _ in 0..sim.horizon {
        sim.step()?;
        rec.frame(&mut sim.world)?;
    }
    rec.finish()
}

#[cfg(not(feature = "rerun"))]
fn record_best(
    _: &Problem,
    _: &BTreeMap<(Method, usize), Vec<Record>>,
    _: &Path,
) -> anyhow::Result<()> {
    Ok(())
}
