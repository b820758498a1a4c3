//! `powderlab study directions`: does a loss's derivative point where the dose error falls?
//!
//! At each Θ of a list, the adjoint gradient of each loss (eq. 5, the dosing loss, the carry
//! loss) is compared with the secant gradient of the dose error `d = |indicator|`:
//! `ĝ_k = (d(Θ + h·e_k) − d(Θ − h·e_k))/(Θ⁺_k − Θ⁻_k)`, the steps clamped to [−1, 1]. The
//! cosine between `∇L` and `ĝ` is 1 where descending the loss descends the dose error at the
//! scale h, −1 where it climbs it; on a loss whose derivative sees only where grains go it
//! hovers about 0.
//!
//! Every rollout is appended to `rollouts.jsonl` in the output folder as it finishes, so a
//! killed study resumes where it stopped.

use crate::adjoint::loss::scene_loss;
use crate::lab::optim::problem::Problem;
use crate::lab::stats::cosine;
use crate::scene::{LossSpec, TargetValue};
use crate::skills::Theta;
use crate::util::write_atomic;
use crate::util::SplitMix64;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::Path;

/// The losses compared.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    /// A forward rollout: its value is the dose error.
    Forward,
    /// Seed A's eq. 5.
    Eq5,
    /// The dosing loss on the soft mass in the target cup.
    Dosing,
    /// The carry loss at the end of the lift and of the transport.
    Carry,
}

/// The gradient losses, in the page's order.
pub const LOSSES: [Kind; 3] = [Kind::Eq5, Kind::Dosing, Kind::Carry];

impl Kind {
    pub fn name(self) -> &'static str {
        match self {
            Kind::Forward => "forward",
            Kind::Eq5 => "eq. 5",
            Kind::Dosing => "dosing",
            Kind::Carry => "carry",
        }
    }
}

/// One finished rollout.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Rollout {
    pub kind: Kind,
    pub theta: Theta,
    /// The dose error (forward) or the loss (gradient kinds).
    pub value: f64,
    #[serde(default)]
    pub grad: Option<[f64; 5]>,
}

type Key = (Kind, [u64; 5]);

fn key(kind: Kind, theta: &Theta) -> Key {
    (kind, theta.map(f64::to_bits))
}

/// The Θ at which the secant of parameter `k` at step `h` is taken: `(Θ⁻, Θ⁺)`, clamped.
pub fn secant_pair(theta: Theta, k: usize, h: f64) -> (Theta, Theta) {
    let (mut lo, mut hi) = (theta, theta);
    lo[k] = (theta[k] - h).max(-1.0);
    hi[k] = (theta[k] + h).min(1.0);
    (lo, hi)
}

/// The points of the test: Θ_init of seeds 0–2 and the first six secant points of the
/// diagnostics (`gradient_by_region`'s nine), then the three best and three worst Θ by dose
/// error of a landscape map's `landscape.csv`, if given and readable.
pub fn default_points(landscape_csv: Option<&Path>) -> Vec<(String, Theta)> {
    let mut v: Vec<(String, Theta)> = (0..3)
        .map(|k| (format!("seed{k}"), crate::lab::optim::theta_init(k)))
        .chain(
            secant_thetas(6)
                .into_iter()
                .enumerate()
                .map(|(k, t)| (format!("rand{k}"), t)),
        )
        .collect();
    let Some(text) = landscape_csv.and_then(|p| std::fs::read_to_string(p).ok()) else {
        return v;
    };
    // index,theta_d,theta_s,theta_l,theta_t,theta_p,loss,indicator,transported
    let mut map: Vec<(f64, Theta)> = text
        .lines()
        .skip(1)
        .filter_map(|l| {
            let f: Vec<f64> = l.split(',').filter_map(|x| x.parse().ok()).collect();
            (f.len() >= 8).then(|| (f[7].abs(), Theta(std::array::from_fn(|k| f[1 + k]))))
        })
        .collect();
    map.sort_by(|a, b| a.0.total_cmp(&b.0));
    let n = map.len();
    if n >= 6 {
        for (i, (_, t)) in map.iter().take(3).enumerate() {
            v.push((format!("map best {}", i + 1), *t));
        }
        for (i, (_, t)) in map.iter().skip(n - 3).rev().enumerate() {
            v.push((format!("map worst {}", i + 1), *t));
        }
    }
    v
}

