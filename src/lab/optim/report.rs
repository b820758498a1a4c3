//! `metrics.csv` and `summary.json` of an optimisation run.

use super::journal::Record;
use super::problem::{Outcome, Problem};
use super::{Method, Settings};
use crate::lab::stats::{mean_sd as mean_std, median};
use serde_json::json;
use std::collections::BTreeMap;
use std::fmt::Write;

/// Puts one method's and seed's rollouts in their canonical order: by batch, and within a batch
/// (a CMA-ES generation, evaluated in parallel) by Θ, so the order does not depend on which
/// rollout finished first.
pub fn sort_rollouts(list: &mut [Record]) {
    list.sort_by(|a, b| {
        a.batch.cmp(&b.batch).then_with(|| {
            a.theta
                .iter()
                .zip(&b.theta)
                .map(|(x, y)| x.total_cmp(y))
                .find(|o| o.is_ne())
                .unwrap_or(std::cmp::Ordering::Equal)
        })
    });
}

/// The multiple of a forward pass that budgets are planned with: a gradient rollout counts as
/// `1 + BACKWARD_COST` forward rollouts when a method's rollouts are counted out
/// (`powderlab bench scenes/powder_transport.ron --backward` measured 2.41–2.46 on 2 cores,
/// `docs/results/performance.md`). The reports do not assume it: they count compute at the
/// multiple measured in the run itself ([`backward_cost`]).
pub const BACKWARD_COST: f64 = 2.4;

/// The gradient rollouts (rounded up) that cost the compute of `budget` forward rollouts.
pub fn gradient_rollouts(budget: usize) -> usize {
    (budget as f64 / (1.0 + BACKWARD_COST)).ceil() as usize
}

/// The backward pass's multiple of a forward, measured in one run's rollouts, each given as
/// `(has a backward pass, seconds)`: the mean seconds of the gradient rollouts over those of the
/// forward ones, minus the forward that a gradient rollout also runs. `None` when the run has
/// not both kinds (or no time was recorded). Every study that scores at equal compute counts
/// its gradient rollouts at this multiple.
pub fn backward_multiple(rollouts: impl IntoIterator<Item = (bool, f64)>) -> Option<f64> {
    let (mut g, mut f) = ((0.0, 0usize), (0.0, 0usize));
    for (gradient, wall_s) in rollouts {
        let slot = if gradient { &mut g } else { &mut f };
        slot.0 += wall_s;
        slot.1 += 1;
    }
    (g.1 > 0 && f.1 > 0 && f.0 > 0.0).then(|| (g.0 / g.1 as f64) / (f.0 / f.1 as f64) - 1.0)
}

/// [`backward_multiple`] of an optimisation run's records.
pub fn measured_backward_cost(all: &BTreeMap<(Method, usize), Vec<Record>>) -> Option<f64> {
    backward_multiple(
        all.values()
            .flatten()
            .map(|r| (r.outcome.grad.is_some(), r.outcome.wall_s)),
    )
}

/// The multiple a run's compute is counted at: the measured one, or [`BACKWARD_COST`] for a
/// run without both kinds of rollout (where it does not matter, or cannot be measured).
pub fn backward_cost(all: &BTreeMap<(Method, usize), Vec<Record>>) -> f64 {
    measured_backward_cost(all).unwrap_or(BACKWARD_COST)
}

/// What a rollout costs in simulated particle-substeps, its backward pass (if it has one) at
/// `backward_cost` times the forward's.
pub fn rollout_cost(o: &Outcome, backward_cost: f64) -> f64 {
    let forward = o.particles as f64 * o.steps as f64 * o.substeps as f64;
    with_backward(forward, o.grad.is_some(), backward_cost)
}

/// A rollout's compute from its forward particle-substeps: `forward`, or `forward·(1 + m)`
/// when it ran a backward pass at `m` forward passes.
pub fn with_backward(forward: f64, gradient: bool, m: f64) -> f64 {
    if gradient {
        forward * (1.0 + m)
    } else {
        forward
    }
}

/// How the best rollout so far is chosen, said in the summary beside the scores.
pub const SELECTION: &str = "the rollout of lowest loss among those run so far (the loss is what every method sees), scored by its indicator; the dose error is |indicator|";

