//! `powderlab study optimizers`: every optimisation method on paired seeds, at equal compute
//! and at equal rollouts, with a Wilcoxon signed-rank test of each method against each
//! forward-only baseline.
//!
//! Each task (a skill scene) is one `optimize` run ([`crate::lab::optim::run`]) with
//! `equal_compute` set: every method gets the compute of `budget` forward rollouts, the
//! gradient methods `budget/(1 + BACKWARD_COST)` gradient rollouts, the hybrid its budget in
//! forward rollouts. Seed `k` starts every method from the same Θ_init. The run directory keeps
//! the journal, so a killed study resumes where it stopped.
//!
//! **Equal compute.** Each seed's budget is the fewest simulated particle-substeps any method
//! spent on it (the horizon, and hence a rollout's cost, depends on Θ); each method is scored by
//! its best rollout so far (lowest loss) within that budget. **Equal rollouts** reads every
//! method after the fewest rollouts any method ran (the paper's framing, which favours the
//! gradient methods: their rollouts cost 3.4 times as much).

use crate::lab::optim::journal::Record;
use crate::lab::optim::report::{curve, point_within, Point};
use crate::lab::optim::Method;
use crate::lab::stats::median;
use crate::lab::stats::{mean_sd as mean_std, wilcoxon_less, ALPHA};
use serde::Serialize;
use std::collections::BTreeMap;

mod report;
pub use report::page;

/// The methods that use no gradient: the baselines a gradient-informed method must beat.
pub const BASELINES: [Method; 3] = [Method::Random, Method::Cmaes, Method::Sac];

/// One method's score on one task.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub method: Method,
    /// Per seed (in seed order): the dose error of the best rollout within the seed's
    /// equal-compute budget.
    pub dose_equal_compute: Vec<f64>,
    /// Per seed: the dose error after the equal-rollouts count.
    pub dose_equal_rollouts: Vec<f64>,
    /// Mean rollouts within the equal-compute budget.
    pub rollouts_in_budget: f64,
    /// Mean particle-substeps spent within the budget.
    pub particle_substeps: f64,
    /// Mean seconds of rollout time within the budget, per seed (rollouts run side by side,
    /// so this is the time of one core's share of the work).
    pub rollout_s: f64,
    /// One-sided Wilcoxon p-value of "this method's dose error at equal compute is smaller
    /// than the baseline's", per baseline.
    pub p_vs: BTreeMap<String, Option<f64>>,
}

/// A method and a one-sided Wilcoxon p-value about it (`None`: every pair tied).
pub type MethodP = (Method, Option<f64>);

/// A task's result.
#[derive(Clone, Debug, Serialize)]
pub struct TaskResult {
    pub scene: String,
    pub unit: String,
    pub target: f64,
    pub seeds: usize,
    /// The rollouts at which equal rollouts is read.
    pub equal_rollouts: usize,
    /// Mean equal-compute budget per seed, in particle-substeps.
    pub budget_particle_substeps: f64,
    /// The backward pass's multiple of a forward, measured in this task's own rollouts
    /// ([`crate::lab::optim::report::measured_backward_cost`]); compute is counted at it.
    pub backward_cost_measured: Option<f64>,
    pub rows: Vec<Row>,
    /// Each method's whole run time (all seeds, both cores), seconds.
    pub wall_s: BTreeMap<String, f64>,
}

impl TaskResult {
    /// The gradient-informed methods that beat every baseline at equal compute at [`ALPHA`].
    pub fn winners(&self) -> Vec<Method> {
        self.rows
            .iter()
            .filter(|r| r.method.uses_adjoint())
            .filter(|r| {
                self.rows
                    .iter()
                    .filter(|b| BASELINES.contains(&b.method))
                    .all(|b| r.p_vs.get(b.method.name()).copied().flatten() < Some(ALPHA))
            })
            .map(|r| r.method)
            .collect()
    }

