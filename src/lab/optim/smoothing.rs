//! Seed B's smoothed gradient (Diff-LfD, its eq. 6): the gradient of the loss smoothed by
//! Gaussian noise, `∇E_ξ[L(Θ + σξ)]`, estimated from `K` rollouts at `Θ + σξ_k`. The
//! estimates below take any such samples; `optimize --method smoothed` perturbs Θ, and with
//! `--smooth-packing f` also the initial state as seed B does: each sample runs on its own
//! packing of the powder, every particle moved by `f` spacings times a normal draw per axis
//! (`Problem::simulation_repacked`).
//!
//! From the same `K` samples, three estimates:
//! - **first order**: the adjoint gradients, aggregated robustly. A single spilled grain gives an
//!   exact gradient hundreds of times the median (`docs/results/skill_optimisation.md`), so the
//!   plain mean is ruled by rare samples; [`trimmed_mean`] drops the largest and smallest
//!   [`TRIM`] of each component first.
//! - **zeroth order**: `(1/(Kσ))·Σ_k (L_k − L̄)·ξ_k` from the losses alone (a baseline-subtracted
//!   Gaussian-smoothing estimate), which costs nothing more. It sees a staircase's slope over
//!   the noise's scale, where every adjoint gradient is 0.
//! - **α-order**: `α·ĝ₁ + (1 − α)·ĝ₀` with `α = V₀/(V₀ + V₁)`, `V` each estimate's empirical
//!   variance (Suh et al. 2022, "Do differentiable simulators give better policy gradients?"):
//!   the estimate with less variance gets more weight, unless the first-order estimate is
//!   biased. As Suh et al. do, the unbiased zeroth-order estimate is the check: where
//!   `‖ĝ₁ − ĝ₀‖` exceeds [`BIAS_SIGMAS`] of ĝ₀'s standard error, α = 0. On a staircase every
//!   adjoint gradient is 0, so ĝ₁ has no variance at all and only this check keeps it out.

/// Fraction of the samples dropped at each end of each component by [`trimmed_mean`]: with
/// `K = 8` it drops one sample at each end, enough for one planted outlier of either sign.
pub const TRIM: f64 = 0.125;

/// How many of the zeroth-order estimate's standard errors the first-order one may differ by
/// before it is taken as biased (about 95 % of an unbiased difference falls within 2).
pub const BIAS_SIGMAS: f64 = 2.0;

/// One smoothing sample: its noise `ξ` (standard normal), loss and adjoint gradient.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    pub xi: [f64; 5],
    pub loss: f64,
    pub grad: [f64; 5],
}

/// The mean of `xs` without the `⌊trim·n⌋` smallest and largest values (at least one value is
/// kept).
pub fn trimmed_mean(xs: &[f64], trim: f64) -> f64 {
    if xs.is_empty() {
        return 0.0;
    }
    let mut v = xs.to_vec();
    v.sort_by(f64::total_cmp);
    let cut = ((trim * v.len() as f64).floor() as usize).min((v.len() - 1) / 2);
    let kept = &v[cut..v.len() - cut];
    kept.iter().sum::<f64>() / kept.len() as f64
}

/// The first-order estimate: the component-wise [`trimmed_mean`] of the adjoint gradients.
pub fn first_order(samples: &[Sample]) -> [f64; 5] {
    std::array::from_fn(|k| {
        let c: Vec<f64> = samples.iter().map(|s| s.grad[k]).collect();
        trimmed_mean(&c, TRIM)
    })
}

/// The zeroth-order estimate `(1/(Kσ))·Σ (L_k − L̄)·ξ_k`.
pub fn zeroth_order(samples: &[Sample], sigma: f64) -> [f64; 5] {
    let n = samples.len().max(1) as f64;
    let mean = samples.iter().map(|s| s.loss).sum::<f64>() / n;
    std::array::from_fn(|k| {
        samples
            .iter()
            .map(|s| (s.loss - mean) * s.xi[k])
            .sum::<f64>()
            / (n * sigma)
    })
}

/// The empirical variance of the mean of `vectors` (summed over components).
fn variance_of_mean(vectors: &[[f64; 5]]) -> f64 {
    let n = vectors.len();
    if n < 2 {
        return f64::INFINITY;
    }
    (0..5)
        .map(|k| {
            let m = vectors.iter().map(|v| v[k]).sum::<f64>() / n as f64;
            vectors.iter().map(|v| (v[k] - m).powi(2)).sum::<f64>() / ((n - 1) * n) as f64
        })
        .sum()
}

