//! The fine-tune: REINFORCE (Williams 1992) with a baseline, seed B's last step.
//!
//! The policy is a Gaussian of fixed spread σ around the network's outputs (the dosing policy's
//! one output is the knob of [`super::knob`]). Each iteration draws half a batch of contexts
//! (scenes) and, for each, a mirrored pair of episodes `a± = μ(f) ± σε` (clamped into [−1, 1]
//! when run), with rewards `R±`. Each episode's baseline is its partner's reward,
//! `A± = ±(R₊ − R₋)/2`: the scenes of a batch differ in how hard they are far more than two
//! actions on one scene differ, so a baseline taken across scenes (the batch mean) buries the
//! action's effect under the scene's. Mirrored sampling keeps the estimate unbiased: summed over
//! a pair, `A₊∇log p(a₊) + A₋∇log p(a₋) = (R₊ − R₋) ε/σ`, the central-difference estimate of
//! the gradient of the Gaussian-smoothed reward (seed B's eq. 6; Salimans et al. 2017). The
//! advantages are divided by their spread over the batch. One AdamW step descends
//! `−mean(A · log N(a; μ(f), σ²))`.
//!
//! `reward(iteration, slot, context, action)` is the caller's: a rollout's −L, or a toy's. A
//! caller that keeps each (iteration, slot)'s reward can replay a killed run exactly, since the
//! draws follow the seed alone.

use super::net::Policy;
use crate::util::SplitMix64;
use candle_core::{Device, Tensor};
use candle_nn::{AdamW, Optimizer, ParamsAdamW};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// The fine-tune's settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReinforceConfig {
    pub iterations: usize,
    /// Episodes (rollouts) per iteration: `batch / 2` scenes, a mirrored pair on each.
    pub batch: usize,
    /// The Gaussian's standard deviation, in the outputs' units.
    pub sigma: f64,
    pub lr: f64,
    pub seed: u64,
}

/// The default iterations: with [`BATCH`], 384 episodes.
pub const ITERATIONS: usize = 24;
/// The default episodes per iteration (8 scenes, a mirrored pair on each).
pub const BATCH: usize = 16;
/// The default spread, in the knob's units: about 0.17 g of dose on the dosing scene's family,
/// the size of the distilled policy's error.
pub const SIGMA: f64 = 0.1;
/// The default AdamW step. The fine-tune's first settings (12 iterations of 8 episodes at
/// 1e-3) moved the policy's depth by +0.034 on every held-out scene alike, and a handful of
/// pairs carried half of that signal; these take the same total step (24 × 5e-4) with four
/// times the episodes behind it.
pub const LR: f64 = 5e-4;

impl Default for ReinforceConfig {
    fn default() -> Self {
        Self {
            iterations: ITERATIONS,
            batch: BATCH,
            sigma: SIGMA,
            lr: LR,
            seed: 0,
        }
    }
}

/// One iteration's batch.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Iteration {
    pub iteration: usize,
    pub mean_reward: f64,
    pub rewards: Vec<f64>,
    pub contexts: Vec<usize>,
}

/// An episode's reward: `reward(iteration, slot, context, action)`.
pub type Reward<'a> = dyn Fn(usize, usize, usize, &[f64]) -> anyhow::Result<f64> + Sync + 'a;

/// Fine-tunes `policy` in place on `contexts` (feature rows); `on_iteration` hears of each
/// batch.
pub fn finetune(
    policy: &Policy,
    contexts: &[Vec<f64>],
    cfg: &ReinforceConfig,
    reward: &Reward<'_>,
    on_iteration: &mut dyn FnMut(&Iteration),
) -> anyhow::Result<Vec<Iteration>> {
    anyhow::ensure!(!contexts.is_empty(), "no contexts to fine-tune on");
    anyhow::ensure!(
        cfg.batch >= 2 && cfg.batch.is_multiple_of(2),
        "an even batch of at least 2 (the episodes come in mirrored pairs), not {}",
        cfg.batch
    );
    anyhow::ensure!(cfg.sigma > 0.0, "sigma must be positive");
    let mut opt = AdamW::new(
        policy.vars(),
        ParamsAdamW {
            lr: cfg.lr,
            weight_decay: 0.0,
            ..Default::default()
        },
    )?;
    let mut rng = SplitMix64(cfg.seed);
    let mut out = Vec::new();
    for it in 0..cfg.iterations {
        let picks: Vec<usize> = (0..cfg.batch / 2)
            .map(|_| (rng.next_u64() % contexts.len() as u64) as usize)
            .flat_map(|c| [c, c])
            .collect();
        let rows: Vec<Vec<f64>> = picks.iter().map(|&c| contexts[c].clone()).collect();
        let x = policy.inputs(&rows)?;
        let mu = policy.forward(&x)?;
        let mu_v = mu.to_vec2::<f64>()?;
        let n = policy.outputs;
        let mut actions: Vec<Vec<f64>> = Vec::with_capacity(cfg.batch);
        for pair in mu_v.chunks(2) {
            let eps: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
            let m = &pair[0];
            actions.push((0..n).map(|d| m[d] + cfg.sigma * eps[d]).collect());
            actions.push((0..n).map(|d| m[d] - cfg.sigma * eps[d]).collect());
        }
        let rewards: Vec<f64> = actions
            .par_iter()
            .enumerate()
            .map(|(slot, a)| {
                let clamped: Vec<f64> = a.iter().map(|v| v.clamp(-1.0, 1.0)).collect();
                reward(it, slot, picks[slot], &clamped)
            })
            .collect::<anyhow::Result<_>>()?;
        let adv = advantages(&rewards);
        let a = Tensor::from_vec(
            actions.iter().flatten().copied().collect::<Vec<f64>>(),
            (cfg.batch, n),
            &Device::Cpu,
        )?;
        let adv_t = Tensor::from_vec(adv, cfg.batch, &Device::Cpu)?;
        // log N(a; μ, σ²) up to a constant: −|a − μ|²/(2σ²).
        let logp = ((a - &mu)? / cfg.sigma)?.sqr()?.sum(1)?.affine(-0.5, 0.0)?;
        let loss = (logp * adv_t)?.mean_all()?.neg()?;
        opt.backward_step(&loss)?;
        let rec = Iteration {
            iteration: it,
            mean_reward: rewards.iter().sum::<f64>() / rewards.len() as f64,
            rewards,
            contexts: picks,
        };
        on_iteration(&rec);
        out.push(rec);
    }
    Ok(out)
}

/// The mirrored pairs' advantages `±(R₊ − R₋)/2` (`r` in pairs, `+` first), divided by their
/// spread over the batch (left alone when every pair ties).
pub fn advantages(r: &[f64]) -> Vec<f64> {
    let a: Vec<f64> = r
        .chunks(2)
        .flat_map(|p| {
            let d = 0.5 * (p[0] - p[1]);
            [d, -d]
        })
        .collect();
    let sd = (a.iter().map(|v| v * v).sum::<f64>() / a.len().max(1) as f64).sqrt();
    let scale = if sd > 0.0 { sd } else { 1.0 };
    a.iter().map(|v| v / scale).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pair_is_its_own_baseline() {
        // The second scene is far harder than the first; only the difference within a pair
        // counts, so the better action of each pair gets the same positive advantage.
        let a = advantages(&[1.0, 0.0, -10.0, -11.0]);
        assert_eq!(a, vec![1.0, -1.0, 1.0, -1.0]);
        assert_eq!(advantages(&[3.0, 3.0]), vec![0.0, 0.0]);
    }
}
