//! The fine-tune: REINFORCE (Williams 1992) with a baseline, seed B's last step.
//!
//! The policy is a Gaussian of fixed spread σ around the network's Θ. Each iteration draws a
//! batch of contexts (scenes), samples `a = μ(f) + σε` for each, runs it (clamped into the box)
//! and gets its reward `R`. The baseline of each sample is the mean reward of the *other*
//! samples of its batch (leave-one-out, so the estimate stays unbiased), and the advantages are
//! divided by the batch's reward spread. One AdamW step descends
//! `−mean(A · log N(a; μ(f), σ²))`.
//!
//! `reward(iteration, slot, context, Θ)` is the caller's: a rollout's −L, or a toy's. A caller
//! that keeps each (iteration, slot)'s reward can replay a killed run exactly, since the draws
//! follow the seed alone.

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
    /// Episodes (rollouts) per iteration.
    pub batch: usize,
    /// The Gaussian's standard deviation in Θ.
    pub sigma: f64,
    pub lr: f64,
    pub seed: u64,
}

impl Default for ReinforceConfig {
    fn default() -> Self {
        Self {
            iterations: 12,
            batch: 8,
            sigma: 0.1,
            lr: 1e-3,
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

/// Fine-tunes `policy` in place on `contexts` (feature rows); `on_iteration` hears of each
/// batch.
pub fn finetune(
    policy: &Policy,
    contexts: &[Vec<f64>],
    cfg: &ReinforceConfig,
    reward: &(dyn Fn(usize, usize, usize, [f64; 5]) -> anyhow::Result<f64> + Sync),
    on_iteration: &mut dyn FnMut(&Iteration),
) -> anyhow::Result<Vec<Iteration>> {
    anyhow::ensure!(!contexts.is_empty(), "no contexts to fine-tune on");
    anyhow::ensure!(
        cfg.batch >= 2,
        "a batch of at least 2 (the baseline is the others' mean)"
    );
    anyhow::ensure!(cfg.sigma > 0.0, "sigma must be positive");
    let mut opt = AdamW::new(
        policy.mlp.vars(),
        ParamsAdamW {
            lr: cfg.lr,
            weight_decay: 0.0,
            ..Default::default()
        },
    )?;
    let mut rng = SplitMix64(cfg.seed);
    let mut out = Vec::new();
    for it in 0..cfg.iterations {
        let picks: Vec<usize> = (0..cfg.batch)
            .map(|_| (rng.next_u64() % contexts.len() as u64) as usize)
            .collect();
        let rows: Vec<Vec<f64>> = picks.iter().map(|&c| contexts[c].clone()).collect();
        let x = policy.inputs(&rows)?;
        let mu = policy.forward(&x)?;
        let mu_v = mu.to_vec2::<f64>()?;
        let actions: Vec<[f64; 5]> = mu_v
            .iter()
            .map(|m| std::array::from_fn(|d| m[d] + cfg.sigma * rng.normal()))
            .collect();
        let rewards: Vec<f64> = actions
            .par_iter()
            .enumerate()
            .map(|(slot, a)| {
                let theta = a.map(|v| v.clamp(-1.0, 1.0));
                reward(it, slot, picks[slot], theta)
            })
            .collect::<anyhow::Result<_>>()?;
        let adv = advantages(&rewards);
        let a = Tensor::from_vec(
            actions.iter().flatten().copied().collect::<Vec<f64>>(),
            (cfg.batch, 5),
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

/// `R − b` with the leave-one-out baseline `b`, divided by the rewards' spread (left alone when
/// they are all equal).
pub fn advantages(r: &[f64]) -> Vec<f64> {
    let n = r.len() as f64;
    let sum: f64 = r.iter().sum();
    let mean = sum / n;
    let sd = (r.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
    let scale = if sd > 0.0 { sd } else { 1.0 };
    r.iter()
        .map(|v| (v - (sum - v) / (n - 1.0)) / scale)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn leave_one_out_advantages_sum_to_zero_and_order_the_rewards() {
        let a = advantages(&[1.0, 2.0, 4.0]);
        assert!(a.iter().sum::<f64>().abs() < 1e-12);
        assert!(a[0] < a[1] && a[1] < a[2]);
        assert_eq!(advantages(&[3.0, 3.0]), vec![0.0, 0.0]);
    }
}