    /// The baseline of lowest mean dose error at equal compute, and for each gradient-informed
    /// method the one-sided Wilcoxon p that this baseline's dose error is smaller than the
    /// method's: the test of "no worse than the best baseline" (p < [`ALPHA`]: shown worse).
    pub fn worse_than_best_baseline(&self) -> Option<(Method, Vec<MethodP>)> {
        let ranked = self.ranked();
        let base = ranked.iter().find(|r| BASELINES.contains(&r.method))?;
        let ps = ranked
            .iter()
            .filter(|r| r.method.uses_adjoint())
            .map(|r| {
                (
                    r.method,
                    wilcoxon_less(&base.dose_equal_compute, &r.dose_equal_compute),
                )
            })
            .collect();
        Some((base.method, ps))
    }

    /// The rows ranked by mean dose error at equal compute.
    pub fn ranked(&self) -> Vec<&Row> {
        let mut v: Vec<&Row> = self.rows.iter().collect();
        v.sort_by(|a, b| {
            mean_std(&a.dose_equal_compute)
                .0
                .total_cmp(&mean_std(&b.dose_equal_compute).0)
        });
        v
    }
}

/// Scores a finished run's records.
pub fn analyse(
    scene: &str,
    unit: &str,
    target: f64,
    methods: &[Method],
    records: &BTreeMap<(Method, usize), Vec<Record>>,
    wall_s: BTreeMap<String, f64>,
) -> TaskResult {
    let budgets = crate::lab::optim::report::equal_compute_budgets(methods, records);
    let bc = crate::lab::optim::report::backward_cost(records);
    let seeds: Vec<usize> = budgets.keys().copied().collect();
    let equal_rollouts = records
        .iter()
        .filter(|((m, _), _)| methods.contains(m))
        .map(|(_, l)| l.len())
        .min()
        .unwrap_or(0);
    let mut rows: Vec<Row> = methods
        .iter()
        .map(|&m| {
            let mut at_budget: Vec<Point> = Vec::new();
            let mut at_rollouts = Vec::new();
            for k in &seeds {
                let Some(l) = records.get(&(m, *k)) else {
                    continue;
                };
                let c = curve(l, bc);
                if let Some(p) = point_within(&c, budgets[k]) {
                    at_budget.push(p);
                }
                if let Some(p) = c.get(equal_rollouts.saturating_sub(1)) {
                    at_rollouts.push(p.best_indicator.abs());
                }
            }
            Row {
                method: m,
                dose_equal_compute: at_budget.iter().map(|p| p.best_indicator.abs()).collect(),
                dose_equal_rollouts: at_rollouts,
                rollouts_in_budget: mean_std(
                    &at_budget.iter().map(|p| p.epoch as f64).collect::<Vec<_>>(),
                )
                .0,
                particle_substeps: mean_std(
                    &at_budget
                        .iter()
                        .map(|p| p.particle_substeps)
                        .collect::<Vec<_>>(),
                )
                .0,
                rollout_s: mean_std(&at_budget.iter().map(|p| p.wall_s).collect::<Vec<_>>()).0,
                p_vs: BTreeMap::new(),
            }
        })
        .collect();
    let baseline_scores: Vec<(Method, Vec<f64>)> = rows
        .iter()
        .filter(|r| BASELINES.contains(&r.method))
        .map(|r| (r.method, r.dose_equal_compute.clone()))
        .collect();
    for r in &mut rows {
        for (b, scores) in &baseline_scores {
            if *b != r.method && scores.len() == r.dose_equal_compute.len() {
                r.p_vs.insert(
                    b.name().to_string(),
                    wilcoxon_less(&r.dose_equal_compute, scores),
                );
            }
        }
    }
    // line against its ablation: the same search along random axes.
    let ray = rows
        .iter()
        .find(|r| r.method == Method::Ray)
        .map(|r| r.dose_equal_compute.clone());
    if let (Some(ray), Some(line)) = (ray, rows.iter_mut().find(|r| r.method == Method::Line)) {
        if ray.len() == line.dose_equal_compute.len() {
            let p = wilcoxon_less(&line.dose_equal_compute, &ray);
            line.p_vs.insert(Method::Ray.name().to_string(), p);
        }
    }
    TaskResult {
        scene: scene.to_string(),
        unit: unit.to_string(),
        target,
        seeds: seeds.len(),
        equal_rollouts,
        budget_particle_substeps: mean_std(&budgets.values().copied().collect::<Vec<_>>()).0,
        backward_cost_measured: crate::lab::optim::report::measured_backward_cost(records),
        rows,
        wall_s,
    }
}

