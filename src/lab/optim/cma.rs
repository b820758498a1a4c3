//! CMA-ES baseline: the `cmaes` crate (Hansen's CMA-ES with default weights and learning
//! rates), started at Θ_init with step size [`CmaConfig::sigma0`] and population
//! [`CmaConfig::population`].
//!
//! **The box Θ ∈ [−1, 1]⁵.** CMA-ES samples in `R⁵`; each sample is mapped into the box by
//! reflection at the faces ([`reflect`]), which is continuous, the identity inside the box and
//! needs no penalty weight, so every sample is a valid skill and the rollout budget is not spent
//! on penalised points.
//!
//! **Population.** The default for 5 parameters would be `4 + ⌊3 ln 5⌋ = 8`; 6 makes the paper's
//! 30-rollout budget exactly five generations. When the budget is not a multiple of the
//! population, the last generation evaluates only the first samples (in the sampler's order)
//! and the rest are not run.

use serde::{Deserialize, Serialize};

/// CMA-ES settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CmaConfig {
    /// Initial step size σ₀ (Θ units). Default 0.5, a quarter of the box width.
    pub sigma0: f64,
    /// Samples per generation. Default 6.
    pub population: usize,
}

impl Default for CmaConfig {
    fn default() -> Self {
        Self {
            sigma0: 0.5,
            population: 6,
        }
    }
}

/// Runs CMA-ES (the `cmaes` crate, its default population for the dimension) from `x0` with
/// step size `sigma0`, one sample at a time in the sampler's order, until `eval` has scored
/// `budget` samples. `eval` gets each raw sample (the caller maps it into its box) and returns
/// its loss; its first error stops the run and is returned. A termination criterion of the
/// crate ends nothing: the method gets its whole budget.
pub fn run_sequential(
    x0: Vec<f64>,
    sigma0: f64,
    seed: u64,
    budget: usize,
    eval: impl FnMut(&[f64]) -> anyhow::Result<f64>,
) -> anyhow::Result<()> {
    use std::sync::Mutex;
    let done = Mutex::new(0usize);
    let failure: Mutex<Option<anyhow::Error>> = Mutex::new(None);
    let eval = Mutex::new(eval);
    let f = |x: &cmaes::DVector<f64>| -> f64 {
        let mut n = done.lock().expect("lock");
        if *n >= budget || failure.lock().expect("lock").is_some() {
            return f64::MAX;
        }
        match (eval.lock().expect("lock"))(x.as_slice()) {
            Ok(l) => {
                *n += 1;
                l
            }
            Err(e) => {
                failure.lock().expect("lock").get_or_insert(e);
                f64::NAN
            }
        }
    };
    let mut st = cmaes::CMAESOptions::new(x0, sigma0)
        .seed(seed)
        .build(f)
        .map_err(|e| anyhow::anyhow!("CMA-ES options: {e:?}"))?;
    while *done.lock().expect("lock") < budget {
        let _ = st.next();
        if let Some(e) = failure.lock().expect("lock").take() {
            return Err(e);
        }
    }
    Ok(())
}

/// Maps `x ∈ R` into `[−1, 1]` by reflecting at ±1 (a triangle wave of period 4).
pub fn reflect(x: f64) -> f64 {
    if (-1.0..=1.0).contains(&x) {
        return x;
    }
    let y = (x + 1.0).rem_euclid(4.0);
    if y <= 2.0 {
        y - 1.0
    } else {
        3.0 - y
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reflection_is_the_identity_inside_and_folds_outside() {
        for x in [-1.0, -0.3, 0.0, 0.7, 1.0] {
            assert_eq!(reflect(x), x);
        }
        assert!((reflect(1.25) - 0.75).abs() < 1e-15);
        assert!((reflect(-1.5) + 0.5).abs() < 1e-15);
        assert!((reflect(3.5) + 0.5).abs() < 1e-15);
        assert!((reflect(-7.0) - 1.0).abs() < 1e-15);
    }
}
