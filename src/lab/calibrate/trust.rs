//! A bounded trust-region quasi-Newton method on the adjoint gradient, after a coarse scan: the
//! gradient calibrator that spends a gradient rollout's cost where it pays.
//!
//! Adam moves each coordinate by about its step size whatever the gradient's size, so with ten
//! gradient rollouts it neither crosses a wide range quickly nor settles finely (the rows of
//! `docs/results/calibration.md`). A calibration has one to a few parameters and a deterministic
//! loss, the setting of L-BFGS-B; here:
//!
//! 1. **Scan.** The start and `scan` scrambled Sobol points of the box, forward rollouts only
//!    (a pile's loss has more than one basin: a column at 49° that barely fails is a local
//!    minimum for a pile poured at 20°). The best of them is where the descent begins.
//! 2. **Descent.** Each gradient rollout gives the loss and `∂L/∂u`; a damped BFGS update
//!    ([`bfgs_update`]) turns successive gradients into curvature (in one dimension, the secant).
//!    The step minimises the quadratic model within a box trust region intersected with the
//!    parameter bounds ([`box_qp`]); the region grows when the model predicts the loss well and
//!    shrinks when it does not, which is also how the loss's grain-scale roughness is met.
//!
//! Hand-written: no maintained Rust crate has a bounded quasi-Newton method (`argmin`'s L-BFGS
//! is unbounded and its line searches spend several gradient rollouts a step, more than a budget
//! of about ten affords).

use super::Eval;
use serde::{Deserialize, Serialize};

/// The trust-region method's settings.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
pub struct TrustConfig {
    /// Scan points besides the start (forward rollouts); 0 starts the descent at the start.
    pub scan: usize,
    /// The first trust region's half-width in unit coordinates.
    pub radius: f64,
}

impl TrustConfig {
    /// Four scan points per fitted parameter (the quarters of a one-parameter range), and a
    /// first step of a tenth of each range.
    pub fn for_dims(d: usize) -> Self {
        TrustConfig {
            scan: 4 * d,
            radius: 0.1,
        }
    }
}

/// The smallest trust region, in unit coordinates (0.5° of a 10–60° friction range, 0.015 of a
/// 0–1.5 friction): a pile's height loss has bumps under a degree wide (a 0.1° sweep of the
/// collapse on `docs/results/calibration.md`: a rise of 4 % over 0.7° on a two-degree slope
/// down), which a smaller region only settles into. A step rejected at this size ends a descent,
/// and the next starts in another basin.
pub const MIN_RADIUS: f64 = 1e-2;

/// Model agreement `ρ = actual / predicted decrease` above which a step that reached the region's
/// edge doubles it, and below which the region shrinks fourfold (the textbook 0.75 and 0.25).
const GROW_AT: f64 = 0.75;
const SHRINK_AT: f64 = 0.25;

/// Powell's damping: the update keeps `sᵀr ≥ DAMPING · sᵀBs`, so the model stays convex when a
/// rough loss gives a pair of gradients that bend the wrong way.
const DAMPING: f64 = 0.2;