/// One point of a method's curve for one seed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Point {
    /// Rollouts so far (1-based).
    pub epoch: usize,
    /// The lowest loss among the first `epoch` rollouts.
    pub best_loss: f64,
    /// The indicator of that rollout.
    pub best_indicator: f64,
    /// Seconds of rollout time spent so far.
    pub wall_s: f64,
    /// Simulated particle-substeps spent so far ([`rollout_cost`]).
    pub particle_substeps: f64,
}

/// The running best of a list in canonical order, a backward pass counted at `backward_cost`.
pub fn curve(list: &[Record], backward_cost: f64) -> Vec<Point> {
    let mut best: Option<&Record> = None;
    let mut wall = 0.0;
    let mut cost = 0.0;
    list.iter()
        .enumerate()
        .map(|(i, r)| {
            wall += r.outcome.wall_s;
            cost += rollout_cost(&r.outcome, backward_cost);
            if best.is_none_or(|b| r.outcome.loss < b.outcome.loss) {
                best = Some(r);
            }
            let b = best.expect("set above");
            Point {
                epoch: i + 1,
                best_loss: b.outcome.loss,
                best_indicator: b.outcome.indicator,
                wall_s: wall,
                particle_substeps: cost,
            }
        })
        .collect()
}

/// `metrics.csv`: one row per method, seed and epoch.
pub fn metrics_csv(all: &BTreeMap<(Method, usize), Vec<Record>>) -> String {
    let mut s = String::from(
        "method,seed,epoch,rollouts,loss,indicator,transported,theta_d,theta_s,theta_l,theta_t,theta_p,grad_norm,best_loss,best_indicator,best_dose_error,particle_substeps,wall_s\n",
    );
    let bc = backward_cost(all);
    for ((m, seed), list) in all {
        for (r, p) in list.iter().zip(curve(list, bc)) {
            let g = r
                .outcome
                .grad
                .map(|g| g.iter().map(|x| x * x).sum::<f64>().sqrt().to_string())
                .unwrap_or_default();
            let _ = writeln!(
                s,
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{:.6e},{:.3}",
                m.name(),
                seed,
                p.epoch,
                p.epoch,
                r.outcome.loss,
                r.outcome.indicator,
                r.outcome.transported,
                r.theta[0],
                r.theta[1],
                r.theta[2],
                r.theta[3],
                r.theta[4],
                g,
                p.best_loss,
                p.best_indicator,
                p.best_indicator.abs(),
                p.particle_substeps,
                p.wall_s
            );
        }
    }
    s
}

/// Each seed's budget at equal compute: the fewest particle-substeps any method spent on it.
pub fn equal_compute_budgets(
    methods: &[Method],
    all: &BTreeMap<(Method, usize), Vec<Record>>,
) -> BTreeMap<usize, f64> {
    let mut out: BTreeMap<usize, f64> = BTreeMap::new();
    let bc = backward_cost(all);
    for ((m, k), l) in all {
        if !methods.contains(m) {
            continue;
        }
        if let Some(p) = curve(l, bc).last() {
            let b = out.entry(*k).or_insert(f64::INFINITY);
            *b = b.min(p.particle_substeps);
        }
    }
    out
}

/// Where a curve stood when it had spent `budget` particle-substeps: its last point within the
/// budget, or its first point if even the first rollout cost more (every method's first
/// rollout is Θ_init).
pub fn point_within(c: &[Point], budget: f64) -> Option<Point> {
    c.iter()
        .take_while(|p| p.particle_substeps <= budget * (1.0 + 1e-12))
        .last()
        .or(c.first())
        .copied()
}

/// Mean, standard deviation and median of dose errors, as JSON.
fn dose_stats(errors: &[f64]) -> (f64, f64, f64) {
    let (m, s) = mean_std(errors);
    let med = if errors.is_empty() {
        f64::NAN
    } else {
        median(errors)
    };
    (m, s, med)
}