/// Per method: the median over seeds of the best-so-far dose error at each of `n` points of
/// the x-axis, by particle-substeps (`by_compute`) or by rollouts.
pub fn median_curves(
    records: &BTreeMap<(Method, usize), Vec<Record>>,
    by_compute: bool,
    n: usize,
) -> BTreeMap<Method, Vec<(f64, f64)>> {
    let mut per: BTreeMap<Method, Vec<Vec<Point>>> = BTreeMap::new();
    let bc = crate::lab::optim::report::backward_cost(records);
    for ((m, _), l) in records {
        per.entry(*m).or_default().push(curve(l, bc));
    }
    let x_max = |c: &Vec<Point>| {
        c.last().map_or(0.0, |p| {
            if by_compute {
                p.particle_substeps
            } else {
                p.epoch as f64
            }
        })
    };
    per.into_iter()
        .map(|(m, curves)| {
            // Up to where every seed has a point.
            let end = curves.iter().map(x_max).fold(f64::INFINITY, f64::min);
            let pts = (1..=n)
                .filter_map(|i| {
                    let x = end * i as f64 / n as f64;
                    let v: Vec<f64> = curves
                        .iter()
                        .filter_map(|c| {
                            if by_compute {
                                c.iter()
                                    .take_while(|p| p.particle_substeps <= x * (1.0 + 1e-12))
                                    .last()
                            } else {
                                c.iter().take_while(|p| p.epoch as f64 <= x + 1e-9).last()
                            }
                            .map(|p| p.best_indicator.abs())
                        })
                        .collect();
                    (v.len() == curves.len()).then(|| (x, median(&v)))
                })
                .collect();
            (m, pts)
        })
        .collect()
}

/// What the study runs.
#[derive(Clone, Debug)]
pub struct StudyOptions {
    /// The skill scenes, each a task.
    pub tasks: Vec<std::path::PathBuf>,
    pub seeds: usize,
    /// The stream's first seed (`optim::Settings::first_seed`).
    pub first_seed: usize,
    /// Compute per seed and method, in forward rollouts.
    pub budget: usize,
    pub methods: Vec<Method>,
    /// Run directories (journals), one per task.
    pub out: std::path::PathBuf,
    /// Where the page (`.md`), its figure (`.svg`) and its table (`.csv`) go.
    pub results: std::path::PathBuf,
    /// The page's file stem (`optimisation`).
    pub page: String,
    /// The command line that regenerates the page, written at its top.
    pub command: String,
    pub quiet: bool,
}