/// The α-order estimate and its α: `α = V₀/(V₀ + V₁)` from the empirical variances of the
/// zeroth-order terms and of the adjoint gradients (each sample's own term), or 0 where the
/// first-order estimate is more than [`BIAS_SIGMAS`] standard errors from the zeroth-order one.
pub fn alpha_order(samples: &[Sample], sigma: f64) -> ([f64; 5], f64) {
    let g1 = first_order(samples);
    let g0 = zeroth_order(samples, sigma);
    let n = samples.len().max(1) as f64;
    let mean = samples.iter().map(|s| s.loss).sum::<f64>() / n;
    let terms0: Vec<[f64; 5]> = samples
        .iter()
        .map(|s| s.xi.map(|x| (s.loss - mean) * x / sigma))
        .collect();
    let terms1: Vec<[f64; 5]> = samples.iter().map(|s| s.grad).collect();
    let (v0, v1) = (variance_of_mean(&terms0), variance_of_mean(&terms1));
    let gap = (0..5).map(|k| (g1[k] - g0[k]).powi(2)).sum::<f64>().sqrt();
    let alpha = if gap > BIAS_SIGMAS * v0.sqrt() {
        0.0
    } else if (v0 + v1).is_finite() && v0 + v1 > 0.0 {
        v0 / (v0 + v1)
    } else {
        0.5
    };
    (
        std::array::from_fn(|k| alpha * g1[k] + (1.0 - alpha) * g0[k]),
        alpha,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::SplitMix64;

    /// A staircase in θ₀ falling by 1 per 0.1 (and flat in the rest): the derivative is 0
    /// almost everywhere.
    fn staircase(t: &[f64; 5]) -> f64 {
        (t[0] / 0.1).floor()
    }

    fn samples(k: usize, sigma: f64, at: [f64; 5], seed: u64) -> Vec<Sample> {
        let mut rng = SplitMix64(seed);
        (0..k)
            .map(|_| {
                let xi: [f64; 5] = std::array::from_fn(|_| rng.normal());
                let t: [f64; 5] = std::array::from_fn(|i| at[i] + sigma * xi[i]);
                Sample {
                    xi,
                    loss: staircase(&t),
                    grad: [0.0; 5],
                }
            })
            .collect()
    }

    #[test]
    fn on_a_staircase_the_derivative_is_zero_and_the_smoothed_estimates_point_downhill() {
        let s = samples(256, 0.2, [0.05, 0.0, 0.0, 0.0, 0.0], 3);
        // Every adjoint gradient of a staircase is 0.
        assert_eq!(first_order(&s), [0.0; 5]);
        // The smoothed loss rises by 1 per 0.1 in θ₀: the estimates see a slope near 10.
        let g0 = zeroth_order(&s, 0.2);
        assert!(
            g0[0] > 5.0 && g0[1..].iter().all(|x| x.abs() < 0.5 * g0[0]),
            "{g0:?}"
        );
        let (ga, alpha) = alpha_order(&s, 0.2);
        assert!(
            (0.0..=1.0).contains(&alpha) && ga[0] > 0.0,
            "{ga:?} {alpha}"
        );
    }

    #[test]
    fn the_robust_aggregate_ignores_a_planted_outlier() {
        let mut s: Vec<Sample> = (0..8)
            .map(|k| Sample {
                xi: [0.0; 5],
                loss: 1.0,
                grad: [1.0 + 0.01 * k as f64, -2.0, 0.5, 0.0, 3.0],
            })
            .collect();
        let clean = first_order(&s);
        s[3].grad = [700.0, -900.0, 0.5, 1e4, -5e3];
        let with = first_order(&s);
        for k in 0..5 {
            assert!(
                (with[k] - clean[k]).abs() < 0.05,
                "{k}: {with:?} against {clean:?}"
            );
        }
        // The plain mean would have moved by hundreds.
        let mean0: f64 = s.iter().map(|x| x.grad[0]).sum::<f64>() / 8.0;
        assert!(mean0 > 80.0);
    }

    #[test]
    fn alpha_favours_the_estimate_with_less_variance() {
        let mut rng = SplitMix64(9);
        // Losses pure noise (a large zeroth-order variance), gradients all alike.
        let s: Vec<Sample> = (0..16)
            .map(|_| Sample {
                xi: std::array::from_fn(|_| rng.normal()),
                loss: 100.0 * rng.normal(),
                grad: [1.0, 0.0, 0.0, 0.0, 0.0],
            })
            .collect();
        let (g, alpha) = alpha_order(&s, 0.1);
        assert!(alpha > 0.99 && (g[0] - 1.0).abs() < 0.5, "{alpha} {g:?}");
    }
}
