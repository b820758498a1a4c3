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
//!
//! Optionally (`normalize`, off by default: the paper's method is the default) the gradient of
//! the parameters allowed to move is scaled to unit length before it enters the running mean
//! square. On the transport scene single rollouts return gradients hundreds of times the usual
//! size (contacts in a chaotic pour; measured in `docs/results/skill_optimisation.md`), and one such spike holds `s` up
//! for tens of epochs (it decays by β = 0.9 per epoch), shrinking every later step to almost
//! nothing. A unit gradient keeps the direction and lets no single rollout set the step size.
//!
//! Or (`clip_median`, also off by default) a gradient longer than the median length of the
//! seed's gradients so far, its own included, is scaled down to that median: a robust cap with
//! no constant to tune, which keeps a spike's direction, keeps small gradients small (unlike
//! `normalize`) and keeps `s` at the usual scale. Neither beats the paper's method on the
//! transport scene (measured in `docs/results/skill_optimisation.md`); the driver rebuilds the seed's history of lengths
//! from the journal on `--resume`, so a resumed run takes the same steps.

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
    /// Scale the moving parameters' gradient to unit length first. Default false.
    #[serde(default)]
    pub normalize: bool,
    /// Clip the moving parameters' gradient to the median length of this seed's gradients so
    /// far (this one included) first. Default false.
    #[serde(default)]
    pub clip_median: bool,
}