/// Runs every task (resuming each from its journal) and writes the page; returns its text.
pub fn run(o: &StudyOptions) -> anyhow::Result<String> {
    use crate::lab::optim::{self, problem::Problem};
    use anyhow::Context;
    use std::fmt::Write;
    if o.seeds == 0 || o.budget == 0 {
        anyhow::bail!("study optimizers: --seeds and --budget must be at least 1");
    }
    let mut results = Vec::new();
    let mut curves = Vec::new();
    let mut csv =
        String::from("task,method,seed,dose_error_equal_compute,dose_error_equal_rollouts\n");
    for scene_path in &o.tasks {
        let scene = crate::scene::Scene::load(scene_path)?;
        let problem = Problem::new(scene.clone(), TAPE_BUDGET)?;
        let stem = scene_path
            .file_stem()
            .map(|s| s.to_string_lossy().to_string())
            .unwrap_or_else(|| "task".into());
        let out = o.out.join(&stem);
        let settings = optim::Settings {
            scene_hash: scene.fingerprint(),
            methods: o.methods.clone(),
            epochs: o.budget,
            seeds: o.seeds,
            first_seed: o.first_seed,
            // The paper's curriculum frees θ_t and θ_p after half the budget (15 of 30).
            rmsprop: crate::lab::optim::rmsprop::RmsProp {
                switch_epoch: o.budget.div_ceil(2),
                ..Default::default()
            },
            cmaes: Default::default(),
            sac: Default::default(),
            smoothing: Default::default(),
            hybrid: Default::default(),
            equal_compute: true,
            tape_budget: TAPE_BUDGET,
            init: None,
        };
        let resume = out.join("settings.json").exists();
        if !o.quiet {
            eprintln!(
                "{}: {} seeds x {} forward rollouts of compute per method{}",
                scene_path.display(),
                o.seeds,
                o.budget,
                if resume { ", resuming" } else { "" }
            );
        }
        let r = optim::run(
            &problem,
            &optim::Options {
                settings,
                out: out.clone(),
                resume,
                quiet: o.quiet,
            },
        )
        .with_context(|| format!("task {}", scene_path.display()))?;
        let unit = r.summary["indicator_unit"]
            .as_str()
            .unwrap_or("")
            .to_string();
        let target = r.summary["target_value"].as_f64().unwrap_or(f64::NAN);
        let wall: BTreeMap<String, f64> = o
            .methods
            .iter()
            .map(|m| {
                let w = r.summary["methods"][m.name()]["wall_s"]
                    .as_f64()
                    .unwrap_or(f64::NAN);
                (m.name().to_string(), w)
            })
            .collect();
        let t = analyse(&stem, &unit, target, &o.methods, &r.records, wall);
        for row in &t.rows {
            for (k, (c, e)) in row
                .dose_equal_compute
                .iter()
                .zip(&row.dose_equal_rollouts)
                .enumerate()
            {
                let _ = writeln!(csv, "{stem},{},{k},{c},{e}", row.method.name());
            }
        }
        curves.push(crate::lab::optim::plot::Curves {
            title: format!("{stem} ({target} {unit})"),
            unit: unit.clone(),
            by_compute: median_curves(&r.records, true, 60),
            by_rollouts: median_curves(&r.records, false, 60),
        });
        results.push(t);
    }
    crate::util::create_output_dir(&o.results, "--results")?;
    let file = |ext: &str| o.results.join(format!("{}.{ext}", o.page));
    crate::lab::optim::plot::optimisation_figure(&file("svg"), &curves)?;
    crate::util::write_atomic(&file("csv"), csv.as_bytes())?;
    let md = page(o, &results);
    crate::util::write_atomic(&file("md"), md.as_bytes())?;
    Ok(md)
}

/// Tape memory of one backward pass (1 GiB, the `optimize` default).
pub const TAPE_BUDGET: usize = 1 << 30;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_worse_is_tested_against_the_best_baseline() {
        let row = |method, errors: &[f64]| Row {
            method,
            dose_equal_compute: errors.to_vec(),
            dose_equal_rollouts: errors.to_vec(),
            rollouts_in_budget: 20.0,
            particle_substeps: 1.0,
            rollout_s: 1.0,
            p_vs: BTreeMap::new(),
        };
        let seeds: Vec<f64> = (0..10).map(|i| 0.5 + 0.01 * i as f64).collect();
        let shifted = |d: f64| seeds.iter().map(|x| x + d).collect::<Vec<_>>();
        let t = TaskResult {
            scene: "t".into(),
            unit: "g".into(),
            target: 5.0,
            seeds: 10,
            equal_rollouts: 20,
            budget_particle_substeps: 1.0,
            backward_cost_measured: Some(3.0),
            rows: vec![
                row(Method::Random, &shifted(0.3)),
                row(Method::Sac, &seeds),
                row(Method::Line, &shifted(1.0)),
                row(Method::Ray, &shifted(2.0)),
                row(Method::Hybrid, &seeds),
            ],
            wall_s: BTreeMap::new(),
        };
        let (base, ps) = t.worse_than_best_baseline().unwrap();
        // SAC is the best baseline (random is worse); ray uses no adjoint and is not tested.
        assert_eq!(base, Method::Sac);
        assert_eq!(ps.len(), 2, "{ps:?}");
        let p = |m| ps.iter().find(|(x, _)| *x == m).unwrap().1;
        assert!((p(Method::Line).unwrap() - 1.0 / 1024.0).abs() < 1e-15);
        // Equal on every seed: no test, so not shown worse.
        assert_eq!(p(Method::Hybrid), None);
    }
}
