//! `powderlab study landscape`: how hard a skill task is for search, and where its good region
//! lies, from forward rollouts at quasi-random Θ (an Owen-scrambled Sobol sequence over
//! [−1, 1]⁵, `sobol_burley`).
//!
//! From the rollouts:
//! - **random search's expected best-of-k**, by bootstrap: `k` rollouts drawn with replacement,
//!   the one of lowest loss kept (what a search sees), scored by its dose error |indicator|;
//! - **each parameter's main effect**: the mean dose error in each quarter of its range;
//! - **the fraction of Θ that pour nothing** into the target.
//!
//! Each finished rollout is appended to `rollouts.jsonl` at once, so a killed study resumes
//! where it stopped.

use crate::lab::optim::problem::{Outcome, Problem};
pub use crate::lab::optim::sobol_thetas;
use crate::skills::Theta;
use crate::util::{write_atomic, SplitMix64};
use serde::{Deserialize, Serialize};
use std::fmt::Write;
use std::path::Path;

/// Bootstrap draws per `k`.
pub const BOOTSTRAP_DRAWS: usize = 2000;

/// One rollout of the map.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Point {
    pub index: usize,
    pub theta: Theta,
    pub loss: f64,
    pub indicator: f64,
    pub transported: f64,
}

/// Random search's best-of-`k` by bootstrap: the mean, 10th and 90th percentile of the dose
/// error of the lowest-loss rollout among `k` drawn with replacement.
pub fn best_of_k(points: &[Point], k: usize, seed: u64) -> (f64, f64, f64) {
    let mut rng = SplitMix64(seed);
    let mut best: Vec<f64> = (0..BOOTSTRAP_DRAWS)
        .map(|_| {
            let p = (0..k)
                .map(|_| &points[rng.index(points.len())])
                .min_by(|a, b| a.loss.total_cmp(&b.loss))
                .expect("k ≥ 1");
            p.indicator.abs()
        })
        .collect();
    best.sort_by(f64::total_cmp);
    let mean = best.iter().sum::<f64>() / best.len() as f64;
    let q = |f: f64| best[((best.len() - 1) as f64 * f).round() as usize];
    (mean, q(0.1), q(0.9))
}

/// Each parameter's main effect: the mean dose error of the points in each quarter of its range.
pub fn main_effects(points: &[Point]) -> [[f64; 4]; 5] {
    std::array::from_fn(|d| {
        std::array::from_fn(|q| {
            let lo = -1.0 + 0.5 * q as f64;
            let sel: Vec<f64> = points
                .iter()
                .filter(|p| p.theta[d] >= lo && (p.theta[d] < lo + 0.5 || q == 3))
                .map(|p| p.indicator.abs())
                .collect();
            sel.iter().sum::<f64>() / sel.len().max(1) as f64
        })
    })
}

/// The rollouts of `rollouts.jsonl` in `dir`, if any.
pub fn load(dir: &Path) -> anyhow::Result<Vec<Point>> {
    // A line cut off by a kill is left out; the rollout runs again.
    crate::lab::journal::read(&dir.join("rollouts.jsonl"))
}

/// Runs the rollouts of `thetas` not yet in `dir` (in parallel), appending each as it finishes.
pub fn run(
    problem: &Problem,
    thetas: &[Theta],
    dir: &Path,
    progress: &(dyn Fn() + Sync),
) -> anyhow::Result<Vec<Point>> {
    use rayon::prelude::*;
    crate::util::create_output_dir(dir, "--out")?;
    // The rollouts kept in `dir` are reused only for the same parsed scene.
    let hash = problem.scene().fingerprint();
    let stamp = dir.join("scene.fnv1a");
    match std::fs::read_to_string(&stamp) {
        Ok(old) if old.trim() != hash => anyhow::bail!(
            "{} holds a landscape of another scene (or another version of it); choose another --out",
            dir.display()
        ),
        Ok(_) => {}
        Err(_) => write_atomic(&stamp, hash.as_bytes())?,
    }
    // A torn last line (killed mid-write) is cut off.
    let (file, mut done) =
        crate::lab::journal::Journal::<Point>::open(&dir.join("rollouts.jsonl"))?;
    let todo: Vec<usize> = (0..thetas.len())
        .filter(|i| !done.iter().any(|p| p.index == *i))
        .collect();
    let new: Vec<Point> = todo
        .par_iter()
        .map(|&i| {
            let o: Outcome = problem.evaluate(thetas[i], false, true)?;
            let p = Point {
                index: i,
                theta: thetas[i],
                loss: o.loss,
                indicator: o.indicator,
                transported: o.transported,
            };
            file.append(&p)?;
            progress();
            Ok(p)
        })
        .collect::<anyhow::Result<_>>()?;
    done.extend(new);
    done.sort_by_key(|p| p.index);
    Ok(done)
}