/// One rollout of `kind` at Θ.
fn run_one(problem: &Problem, kind: Kind, theta: Theta) -> anyhow::Result<Rollout> {
    let (value, grad) = match kind {
        Kind::Forward => (problem.evaluate(theta, false, true)?.indicator.abs(), None),
        Kind::Carry => {
            let (o, carried) = problem.evaluate_carry(theta, true)?;
            (carried, o.grad)
        }
        Kind::Eq5 | Kind::Dosing => {
            let mut scene = problem.scene().clone();
            scene.loss = match kind {
                Kind::Eq5 => None,
                _ => Some(LossSpec::Dosing {
                    grams: match problem.target {
                        TargetValue::Grams(g) => g,
                        TargetValue::Particles(n) => {
                            n * scene.particle_masses().first().copied().unwrap_or(0.0) * 1e3
                        }
                    },
                    width: None,
                }),
            };
            let loss = scene_loss(&scene);
            let mut sim = problem.simulation(theta, true)?;
            let (l, g) = problem.skill_gradient(&mut sim, &loss)?;
            (l, Some(g))
        }
    };
    Ok(Rollout {
        kind,
        theta,
        value,
        grad,
    })
}

/// Runs every rollout the points need (resuming from `dir/rollouts.jsonl`); `progress` is
/// called after each new one.
pub fn run(
    problem: &Problem,
    points: &[Theta],
    steps: &[f64],
    dir: &Path,
    progress: &(dyn Fn() + Sync),
) -> anyhow::Result<HashMap<Key, Rollout>> {
    crate::util::create_output_dir(dir, "--out")?;
    let path = dir.join("rollouts.jsonl");
    // A torn last line (killed mid-write) is cut off.
    let (file, kept) = crate::lab::journal::Journal::<Rollout>::open(&path)?;
    let mut done: HashMap<Key, Rollout> = kept
        .into_iter()
        .map(|r| (key(r.kind, &r.theta), r))
        .collect();
    let mut jobs: Vec<(Kind, Theta)> = Vec::new();
    for &t in points {
        jobs.extend(LOSSES.iter().map(|&k| (k, t)));
        jobs.push((Kind::Forward, t));
        for &h in steps {
            for k in 0..5 {
                let (lo, hi) = secant_pair(t, k, h);
                jobs.push((Kind::Forward, lo));
                jobs.push((Kind::Forward, hi));
            }
        }
    }
    jobs.sort_by_key(|a| key(a.0, &a.1));
    jobs.dedup();
    jobs.retain(|(k, t)| !done.contains_key(&key(*k, t)));
    let new: Vec<Rollout> = jobs
        .par_iter()
        .map(|&(k, t)| {
            let r = run_one(problem, k, t)?;
            file.append(&r)?;
            progress();
            Ok(r)
        })
        .collect::<anyhow::Result<_>>()?;
    for r in new {
        done.insert(key(r.kind, &r.theta), r);
    }
    Ok(done)
}

/// One row: a point, a loss, a step and the cosine.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Row {
    pub point: usize,
    pub label: String,
    pub loss: Kind,
    pub h: f64,
    pub cosine: f64,
    pub dose_error: f64,
}

/// The cosines of every point, loss and step.
pub fn rows(
    labels: &[String],
    points: &[Theta],
    steps: &[f64],
    done: &HashMap<Key, Rollout>,
) -> anyhow::Result<Vec<Row>> {
    let get = |k: Kind, t: &Theta| {
        done.get(&key(k, t))
            .ok_or_else(|| anyhow::anyhow!("rollout {k:?} at {t:?} missing"))
    };
    let mut out = Vec::new();
    for (i, t) in points.iter().enumerate() {
        for &h in steps {
            let secant: [f64; 5] = std::array::from_fn(|k| {
                let (lo, hi) = secant_pair(*t, k, h);
                match (get(Kind::Forward, &lo), get(Kind::Forward, &hi)) {
                    (Ok(a), Ok(b)) if hi[k] > lo[k] => (b.value - a.value) / (hi[k] - lo[k]),
                    _ => f64::NAN,
                }
            });
            for &l in &LOSSES {
                let g = get(l, t)?.grad.unwrap_or([f64::NAN; 5]);
                out.push(Row {
                    point: i,
                    label: labels[i].clone(),
                    loss: l,
                    h,
                    cosine: cosine(&g, &secant),
                    dose_error: get(Kind::Forward, t).map(|r| r.value).unwrap_or(f64::NAN),
                });
            }
        }
    }
    Ok(out)
}

