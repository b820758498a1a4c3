//! The optimisers of a calibration, in unit coordinates: Adam on the adjoint gradient and
//! CMA-ES on the forward loss, each counting its compute in forward rollouts.

use super::{Calibration, Eval};
use serde::{Deserialize, Serialize};

/// Adam's settings.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
pub struct AdamConfig {
    /// Step size in unit coordinates: the first steps move each parameter by about this share
    /// of its range.
    pub lr: f64,
    pub beta1: f64,
    pub beta2: f64,
}

impl Default for AdamConfig {
    fn default() -> Self {
        AdamConfig {
            lr: 0.08,
            beta1: 0.8,
            beta2: 0.99,
        }
    }
}

/// The backward pass's cost in forward rollouts on `cal` at `u`: the median of `reps` timed
/// forward and gradient rollouts, `t_grad/t_forward − 1`.
pub fn measure_backward_cost(cal: &Calibration, u: &[f64], reps: usize) -> anyhow::Result<f64> {
    let mut f = Vec::new();
    let mut g = Vec::new();
    for _ in 0..reps.max(1) {
        f.push(cal.evaluate(u, false)?.wall_s);
        g.push(cal.evaluate(u, true)?.wall_s);
    }
    let med = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    Ok((med(&mut g) / med(&mut f) - 1.0).max(0.0))
}

/// Adam on the adjoint gradient from `u0`, projected onto `[0, 1]` per coordinate, until the
/// next gradient rollout would pass `budget` forward rollouts' compute (at least one runs).
/// `eval` runs (or replays) one rollout; its `cost` is what the budget counts.
pub fn adam(
    u0: &[f64],
    budget: f64,
    cfg: AdamConfig,
    mut eval: impl FnMut(usize, &[f64], bool) -> anyhow::Result<Eval>,
) -> anyhow::Result<Vec<Eval>> {
    let d = u0.len();
    let (mut u, mut m, mut v) = (u0.to_vec(), vec![0.0; d], vec![0.0; d]);
    let mut out: Vec<Eval> = Vec::new();
    let mut spent = 0.0;
    for t in 1.. {
        // The next rollout costs what the last one did.
        if let Some(last) = out.last() {
            if spent + last.cost > budget + 1e-9 {
                break;
            }
        }
        let e = eval(out.len(), &u, true)?;
        spent += e.cost;
        let g = e.grad.clone().unwrap_or_else(|| vec![0.0; d]);
        out.push(e);
        for i in 0..d {
            m[i] = cfg.beta1 * m[i] + (1.0 - cfg.beta1) * g[i];
            v[i] = cfg.beta2 * v[i] + (1.0 - cfg.beta2) * g[i] * g[i];
            let mh = m[i] / (1.0 - cfg.beta1.powi(t));
            let vh = v[i] / (1.0 - cfg.beta2.powi(t));
            if vh > 0.0 {
                u[i] = (u[i] - cfg.lr * mh / vh.sqrt()).clamp(0.0, 1.0);
            }
        }
    }
    Ok(out)
}

/// Maps `x ∈ R` into `[0, 1]` by reflection at the faces.
fn reflect01(x: f64) -> f64 {
    0.5 * (crate::lab::optim::cma::reflect(2.0 * x - 1.0) + 1.0)
}

/// CMA-ES's initial step size in unit coordinates: a quarter of the box.
pub const CMA_SIGMA0: f64 = 0.25;

/// CMA-ES (the `cmaes` crate, its default population) on the forward loss, `budget` forward
/// rollouts: the first at `u0` (as Adam's first is), then the sampler's points around `u0`,
/// reflected into the box.
pub fn cmaes(
    u0: &[f64],
    budget: usize,
    seed: u64,
    mut eval: impl FnMut(usize, &[f64], bool) -> anyhow::Result<Eval>,
) -> anyhow::Result<Vec<Eval>> {
    let mut out = vec![eval(0, u0, false)?];
    crate::lab::optim::cma::run_sequential(
        u0.to_vec(),
        CMA_SIGMA0,
        seed,
        budget.saturating_sub(1),
        |x| {
            let u: Vec<f64> = x.iter().map(|v| reflect01(*v)).collect();
            let e = eval(out.len(), &u, false)?;
            let l = e.loss;
            out.push(e);
            Ok(l)
        },
    )?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reflection_keeps_samples_in_the_unit_box() {
        for x in [-0.7, -0.1, 0.0, 0.3, 1.0, 1.2, 2.9] {
            let y = reflect01(x);
            assert!((0.0..=1.0).contains(&y), "{x} -> {y}");
        }
        assert_eq!(reflect01(0.3), 0.3);
        assert!((reflect01(1.2) - 0.8).abs() < 1e-12);
    }
}
