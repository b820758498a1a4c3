//! The hybrid method: a forward-only global phase, then guarded gradient steps.
//!
//! 1. **Global.** The first [`HybridConfig::global`] of the budget goes to forward rollouts at
//!    Θ_init and at Owen-scrambled Sobol points of [−1, 1]⁵ (`sobol_burley`, scrambled per seed),
//!    which cover the box more evenly than random draws.
//! 2. **Local.** From the global phase's best Θ (by loss), a trust region: one gradient rollout
//!    at the incumbent gives `g = ∂L/∂Θ`; the trial `Θ − r·g/‖g‖` (clamped to the box) runs
//!    forward only. If its loss falls, it becomes the incumbent (its gradient rollout is the next
//!    step's) and `r` grows; otherwise `r` shrinks and the next trial reuses the same gradient,
//!    so a rejected step costs one forward rollout, not a backward pass.
//!
//! The budget is counted in forward rollouts, a gradient rollout at `1 + BACKWARD_COST`
//! ([`super::report::BACKWARD_COST`]), so that `--epochs N` gives the hybrid the compute of N
//! forward rollouts. The gradient's length is not used (only its direction): on the transport
//! scene single rollouts return gradients hundreds of times the usual size.

use crate::skills::Theta;
use serde::{Deserialize, Serialize};

/// The hybrid's settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct HybridConfig {
    /// Fraction of the budget spent on the global phase. Default 0.5.
    pub global: f64,
    /// Initial trust radius (Θ units, Euclidean). Default 0.1.
    pub radius: f64,
}

impl Default for HybridConfig {
    fn default() -> Self {
        Self {
            global: 0.5,
            radius: 0.1,
        }
    }
}

/// A trust region on the step length.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrustRegion {
    pub radius: f64,
}

impl TrustRegion {
    /// Factor applied to the radius after an accepted step.
    pub const GROW: f64 = 1.5;
    /// Factor applied after a rejected step.
    pub const SHRINK: f64 = 0.5;
    /// Largest radius: a quarter of the box's side.
    pub const MAX: f64 = 0.5;
    /// Below this radius (one part in a thousand of the box) steps no longer change the rollout
    /// measurably; the region restarts at the initial radius from the incumbent.
    pub const MIN: f64 = 1e-3;

    /// The trial point `Θ − r·g/‖g‖`, clamped to [−1, 1]⁵; `None` for a zero or non-finite
    /// gradient (no direction to try).
    pub fn propose(&self, theta: Theta, grad: [f64; 5]) -> Option<Theta> {
        let t = self.propose_in(&theta[..], &grad)?;
        Some(Theta(std::array::from_fn(|k| t[k])))
    }

    /// [`Self::propose`] in any dimension: `x − r·g/‖g‖`, clamped to [−1, 1]ⁿ.
    pub fn propose_in(&self, x: &[f64], grad: &[f64]) -> Option<Vec<f64>> {
        let norm = grad.iter().map(|g| g * g).sum::<f64>().sqrt();
        if !(norm > 0.0 && norm.is_finite()) {
            return None;
        }
        Some(
            x.iter()
                .zip(grad)
                .map(|(x, g)| (x - self.radius * g / norm).clamp(-1.0, 1.0))
                .collect(),
        )
    }

    /// Judges a trial: accepted if its loss is below the incumbent's. Grows the radius on
    /// acceptance, shrinks it otherwise; returns whether the step was accepted.
    pub fn judge(&mut self, incumbent: f64, trial: f64, initial: f64) -> bool {
        let accept = trial < incumbent;
        self.radius = if accept {
            (self.radius * Self::GROW).min(Self::MAX)
        } else {
            self.radius * Self::SHRINK
        };
        if self.radius < Self::MIN {
            self.radius = initial;
        }
        accept
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_trust_region_accepts_a_decrease_and_grows() {
        let mut tr = TrustRegion { radius: 0.1 };
        assert!(tr.judge(2.0, 1.5, 0.1));
        assert!((tr.radius - 0.15).abs() < 1e-15);
        // Never past the largest radius.
        for _ in 0..10 {
            tr.judge(2.0, 1.0, 0.1);
        }
        assert_eq!(tr.radius, TrustRegion::MAX);
    }

    #[test]
    fn the_trust_region_rejects_an_increase_or_a_tie_and_shrinks() {
        let mut tr = TrustRegion { radius: 0.1 };
        assert!(!tr.judge(1.0, 1.2, 0.1));
        assert!((tr.radius - 0.05).abs() < 1e-15);
        assert!(!tr.judge(1.0, 1.0, 0.1), "a tie is no progress");
        assert!((tr.radius - 0.025).abs() < 1e-15);
        // Shrunk below the smallest radius, it restarts at the initial one.
        let mut tiny = TrustRegion { radius: 1.5e-3 };
        assert!(!tiny.judge(1.0, 3.0, 0.1));
        assert_eq!(tiny.radius, 0.1);
    }

    #[test]
    fn a_trial_steps_the_radius_downhill_and_stays_in_the_box() {
        let tr = TrustRegion { radius: 0.2 };
        let t = tr
            .propose(Theta([0.0; 5]), [3.0, 4.0, 0.0, 0.0, 0.0])
            .unwrap();
        assert!((t[0] + 0.12).abs() < 1e-15 && (t[1] + 0.16).abs() < 1e-15);
        let step = t.iter().map(|x| x * x).sum::<f64>().sqrt();
        assert!((step - 0.2).abs() < 1e-15);
        // At the box's edge the step is clamped.
        let edge = tr
            .propose(Theta([-1.0, 0.0, 0.0, 0.0, 0.0]), [1.0, 0.0, 0.0, 0.0, 0.0])
            .unwrap();
        assert_eq!(edge[0], -1.0);
        assert!(tr.propose(Theta([0.0; 5]), [0.0; 5]).is_none());
        assert!(tr.propose(Theta([0.0; 5]), [f64::NAN; 5]).is_none());
    }
}