/// `B s` for a row-major `d × d` matrix.
fn mul(b: &[f64], s: &[f64]) -> Vec<f64> {
    let d = s.len();
    (0..d)
        .map(|i| (0..d).map(|j| b[i * d + j] * s[j]).sum())
        .collect()
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The damped BFGS update of the Hessian model `b` (row-major, `d × d`, positive definite) by the
/// step `s` and gradient change `y`. With no model yet (`None`) the first pair of positive
/// curvature sets it to `(yᵀy / sᵀy) I` before the update; a first pair of negative curvature
/// leaves it unset. Returns the new model.
pub fn bfgs_update(b: Option<Vec<f64>>, s: &[f64], y: &[f64]) -> Option<Vec<f64>> {
    let d = s.len();
    let ss = dot(s, s);
    if ss <= 0.0 || !ss.is_finite() || y.iter().any(|v| !v.is_finite()) {
        return b;
    }
    let sy = dot(s, y);
    let b = match b {
        Some(b) => b,
        None if sy > 0.0 => {
            let scale = dot(y, y) / sy;
            let mut b = vec![0.0; d * d];
            for i in 0..d {
                b[i * d + i] = scale;
            }
            b
        }
        None => return None,
    };
    let bs = mul(&b, s);
    let sbs = dot(s, &bs);
    if sbs <= 0.0 {
        return Some(b);
    }
    let theta = if sy >= DAMPING * sbs {
        1.0
    } else {
        (1.0 - DAMPING) * sbs / (sbs - sy)
    };
    let r: Vec<f64> = y
        .iter()
        .zip(&bs)
        .map(|(yi, bi)| theta * yi + (1.0 - theta) * bi)
        .collect();
    let sr = dot(s, &r);
    let mut out = b.clone();
    for i in 0..d {
        for j in 0..d {
            out[i * d + j] += r[i] * r[j] / sr - bs[i] * bs[j] / sbs;
        }
    }
    Some(out)
}

/// Sweeps of coordinate descent in [`box_qp`]: exact for one parameter, and far more than a
/// well-conditioned model of a few needs.
const QP_SWEEPS: usize = 200;

/// The minimiser of the model `gᵀs + ½ sᵀBs` over the box `lo ≤ s ≤ hi` (`lo ≤ 0 ≤ hi`), by
/// projected coordinate descent from `s = 0`; `b` positive definite. Without a model, the
/// steepest-descent step to the box's edge: `s = −t g` with the largest `t` the box allows
/// in `g`'s largest coordinate, then clamped.
pub fn box_qp(g: &[f64], b: Option<&[f64]>, lo: &[f64], hi: &[f64]) -> Vec<f64> {
    let d = g.len();
    let Some(b) = b else {
        let gmax = g.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if gmax == 0.0 {
            return vec![0.0; d];
        }
        // Scaled so that the largest coordinate moves to the region's edge.
        let width = (0..d)
            .map(|i| if g[i] > 0.0 { -lo[i] } else { hi[i] })
            .zip(g)
            .filter(|(_, gi)| gi.abs() == gmax)
            .map(|(w, _)| w)
            .fold(f64::INFINITY, f64::min);
        return (0..d)
            .map(|i| (-g[i] / gmax * width).clamp(lo[i], hi[i]))
            .collect();
    };
    let mut s = vec![0.0; d];
    for _ in 0..QP_SWEEPS {
        let mut moved = 0.0f64;
        for i in 0..d {
            let off: f64 = (0..d)
                .filter(|&j| j != i)
                .map(|j| b[i * d + j] * s[j])
                .sum();
            let bii = b[i * d + i];
            let v = if bii > 0.0 {
                (-(g[i] + off) / bii).clamp(lo[i], hi[i])
            } else if g[i] + off > 0.0 {
                lo[i]
            } else {
                hi[i]
            };
            moved = moved.max((v - s[i]).abs());
            s[i] = v;
        }
        if moved < 1e-15 {
            break;
        }
    }
    s
}

/// The model's predicted decrease `−(gᵀs + ½ sᵀBs)` (first order without a model).
fn predicted(g: &[f64], b: Option<&[f64]>, s: &[f64]) -> f64 {
    -(dot(g, s) + b.map_or(0.0, |b| 0.5 * dot(s, &mul(b, s))))
}

/// The scan's points: `n` points of a scrambled Sobol sequence in `[0, 1]^d` from `seed`, so
/// that four points of one parameter see each quarter of its range.
pub fn scan_points(d: usize, n: usize, seed: u64) -> Vec<Vec<f64>> {
    crate::lab::optim::sobol_unit(n, d, seed as u32)
}

/// The scan, then trust-region descents, the first from the scan's best point and each later one
/// from the best scan point in a basin no earlier descent reached, until the next rollout would
/// pass `budget` forward rollouts' compute (at least the start runs). `eval(i, u, grad)` runs (or
/// replays) rollout `i`.
pub fn trust_region(
    u0: &[f64],
    budget: f64,
    cfg: TrustConfig,
    seed: u64,
    mut eval: impl FnMut(usize, &[f64], bool) -> anyhow::Result<Eval>,
) -> anyhow::Result<Vec<Eval>> {
    let d = u0.len();
    let mut out: Vec<Eval> = Vec::new();
    let mut spent = 0.0;
    // The scan: the start, then the Sobol points, forward only.
    let mut points = vec![u0.to_vec()];
    points.extend(scan_points(d, cfg.scan, seed));
    for p in points {
        if !out.is_empty() && spent + 1.0 > budget + 1e-9 {
            return Ok(out);
        }
        let e = eval(out.len(), &p, false)?;
        spent += e.cost;
        out.push(e);
    }
    // The descents: from the best scan point, then, each time one settles, from the best scan
    // point that no earlier descent came within the scan's spacing of (another basin).
    let mut starts: Vec<Vec<f64>> = {
        let mut by_loss: Vec<&Eval> = out.iter().collect();
        by_loss.sort_by(|a, b| a.loss.total_cmp(&b.loss));
        by_loss.into_iter().map(|e| e.u.clone()).collect()
    };
    let mut visited: Vec<Vec<f64>> = Vec::new();
    let spacing = ((cfg.scan + 1) as f64).powf(-1.0 / d as f64);
    while let Some(k) = starts.iter().position(|p| {
        visited
            .iter()
            .all(|v| v.iter().zip(p).any(|(a, b)| (a - b).abs() > spacing))
    }) {
        let x0 = starts.remove(k);
        let more = descend(&x0, budget, cfg.radius, &mut out, &mut visited, &mut eval)?;
        if !more {
            break;
        }
    }
    Ok(out)
}

/// One trust-region descent from `x0`, appending its rollouts to `out` and its points to
/// `visited`. Returns whether the budget allows another descent: `false` when it ran out, `true`
/// when the descent settled (a step the region's floor cannot improve, or no step at all).
fn descend(
    x0: &[f64],
    budget: f64,
    radius0: f64,
    out: &mut Vec<Eval>,
    visited: &mut Vec<Vec<f64>>,
    eval: &mut impl FnMut(usize, &[f64], bool) -> anyhow::Result<Eval>,
) -> anyhow::Result<bool> {
    let d = x0.len();
    // Whether the next gradient rollout fits: it costs what the last one did (the first always
    // runs if the scan left any budget).
    let room = |out: &[Eval]| {
        let spent: f64 = out.iter().map(|e| e.cost).sum();
        let next = out
            .iter()
            .rev()
            .find(|e| e.grad.is_some())
            .map_or(1.0, |e| e.cost);
        spent + next <= budget + 1e-9
    };
    if !room(out) {
        return Ok(false);
    }
    let mut x = x0.to_vec();
    let first = eval(out.len(), &x, true)?;
    out.push(first.clone());
    visited.push(x.clone());
    let mut cur = first;
    let mut b: Option<Vec<f64>> = None;
    let mut radius = radius0;
    loop {
        if !room(out) {
            return Ok(false);
        }
        let g = cur.grad.clone().unwrap_or_else(|| vec![0.0; d]);
        let lo: Vec<f64> = x.iter().map(|xi| (-radius).max(-xi)).collect();
        let hi: Vec<f64> = x.iter().map(|xi| radius.min(1.0 - xi)).collect();
        let s = box_qp(&g, b.as_deref(), &lo, &hi);
        if s.iter().all(|v| v.abs() < 1e-12) {
            // A stationary point, or a corner the gradient pushes against: nothing to try.
            return Ok(true);
        }
        let pred = predicted(&g, b.as_deref(), &s);
        let trial: Vec<f64> = x
            .iter()
            .zip(&s)
            .map(|(a, b)| (a + b).clamp(0.0, 1.0))
            .collect();
        let e = eval(out.len(), &trial, true)?;
        out.push(e.clone());
        visited.push(trial.clone());
        let gy = e.grad.clone().unwrap_or_else(|| vec![0.0; d]);
        let y: Vec<f64> = gy.iter().zip(&g).map(|(a, b)| a - b).collect();
        b = bfgs_update(b, &s, &y);
        let rho = if pred > 0.0 {
            (cur.loss - e.loss) / pred
        } else {
            -1.0
        };
        let at_edge = s
            .iter()
            .zip(lo.iter().zip(&hi))
            .any(|(v, (l, h))| (*v - l).abs() < 1e-12 || (*v - h).abs() < 1e-12);
        let floor = radius <= MIN_RADIUS;
        if rho > GROW_AT && at_edge {
            radius = (2.0 * radius).min(1.0);
        } else if rho < SHRINK_AT {
            radius = (radius / 4.0).max(MIN_RADIUS);
        }
        if e.loss < cur.loss {
            x = trial;
            cur = e;
        } else if floor {
            // Settled: the smallest region the loss's grain allows found nothing lower.
            return Ok(true);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quadratic_eval(
        centre: Vec<f64>,
        h: Vec<f64>,
    ) -> impl FnMut(usize, &[f64], bool) -> anyhow::Result<Eval> {
        move |_, u, grad| {
            let r: Vec<f64> = u.iter().zip(&centre).map(|(a, b)| a - b).collect();
            let hr = mul(&h, &r);
            Ok(Eval {
                u: u.to_vec(),
                values: u.to_vec(),
                loss: 0.5 * dot(&r, &hr),
                grad: grad.then(|| hr.clone()),
                cost: if grad { 3.5 } else { 1.0 },
                wall_s: 0.0,
            })
        }
    }

    #[test]
    fn one_secant_pair_gives_the_exact_curvature_of_a_parabola() {
        // L = 3 u², so g = 6u: any two points give B = 6.
        let b = bfgs_update(None, &[0.2], &[6.0 * 0.2]).expect("positive curvature");
        assert!((b[0] - 6.0).abs() < 1e-12, "{b:?}");
        let b = bfgs_update(Some(vec![1.0]), &[-0.1], &[-0.6]).expect("kept");
        assert!((b[0] - 6.0).abs() < 1e-12, "{b:?}");
    }

    #[test]
    fn a_pair_that_bends_the_wrong_way_keeps_the_model_convex() {
        assert_eq!(bfgs_update(None, &[0.1], &[-0.3]), None);
        let b =
            bfgs_update(Some(vec![2.0, 0.0, 0.0, 2.0]), &[0.1, 0.0], &[-0.5, 0.1]).expect("kept");
        // Positive definite: both leading minors positive.
        assert!(b[0] > 0.0 && b[0] * b[3] - b[1] * b[2] > 0.0, "{b:?}");
    }

    #[test]
    fn the_box_qp_is_the_clamped_newton_step() {
        // Inside the box: the Newton step −B⁻¹g.
        let b = [2.0, 0.5, 0.5, 1.0];
        let g = [1.0, -1.0];
        let s = box_qp(&g, Some(&b), &[-10.0, -10.0], &[10.0, 10.0]);
        let r = mul(&b, &s);
        assert!(
            (r[0] + g[0]).abs() < 1e-10 && (r[1] + g[1]).abs() < 1e-10,
            "{s:?}"
        );
        // A bound that binds: the minimiser over the face, from the KKT conditions.
        let s = box_qp(&g, Some(&b), &[-0.1, -0.1], &[0.1, 0.1]);
        assert!((s[0] + 0.1).abs() < 1e-12, "{s:?}");
        // On the face s0 = −0.1: minimise over s1, 1·s1 + 0.5·(−0.1) − 1 = 0 → s1 = 1.05 → 0.1.
        assert!((s[1] - 0.1).abs() < 1e-12, "{s:?}");
        // Without a model: steepest descent to the edge along the largest coordinate.
        let s = box_qp(&[2.0, -1.0], None, &[-0.2, -0.2], &[0.2, 0.2]);
        assert!(
            (s[0] + 0.2).abs() < 1e-12 && (s[1] - 0.1).abs() < 1e-12,
            "{s:?}"
        );
    }

    #[test]
    fn four_scan_points_see_every_quarter_of_one_range() {
        for seed in [0, 7, 12345] {
            let mut q: Vec<usize> = scan_points(1, 4, seed)
                .iter()
                .map(|p| (p[0] * 4.0) as usize)
                .collect();
            q.sort();
            assert_eq!(q, vec![0, 1, 2, 3], "seed {seed}");
        }
    }

    #[test]
    fn a_settled_descent_hands_the_budget_to_another_basin() {
        // A wide basin (bottom 0.1 at 0.75) that the scan's best point lies in, and a narrow,
        // deeper one (0 at 0.3) that no scan point reaches the bottom of.
        let f = |u: f64| {
            let (a, b) = (40.0 * (u - 0.75).powi(2) + 0.1, 400.0 * (u - 0.3).powi(2));
            if a < b {
                (a, 80.0 * (u - 0.75))
            } else {
                (b, 800.0 * (u - 0.3))
            }
        };
        let trace = trust_region(&[0.9], 40.0, TrustConfig::for_dims(1), 3, |_, u, grad| {
            let (l, g) = f(u[0]);
            Ok(Eval {
                u: u.to_vec(),
                values: u.to_vec(),
                loss: l,
                grad: grad.then(|| vec![g]),
                cost: if grad { 3.5 } else { 1.0 },
                wall_s: 0.0,
            })
        })
        .expect("runs");
        let scan_best = crate::lab::calibrate::lowest(&trace[..5]).expect("scanned");
        assert!(scan_best.loss > 0.1 - 1e-12 && (scan_best.u[0] - 0.3).abs() > 0.05);
        let best = crate::lab::calibrate::lowest(&trace).expect("ran");
        assert!(
            (best.u[0] - 0.3).abs() < 1e-3,
            "{:?}",
            trace
                .iter()
                .map(|e| (e.u[0], e.loss, e.grad.is_some()))
                .collect::<Vec<_>>()
        );
    }

    #[test]
    fn it_finds_a_bowls_bottom_in_a_few_gradient_rollouts() {
        // A parabola whose minimum is far from the start and off the scan's points.
        let centre = vec![0.731];
        let trace = trust_region(
            &[0.05],
            5.0 + 6.0 * 3.5,
            TrustConfig::for_dims(1),
            3,
            quadratic_eval(centre.clone(), vec![40.0]),
        )
        .expect("runs");
        let best = crate::lab::calibrate::lowest(&trace).expect("ran");
        assert!((best.u[0] - centre[0]).abs() < 1e-6, "{:?}", best.u);
        // The budget is kept: 5 scans and 6 gradient rollouts.
        let spent: f64 = trace.iter().map(|e| e.cost).sum();
        assert!(spent <= 5.0 + 6.0 * 3.5 + 1e-9, "{spent}");
        // Three parameters, an ill-conditioned bowl with its bottom against a bound.
        let centre = vec![0.2, 0.5, 1.3];
        let h = vec![50.0, 5.0, 0.0, 5.0, 2.0, 0.0, 0.0, 0.0, 10.0];
        let trace = trust_region(
            &[0.9, 0.1, 0.5],
            13.0 + 12.0 * 3.5,
            TrustConfig::for_dims(3),
            3,
            quadratic_eval(centre, h),
        )
        .expect("runs");
        let best = crate::lab::calibrate::lowest(&trace).expect("ran");
        let want = [0.2, 0.5, 1.0];
        for (got, want) in best.u.iter().zip(want) {
            assert!((got - want).abs() < 1e-3, "{:?}", best.u);
        }
    }
}