/// `summary.json`.
pub fn summary(
    problem: &Problem,
    s: &Settings,
    all: &BTreeMap<(Method, usize), Vec<Record>>,
    elapsed: &BTreeMap<Method, f64>,
    replayed: usize,
    ran: usize,
) -> serde_json::Value {
    let bc = backward_cost(all);
    let unit = match problem.target {
        crate::scene::TargetValue::Particles(_) => "particles",
        crate::scene::TargetValue::Grams(_) => "g",
    };
    let mut methods = serde_json::Map::new();
    let budgets = equal_compute_budgets(&s.methods, all);
    let mut rank_rollouts: Vec<(f64, &str)> = Vec::new();
    let mut rank_compute: Vec<(f64, &str)> = Vec::new();
    for &m in &s.methods {
        let per_seed: Vec<(usize, &Vec<Record>)> = all
            .iter()
            .filter(|((mm, _), _)| *mm == m)
            .map(|((_, k), l)| (*k, l))
            .collect();
        let finals: Vec<f64> = per_seed
            .iter()
            .filter_map(|(_, l)| curve(l, bc).last().map(|p| p.best_indicator))
            .collect();
        let initials: Vec<f64> = per_seed
            .iter()
            .filter_map(|(_, l)| l.first().map(|r| r.outcome.indicator))
            .collect();
        let best_losses: Vec<f64> = per_seed
            .iter()
            .filter_map(|(_, l)| curve(l, bc).last().map(|p| p.best_loss))
            .collect();
        let dose: Vec<f64> = finals.iter().map(|x| x.abs()).collect();
        let (dm, ds, dmed) = dose_stats(&dose);
        let spent: Vec<f64> = per_seed
            .iter()
            .filter_map(|(_, l)| curve(l, bc).last().map(|p| p.particle_substeps))
            .collect();
        let at_budget: Vec<Point> = per_seed
            .iter()
            .filter_map(|(k, l)| point_within(&curve(l, bc), budgets[k]))
            .collect();
        let eq_dose: Vec<f64> = at_budget.iter().map(|p| p.best_indicator.abs()).collect();
        let (em, es, emed) = dose_stats(&eq_dose);
        rank_rollouts.push((dm, m.name()));
        rank_compute.push((em, m.name()));
        let (fm, fs) = mean_std(&finals);
        let (im, is) = mean_std(&initials);
        let (lm, ls) = mean_std(&best_losses);
        let seeds: Vec<serde_json::Value> = per_seed
            .iter()
            .map(|(k, l)| {
                let c = curve(l, bc);
                let best = l
                    .iter()
                    .min_by(|a, b| a.outcome.loss.total_cmp(&b.outcome.loss))
                    .expect("non-empty");
                json!({
                    "seed": k,
                    "theta_init": l.first().map(|r| r.theta),
                    "initial_indicator": l.first().map(|r| r.outcome.indicator),
                    "final_indicator": c.last().map(|p| p.best_indicator),
                    "final_loss": c.last().map(|p| p.best_loss),
                    "best_theta": best.theta,
                    "rollouts": l.len(),
                    "rollout_wall_s": c.last().map(|p| p.wall_s),
                    "lowered_indicator": c.last().map(|p| p.best_indicator) < l.first().map(|r| r.outcome.indicator),
                })
            })
            .collect();
        methods.insert(
            m.name().to_string(),
            json!({
                "final_dose_error_mean": dm,
                "final_dose_error_std": ds,
                "final_dose_error_median": dmed,
                "particle_substeps_per_seed_mean": mean_std(&spent).0,
                "equal_compute": {
                    "dose_error_mean": em,
                    "dose_error_std": es,
                    "dose_error_median": emed,
                    "indicator_mean": mean_std(&at_budget.iter().map(|p| p.best_indicator).collect::<Vec<_>>()).0,
                    "rollouts_mean": mean_std(&at_budget.iter().map(|p| p.epoch as f64).collect::<Vec<_>>()).0,
                    "particle_substeps_mean": mean_std(&at_budget.iter().map(|p| p.particle_substeps).collect::<Vec<_>>()).0,
                },
                "final_indicator_mean": fm,
                "final_indicator_std": fs,
                "initial_indicator_mean": im,
                "initial_indicator_std": is,
                "final_loss_mean": lm,
                "final_loss_std": ls,
                "rollouts_per_seed": per_seed.iter().map(|(_, l)| l.len()).max().unwrap_or(0),
                "wall_s": elapsed.get(&m),
                "seeds": seeds,
            }),
        );
    }
    let ranking = |mut v: Vec<(f64, &str)>| {
        v.sort_by(|a, b| a.0.total_cmp(&b.0));
        v.into_iter().map(|e| e.1.to_string()).collect::<Vec<_>>()
    };
    json!({
        "scene": problem.scene().path.display().to_string(),
        "selection": SELECTION,
        "backward_cost_planned": BACKWARD_COST,
        "backward_cost_measured": measured_backward_cost(all),
        "backward_cost": bc,
        "ranking_equal_rollouts": ranking(rank_rollouts),
        "ranking_equal_compute": ranking(rank_compute),
        "equal_compute_budget_per_seed": budgets.values().collect::<Vec<_>>(),
        "indicator_unit": unit,
        "target_value": match problem.target {
            crate::scene::TargetValue::Particles(n) | crate::scene::TargetValue::Grams(n) => n,
        },
        "epochs": s.epochs,
        "seeds": s.seeds,
        "settings": s,
        "methods": methods,
        "wall_s_total": elapsed.values().sum::<f64>(),
        "rollouts_replayed": replayed,
        "rollouts_run": ran,
        "threads": rayon::current_num_threads(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(method: Method, batch: usize, loss: f64, indicator: f64, grad: bool) -> Record {
        Record {
            method,
            seed: 0,
            batch,
            theta: crate::skills::Theta([0.0; 5]),
            outcome: Outcome {
                loss,
                indicator,
                transported: 0.0,
                grad: grad.then_some([0.0; 5]),
                steps: 10,
                substeps: 2,
                particles: 100,
                wall_s: 1.0,
            },
            method_elapsed_s: None,
        }
    }

    #[test]
    fn a_backward_pass_counts_at_its_cost() {
        let forward = record(Method::Random, 0, 1.0, 0.0, false);
        let gradient = record(Method::Grad, 0, 1.0, 0.0, true);
        assert_eq!(rollout_cost(&forward.outcome, 3.0), 2000.0);
        assert_eq!(rollout_cost(&gradient.outcome, 3.0), 2000.0 * 4.0);
    }

    /// The multiple is the run's own: gradient rollouts that took 4.5 s against forward ones
    /// of 1.5 s cost 2 forward passes more each; a run of one kind has no measurement.
    #[test]
    fn the_backward_multiple_is_measured_in_the_run() {
        let timed = |m, e, g, wall_s| {
            let mut r = record(m, e, 1.0, 0.0, g);
            r.outcome.wall_s = wall_s;
            r
        };
        let mut all = BTreeMap::new();
        all.insert(
            (Method::Grad, 0),
            vec![
                timed(Method::Grad, 0, true, 4.0),
                timed(Method::Grad, 1, true, 5.0),
            ],
        );
        assert_eq!(measured_backward_cost(&all), None);
        assert_eq!(backward_cost(&all), BACKWARD_COST);
        all.insert(
            (Method::Random, 0),
            vec![timed(Method::Random, 0, false, 1.5)],
        );
        assert_eq!(measured_backward_cost(&all), Some(2.0));
    }

    #[test]
    fn equal_compute_stops_each_method_at_the_cheapest_methods_spend() {
        let mut all = BTreeMap::new();
        // Three gradient rollouts (6,800 each at a backward multiple of 2.4) against three
        // forward ones (2,000 each): the budget is 6,000, within which grad has only its first
        // rollout and random all three.
        let bc = 2.4;
        all.insert(
            (Method::Grad, 0),
            vec![
                record(Method::Grad, 0, 5.0, 3.0, true),
                record(Method::Grad, 1, 4.0, -0.5, true),
                record(Method::Grad, 2, 3.0, 0.1, true),
            ],
        );
        all.insert(
            (Method::Random, 0),
            vec![
                record(Method::Random, 0, 5.0, 3.0, false),
                record(Method::Random, 1, 6.0, 4.0, false),
                record(Method::Random, 2, 4.5, 1.0, false),
            ],
        );
        // The run measured its gradient rollouts at 3.4 s against 1 s forward: a multiple of 2.4.
        for r in all.get_mut(&(Method::Grad, 0)).unwrap() {
            r.outcome.wall_s = 3.4;
        }
        assert!((backward_cost(&all) - bc).abs() < 1e-12);
        let budgets = equal_compute_budgets(&[Method::Grad, Method::Random], &all);
        assert_eq!(budgets[&0], 6000.0);
        let grad = point_within(&curve(&all[&(Method::Grad, 0)], bc), budgets[&0]).unwrap();
        let random = point_within(&curve(&all[&(Method::Random, 0)], bc), budgets[&0]).unwrap();
        assert_eq!((grad.epoch, grad.best_indicator), (1, 3.0));
        assert_eq!((random.epoch, random.best_indicator), (3, 1.0));
        // At equal rollouts grad's best by loss is its third, whose dose error 0.1 beats an
        // over-delivery of 0.5 that a signed average would have ranked first.
        let last = curve(&all[&(Method::Grad, 0)], bc).last().copied().unwrap();
        assert_eq!(last.best_indicator.abs(), 0.1);
    }
}