/// The page: the summary per loss and step, then every point's cosines.
pub fn report(rows: &[Row], steps: &[f64], command: &str, unit: &str) -> String {
    use std::fmt::Write;
    let mut s = String::from(
        "# Direction test: does a loss's gradient point where the dose error falls?\n\n",
    );
    let _ = writeln!(s, "Regenerate: `{command}`  ");
    let _ = writeln!(s, "Machine: {}.\n", crate::lab::study::machine());
    let _ = writeln!(
        s,
        "At each Θ, the cosine between the adjoint gradient of a loss and the secant gradient of the dose error |indicator| ({unit}) at step h (central, clamped to the box). 1: descending the loss descends the dose error; 0: unrelated; −1: it climbs it. NaN: a zero gradient or a flat secant.\n"
    );
    s.push_str(
        "| loss | h | mean cosine | median | positive | points |\n|---|---|---|---|---|---|\n",
    );
    for &l in &LOSSES {
        for &h in steps {
            let mut c: Vec<f64> = rows
                .iter()
                .filter(|r| r.loss == l && r.h == h && r.cosine.is_finite())
                .map(|r| r.cosine)
                .collect();
            c.sort_by(f64::total_cmp);
            let n = c.len();
            let mean = c.iter().sum::<f64>() / n.max(1) as f64;
            let med = if n == 0 { f64::NAN } else { c[n / 2] };
            let pos = c.iter().filter(|x| **x > 0.0).count();
            let _ = writeln!(
                s,
                "| {} | {h} | {mean:+.3} | {med:+.3} | {pos}/{n} | {n} |",
                l.name()
            );
        }
    }
    s.push_str("\n| point | dose error | ");
    let cols: Vec<(Kind, f64)> = LOSSES
        .iter()
        .flat_map(|&l| steps.iter().map(move |&h| (l, h)))
        .collect();
    for (l, h) in &cols {
        let _ = write!(s, "{} h={h} | ", l.name());
    }
    s.push_str("\n|---|---|");
    s.push_str(&"---|".repeat(cols.len()));
    s.push('\n');
    let mut points: Vec<(usize, &str, f64)> = rows
        .iter()
        .map(|r| (r.point, r.label.as_str(), r.dose_error))
        .collect();
    points.dedup_by_key(|p| p.0);
    for (i, label, d) in points {
        let _ = write!(s, "| {label} | {d:.3} | ");
        for (l, h) in &cols {
            let c = rows
                .iter()
                .find(|r| r.point == i && r.loss == *l && r.h == *h)
                .map_or(f64::NAN, |r| r.cosine);
            let _ = write!(s, "{c:+.2} | ");
        }
        s.push('\n');
    }
    s
}

/// Writes `directions.md` and `directions.csv` to `dir`.
pub fn write(rows: &[Row], md: &str, dir: &Path) -> anyhow::Result<()> {
    use std::fmt::Write;
    crate::util::create_output_dir(dir, "--results")?;
    let mut csv = String::from("point,label,loss,h,cosine,dose_error\n");
    for r in rows {
        let _ = writeln!(
            csv,
            "{},{},{},{},{},{}",
            r.point,
            r.label,
            r.loss.name(),
            r.h,
            r.cosine,
            r.dose_error
        );
    }
    write_atomic(&dir.join("directions.csv"), csv.as_bytes())?;
    write_atomic(&dir.join("directions.md"), md.as_bytes())?;
    Ok(())
}

/// The first `n` random Θ at which the diagnostic examples take secants: uniform in
/// [−0.8, 0.8]⁵ from a fixed generator, so that `gradient_at_scale`'s point `k` and
/// `gradient_by_region`'s `randK` are the same Θ.
pub fn secant_thetas(n: usize) -> Vec<Theta> {
    let mut rng = SplitMix64(1234);
    (0..n)
        .map(|_| Theta(std::array::from_fn(|_| rng.uniform_in(-0.8, 0.8))))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn secants_stay_in_the_box() {
        let (lo, hi) = secant_pair(Theta([0.95, 0.0, -1.0, 0.0, 0.0]), 0, 0.1);
        assert_eq!((lo[0], hi[0]), (0.85, 1.0));
        let (lo, hi) = secant_pair(Theta([0.95, 0.0, -1.0, 0.0, 0.0]), 2, 0.1);
        assert_eq!((lo[2], hi[2]), (-1.0, -0.9));
        assert_eq!(lo[0], 0.95);
    }
}