impl Default for RmsProp {
    fn default() -> Self {
        Self {
            lr: 0.05,
            beta: 0.9,
            eps: 1e-8,
            switch_epoch: 15,
            normalize: false,
            clip_median: false,
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
    pub theta: Theta,
    pub mean_square: [f64; 5],
}

/// The length of `g` over the components `mask` lets move.
pub fn masked_norm(g: &[f64; 5], mask: [bool; 5]) -> f64 {
    (0..5)
        .filter(|&k| mask[k])
        .map(|k| g[k] * g[k])
        .sum::<f64>()
        .sqrt()
}

use crate::lab::stats::median;
use crate::skills::Theta;

impl RmsProp {
    /// With `clip_median`, `g` scaled down to the median of `history` (the lengths of this
    /// seed's earlier gradients over the parameters moving now) and its own length, if longer;
    /// `history` gains its length. Without, `g` as it is.
    pub fn clip(&self, g: [f64; 5], epoch: usize, history: &mut Vec<f64>) -> [f64; 5] {
        if !self.clip_median {
            return g;
        }
        let norm = masked_norm(&g, curriculum_mask(epoch, self.switch_epoch));
        history.push(norm);
        let cap = median(history);
        if norm > cap && norm > 0.0 {
            g.map(|x| x * cap / norm)
        } else {
            g
        }
    }

    /// One step at `epoch` (1-based) with gradient `g`.
    pub fn step(&self, state: &mut RmsState, mut g: [f64; 5], epoch: usize) {
        let mask = curriculum_mask(epoch, self.switch_epoch);
        if self.normalize {
            let norm = masked_norm(&g, mask);
            if norm > 0.0 {
                g = g.map(|x| x / norm);
            }
        }
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
            theta: Theta([0.1, -0.2, 0.3, 0.4, -0.5]),
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
            theta: Theta([0.0; 5]),
            mean_square: [0.0; 5],
        };
        opt.step(&mut st, [1.0; 5], 15);
        assert_eq!(st.theta[3..], [0.0, 0.0]);
        assert!(st.theta[..3].iter().all(|t| *t < 0.0));
    }

    /// Round-off of a few operations on O(0.1) values (`1 − β` is not exactly 0.1).
    const ROUND_OFF: f64 = 1e-15;
    /// What ε = 1e-8 in the denominator changes a step of ≤ 0.1 over √s ≥ 0.3 by, with room.
    const EPS_EFFECT: f64 = 1e-8;

    /// With `normalize`, a gradient and the same gradient times 1000 give the same steps, and
    /// the frozen components do not count in the length.
    #[test]
    fn normalized_steps_do_not_depend_on_the_gradient_size() {
        let opt = RmsProp {
            normalize: true,
            ..Default::default()
        };
        let start = RmsState {
            theta: Theta([0.1, -0.2, 0.3, 0.4, -0.5]),
            mean_square: [0.0; 5],
        };
        let g = [3.0, -4.0, 0.0, 50.0, 50.0];
        let (mut a, mut b) = (start, start);
        opt.step(&mut a, g, 1);
        opt.step(&mut b, g.map(|x| x * 1000.0), 1);
        assert_eq!(a, b);
        // Unit length over θ_d, θ_s, θ_l: (0.6, −0.8, 0), so s = 0.1·(0.36, 0.64, 0).
        for (got, want) in a.mean_square.iter().zip([0.036, 0.064, 0.0]) {
            assert!((got - want).abs() < ROUND_OFF, "{got} vs {want}");
        }
        assert_eq!(a.theta[3..], start.theta[3..]);
        // A spike of 500 in θ_d, then a unit gradient: the paper's RMSprop then moves θ_d by
        // lr/√(0.9·0.1·500² + 0.1) ≈ 3.3e-4, the normalised one by
        // lr·(1/√3)/√(0.9·0.1 + 0.1/3) ≈ 0.082.
        let spike = [500.0, 0.0, 0.0, 0.0, 0.0];
        let second_move = |opt: &RmsProp| {
            let mut st = start;
            opt.step(&mut st, spike, 1);
            let after_spike = st.theta[0];
            opt.step(&mut st, [1.0; 5], 2);
            (st.theta[0] - after_spike).abs()
        };
        let plain = second_move(&RmsProp::default());
        let unit = second_move(&opt);
        let want = 0.05 / (0.09f64 * 250_000.0 + 0.1).sqrt();
        assert!((plain - want).abs() < EPS_EFFECT, "{plain} vs {want}");
        let want = 0.05 / 3f64.sqrt() / (0.09f64 + 0.1 / 3.0).sqrt();
        assert!((unit - want).abs() < EPS_EFFECT, "{unit} vs {want}");
    }

    /// With `clip_median`, a gradient longer than the median of the seed's lengths so far is
    /// scaled down to it (over the moving parameters), a shorter one passes as it is, and with
    /// the option off nothing is clipped or kept.
    #[test]
    fn median_clipping_caps_a_spike_at_the_median_length() {
        let opt = RmsProp {
            clip_median: true,
            ..Default::default()
        };
        assert_eq!(median(&[]), 0.0);
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 3.0, 2.0]), 2.5);
        let mut h = Vec::new();
        // The first gradient is its own median. θ_t and θ_p are frozen and do not count.
        let g = opt.clip([3.0, 4.0, 0.0, 100.0, 100.0], 1, &mut h);
        assert_eq!(g, [3.0, 4.0, 0.0, 100.0, 100.0]);
        assert_eq!(h, [5.0]);
        // A spike of length 500: the median of (5, 500) is 252.5.
        let g = opt.clip([0.0, 500.0, 0.0, 0.0, 0.0], 2, &mut h);
        assert!((g[1] - 252.5).abs() < ROUND_OFF * 252.5, "{}", g[1]);
        // Then 1 (median of 5, 500, 1: 5, so it passes) and 20 (median of 1, 5, 20, 500: 12.5).
        let g = opt.clip([1.0, 0.0, 0.0, 0.0, 0.0], 3, &mut h);
        assert_eq!(g, [1.0, 0.0, 0.0, 0.0, 0.0]);
        let g = opt.clip([0.0, 0.0, 20.0, 0.0, 0.0], 4, &mut h);
        assert!((g[2] - 12.5).abs() < ROUND_OFF * 12.5, "{}", g[2]);
        // After the curriculum's switch the length is over all five.
        let mut h = vec![1.0];
        let g = opt.clip([0.0, 0.0, 0.0, 3.0, 4.0], 16, &mut h);
        assert_eq!(h, [1.0, 5.0]);
        assert!((g[3] - 1.8).abs() < ROUND_OFF && (g[4] - 2.4).abs() < ROUND_OFF);
        // Off (the paper's method): untouched, and no history kept.
        let mut h = Vec::new();
        let g = RmsProp::default().clip([0.0, 500.0, 0.0, 0.0, 0.0], 2, &mut h);
        assert_eq!(g[1], 500.0);
        assert!(h.is_empty());
    }

    #[test]
    fn theta_is_projected_back_to_the_box() {
        let opt = RmsProp {
            lr: 10.0,
            ..Default::default()
        };
        let mut st = RmsState {
            theta: Theta([0.9, -0.9, 0.0, 0.0, 0.0]),
            mean_square: [0.0; 5],
        };
        opt.step(&mut st, [-1.0, 1.0, 0.0, 0.0, 0.0], 20);
        assert_eq!(st.theta[0], 1.0);
        assert_eq!(st.theta[1], -1.0);
        assert_eq!(st.theta[2], 0.0, "a zero gradient does not move θ");
    }
}
