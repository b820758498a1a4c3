//! RMSprop with the paper's curriculum and the projection back to the box.
//!
//! ```text
//! s_k ← β·s_k + (1 − β)·g_k²,    θ_k ← clamp(θ_k − lr·g_k/(√s_k + ε), −1, 1)
//! ```
//!
//! for the parameters the curriculum lets move; a frozen parameter keeps both `θ_k` and its
//! running mean square `s_k` (it has not been seen, so it neither decays nor grows). Epochs
//! 1 … `switch_epoch` update only θ_d, θ_s, θ_l (the scoop: depth, angle, lift); later epochs
//! update all five.

use serde::{Deserialize, Serialize};

/// Settings (the paper's values are the defaults).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RmsProp {
    /// Learning rate. Default 0.05.
    pub lr: f64,
    /// Decay of the running mean square. Default 0.9.
    pub beta: f64,
    /// Added to `√s` in the denominator. Default 1e-8.
    pub eps: f64,
    /// Last epoch (1-based) of the scoop-only phase of the curriculum. Default 15.
    pub switch_epoch: usize,
}

impl Default for RmsProp {
    fn default() -> Self {
        Self {
            lr: 0.05,
            beta: 0.9,
            eps: 1e-8,
            switch_epoch: 15,
        }
    }
}

/// Which of Θ = (θ_d, θ_s, θ_l, θ_t, θ_p) may move in `epoch` (1-based).
pub fn curriculum_mask(epoch: usize, switch_epoch: usize) -> [bool; 5] {
    if epoch <= switch_epoch {
        [true, true, true, false, false]
    } else {
        [true; 5]
    }
}

/// The optimiser's state: Θ and the running mean squares.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RmsState {
    pub theta: [f64; 5],
    pub mean_square: [f64; 5],
}

impl RmsProp {
    /// One step at `epoch` (1-based) with gradient `g`.
    pub fn step(&self, state: &mut RmsState, g: [f64; 5], epoch: usize) {
        let mask = curriculum_mask(epoch, self.switch_epoch);
        for k in 0..5 {
            if !mask[k] {
                continue;
            }
            let s = &mut state.mean_square[k];
            *s = self.beta * *s + (1.0 - self.beta) * g[k] * g[k];
            state.theta[k] =
                (state.theta[k] - self.lr * g[k] / (s.sqrt() + self.eps)).clamp(-1.0, 1.0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Hand computation: with `s₀ = 0`, the first step is `θ − lr·g/(√(0.1·g²) + ε)`
    /// `= θ − lr·sign(g)/√0.1` (to ε), the second uses `s₁ = 0.9·0.1·g₀² + 0.1·g₁²`.
    #[test]
    fn steps_match_a_hand_computation() {
        let opt = RmsProp::default();
        let mut st = RmsState {
            theta: [0.1, -0.2, 0.3, 0.4, -0.5],
            mean_square: [0.0; 5],
        };
        let g0 = [2.0, -0.5, 1e-3, 7.0, 7.0];
        opt.step(&mut st, g0, 1);
        // 0.05/√0.1 = 0.158113883…
        let d = 0.05 / 0.1f64.sqrt();
        let expect = [0.1 - d, -0.2 + d, 0.3 - d, 0.4, -0.5];
        for (k, (got, want)) in st.theta.iter().zip(expect).enumerate() {
            // ε = 1e-8 against √s ≥ 3e-4 changes the step by < 1e-4 relative.
            assert!((got - want).abs() < 1e-4 * d, "θ[{k}] {got}");
        }
        assert_eq!(st.mean_square[3], 0.0, "a frozen parameter keeps s");
        let g1 = [1.0, 1.0, 1.0, 1.0, 1.0];
        let before = st;
        opt.step(&mut st, g1, 16);
        for k in 0..5 {
            let s = 0.9 * before.mean_square[k] + (1.0 - 0.9) * 1.0;
            assert_eq!(st.mean_square[k], s);
            let th = (before.theta[k] - 0.05 / (s.sqrt() + 1e-8)).clamp(-1.0, 1.0);
            assert_eq!(st.theta[k], th, "θ[{k}]");
        }
    }

    #[test]
    fn curriculum_freezes_transport_and_pour_until_the_switch() {
        for e in 1..=15 {
            assert_eq!(curriculum_mask(e, 15), [true, true, true, false, false]);
        }
        for e in 16..=30 {
            assert_eq!(curriculum_mask(e, 15), [true; 5]);
        }
        let opt = RmsProp::default();
        let mut st = RmsState {
            theta: [0.0; 5],
            mean_square: [0.0; 5],
        };
        opt.step(&mut st, [1.0; 5], 15);
        assert_eq!(st.theta[3..], [0.0, 0.0]);
        assert!(st.theta[..3].iter().all(|t| *t < 0.0));
    }

    #[test]
    fn theta_is_projected_back_to_the_box() {
        let opt = RmsProp {
            lr: 10.0,
            ..Default::default()
        };
        let mut st = RmsState {
            theta: [0.9, -0.9, 0.0, 0.0, 0.0],
            mean_square: [0.0; 5],
        };
        opt.step(&mut st, [-1.0, 1.0, 0.0, 0.0, 0.0], 20);
        assert_eq!(st.theta[0], 1.0);
        assert_eq!(st.theta[1], -1.0);
        assert_eq!(st.theta[2], 0.0, "a zero gradient does not move θ");
    }
}
