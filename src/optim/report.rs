//! `metrics.csv` and `summary.json` of an optimisation run.

use super::journal::Record;
use super::problem::Problem;
use super::{Method, Settings};
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
}

/// The running best of a list in canonical order.
pub fn curve(list: &[Record]) -> Vec<Point> {
    let mut best: Option<&Record> = None;
    let mut wall = 0.0;
    list.iter()
        .enumerate()
        .map(|(i, r)| {
            wall += r.outcome.wall_s;
            if best.is_none_or(|b| r.outcome.loss < b.outcome.loss) {
                best = Some(r);
            }
            let b = best.expect("set above");
            Point {
                epoch: i + 1,
                best_loss: b.outcome.loss,
                best_indicator: b.outcome.indicator,
                wall_s: wall,
            }
        })
        .collect()
}

/// `metrics.csv`: one row per method, seed and epoch.
pub fn metrics_csv(all: &BTreeMap<(Method, usize), Vec<Record>>) -> String {
    let mut s = String::from(
        "method,seed,epoch,rollouts,loss,indicator,transported,theta_d,theta_s,theta_l,theta_t,theta_p,grad_norm,best_loss,best_indicator,wall_s\n",
    );
    for ((m, seed), list) in all {
        for (r, p) in list.iter().zip(curve(list)) {
            let g = r
                .outcome
                .grad
                .map(|g| g.iter().map(|x| x * x).sum::<f64>().sqrt().to_string())
                .unwrap_or_default();
            let _ = writeln!(
                s,
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{:.3}",
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
                p.wall_s
            );
        }
    }
    s
}

/// Mean and (population) standard deviation.
pub fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len().max(1) as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / n;
    (m, var.sqrt())
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
    let unit = match problem.target {
        crate::scene::TargetValue::Particles(_) => "particles",
        crate::scene::TargetValue::Grams(_) => "g",
    };
    let mut methods = serde_json::Map::new();
    for &m in &s.methods {
        let per_seed: Vec<(usize, &Vec<Record>)> = all
            .iter()
            .filter(|((mm, _), _)| *mm == m)
            .map(|((_, k), l)| (*k, l))
            .collect();
        let finals: Vec<f64> = per_seed
            .iter()
            .filter_map(|(_, l)| curve(l).last().map(|p| p.best_indicator))
            .collect();
        let initials: Vec<f64> = per_seed
            .iter()
            .filter_map(|(_, l)| l.first().map(|r| r.outcome.indicator))
            .collect();
        let best_losses: Vec<f64> = per_seed
            .iter()
            .filter_map(|(_, l)| curve(l).last().map(|p| p.best_loss))
            .collect();
        let (fm, fs) = mean_std(&finals);
        let (im, is) = mean_std(&initials);
        let (lm, ls) = mean_std(&best_losses);
        let seeds: Vec<serde_json::Value> = per_seed
            .iter()
            .map(|(k, l)| {
                let c = curve(l);
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
    json!({
        "scene": problem.scene.path.display().to_string(),
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