/// The map's summary as Markdown (and the CSV of its points), written to `dir`.
pub fn write_report(points: &[Point], unit: &str, dir: &Path) -> anyhow::Result<String> {
    let mut md = String::new();
    let n = points.len();
    let none = points.iter().filter(|p| p.transported <= 0.0).count();
    let _ = writeln!(
        md,
        "{n} rollouts; {none} of them ({:.1} %) pour nothing into the target.\n",
        100.0 * none as f64 / n.max(1) as f64
    );
    let _ = writeln!(
        md,
        "Random search's best-of-k (the lowest-loss rollout among k, its dose error in {unit}; bootstrap, {BOOTSTRAP_DRAWS} draws):\n"
    );
    let _ = writeln!(
        md,
        "| k | mean | 10th percentile | 90th percentile |\n|---|---|---|---|"
    );
    for k in [1, 2, 5, 10, 20, 30, 50, 100] {
        let (m, lo, hi) = best_of_k(points, k, 0xB0 + k as u64);
        let _ = writeln!(md, "| {k} | {m:.3} | {lo:.3} | {hi:.3} |");
    }
    let _ = writeln!(
        md,
        "\nMain effects: the mean dose error ({unit}) of the rollouts in each quarter of a parameter's range:\n"
    );
    let _ = writeln!(
        md,
        "| parameter | [−1, −0.5) | [−0.5, 0) | [0, 0.5) | [0.5, 1] |\n|---|---|---|---|---|"
    );
    for (d, e) in main_effects(points).iter().enumerate() {
        let _ = writeln!(
            md,
            "| {} | {:.3} | {:.3} | {:.3} | {:.3} |",
            crate::skills::PARAM_NAMES[d],
            e[0],
            e[1],
            e[2],
            e[3]
        );
    }
    let mut csv =
        String::from("index,theta_d,theta_s,theta_l,theta_t,theta_p,loss,indicator,transported\n");
    for p in points {
        let t = p.theta;
        let _ = writeln!(
            csv,
            "{},{},{},{},{},{},{},{},{}",
            p.index, t[0], t[1], t[2], t[3], t[4], p.loss, p.indicator, p.transported
        );
    }
    write_atomic(&dir.join("landscape.csv"), csv.as_bytes())?;
    write_atomic(&dir.join("landscape.md"), md.as_bytes())?;
    Ok(md)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(index: usize, theta0: f64, loss: f64, indicator: f64) -> Point {
        Point {
            index,
            theta: Theta([theta0, 0.0, 0.0, 0.0, 0.0]),
            loss,
            indicator,
            transported: 5.0 - indicator,
        }
    }

    #[test]
    fn sobol_points_cover_the_box_evenly() {
        let t = sobol_thetas(64, 1);
        for d in 0..5 {
            // Each quarter of each axis holds exactly a quarter of 64 stratified points.
            for q in 0..4 {
                let lo = -1.0 + 0.5 * q as f64;
                let n = t.iter().filter(|x| x[d] >= lo && x[d] < lo + 0.5).count();
                assert_eq!(n, 16, "axis {d} quarter {q}");
            }
        }
    }

    #[test]
    fn best_of_k_improves_with_k_and_follows_the_loss() {
        // The loss ranks the points; the lowest loss has dose error 0.1.
        let pts: Vec<Point> = (0..20)
            .map(|i| point(i, 0.0, i as f64, 0.1 + 0.2 * i as f64))
            .collect();
        let (m1, _, _) = best_of_k(&pts, 1, 1);
        let (m10, _, _) = best_of_k(&pts, 10, 1);
        let (m100, lo, _) = best_of_k(&pts, 100, 1);
        assert!(
            m1 > m10 && m10 > m100 && lo >= 0.1 - 1e-12,
            "{m1} {m10} {m100}"
        );
        assert!((m1 - 2.0).abs() < 0.2, "{m1}");
    }

    #[test]
    fn main_effects_bin_by_quarter() {
        let pts = vec![
            point(0, -0.9, 1.0, 4.0),
            point(1, 0.9, 1.0, -1.0),
            point(2, 0.7, 1.0, 3.0),
        ];
        let e = main_effects(&pts);
        assert_eq!(e[0], [4.0, 0.0, 0.0, 2.0]);
    }
}
