//! Soft actor-critic (Haarnoja et al. 2018) over the skill parameters, the reinforcement-learning
//! baseline of the paper: the action is Θ through a tanh-squashed Gaussian policy, each episode
//! is one rollout, and the reward is `−L`.
//!
//! Networks (candle, f64, CPU): the actor maps the observation to the mean and log-std of a
//! Gaussian over `u ∈ Rᵈ` (d = 5 for the skill, 6·knots for a refined trajectory), `Θ = tanh(u)`; two critics `Q₁, Q₂(s, Θ)`; two hidden layers of
//! [`SacConfig::hidden`] ReLU units each. Adam (no weight decay) with the paper's learning rates
//! (1e-3 for actor, critics and the entropy temperature α, which is tuned automatically towards
//! the target entropy `−dim Θ`). Minibatches of 8 transitions are drawn from the replay
//! buffer of all rollouts so far.
//!
//! What the one-rollout episodes imply, and how it is handled:
//! - The task has no state that changes between episodes: the observation is the constant 1.
//! - Every transition is terminal, so the critic's target is `y = r`; the discount γ = 0.99 and
//!   target networks multiply `(1 − done) = 0` and play no role (they are left out).
//! - The reward is the loss standardised over the replay buffer, `−(L − mean)/std`. A skill's
//!   rollouts differ by a few percent of the loss (434–457 on the transport scene), so a fixed
//!   scale such as `−L/L₀` leaves reward differences of a few hundredths against an entropy
//!   term of order α·dim Θ with α starting at 1: the policy follows the entropy, not the task.
//!   Standardised, the critics see the differences at O(1); which Θ is best does not change.
//!   [`Sac::stats`] gives α and the buffer's mean and std, which `optimize` logs to `sac.csv`.
//! - The first rollout is Θ_init itself (the start every method shares), the next ones sample the
//!   initial policy, which is centred on Θ_init with a standard deviation of
//!   [`SacConfig::init_std`] in `u`.
//!
//! Determinism: the weights are initialised and every noise sample is drawn from a seeded
//! [`SplitMix64`], and the networks are small enough that candle's matrix products run on one
//! thread, so a seed fixes the run.

use super::mlp::Mlp;
use crate::util::SplitMix64;
use candle_core::{DType, Device, Result, Tensor, Var};
use candle_nn::{AdamW, Optimizer, ParamsAdamW};

/// SAC settings (the paper's values are the defaults where it gives them).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SacConfig {
    /// Discount γ (recorded; with one-rollout episodes it has no effect). Default 0.99.
    pub gamma: f64,
    /// Minibatch size. Default 8.
    pub batch: usize,
    /// Actor learning rate. Default 1e-3.
    pub actor_lr: f64,
    /// Critic learning rate. Default 1e-3.
    pub critic_lr: f64,
    /// Temperature learning rate. Default 1e-3.
    pub alpha_lr: f64,
    /// Hidden units per layer. Default 64.
    pub hidden: usize,
    /// Gradient steps after each rollout, once the buffer holds a minibatch. Default 20.
    pub updates_per_rollout: usize,
    /// Initial standard deviation of the policy in `u` (pre-tanh). Default 0.5.
    pub init_std: f64,
}

impl Default for SacConfig {
    fn default() -> Self {
        Self {
            gamma: 0.99,
            batch: 8,
            actor_lr: 1e-3,
            critic_lr: 1e-3,
            alpha_lr: 1e-3,
            hidden: 64,
            updates_per_rollout: 20,
            init_std: 0.5,
        }
    }
}

const LOG_STD_MIN: f64 = -5.0;
const LOG_STD_MAX: f64 = 1.0;
/// `ln(1 − tanh²u + SQUASH_EPS)`: keeps the squashing correction finite at `|Θ| → 1`.
const SQUASH_EPS: f64 = 1e-6;

/// One SAC agent (one seed).
pub struct Sac {
    cfg: SacConfig,
    dev: Device,
    actor: Mlp,
    q1: Mlp,
    q2: Mlp,
    log_alpha: Var,
    opt_actor: AdamW,
    opt_q: AdamW,
    opt_alpha: AdamW,
    /// (Θ, loss) of every rollout so far.
    buffer: Vec<(Vec<f64>, f64)>,
    rng: SplitMix64,
    theta_init: Vec<f64>,
}

fn adam(vars: Vec<Var>, lr: f64) -> Result<AdamW> {
    AdamW::new(
        vars,
        ParamsAdamW {
            lr,
            weight_decay: 0.0,
            ..Default::default()
        },
    )
}

impl Sac {
    /// An agent over `Θ ∈ (−1, 1)ᵈ`, d = `theta_init.len()`, whose first action is `theta_init`.
    pub fn new(cfg: SacConfig, theta_init: &[f64], seed: u64) -> Result<Sac> {
        let dim = theta_init.len();
        let dev = Device::Cpu;
        let mut rng = SplitMix64(seed);
        let h = cfg.hidden;
        let actor = Mlp::new(&[1, h, h, 2 * dim], &mut rng, &dev)?;
        // Centre the initial policy on Θ_init: small output weights, and output biases giving
        // mean atanh(Θ_init) and log-std ln(init_std).
        {
            let (w, b) = actor.layers.last().expect("three layers");
            w.set(&(w.as_tensor() * 1e-3)?)?;
            let mut bias: Vec<f64> = theta_init
                .iter()
                .map(|t| t.clamp(-0.95, 0.95).atanh())
                .collect();
            bias.extend(std::iter::repeat_n(cfg.init_std.ln(), dim));
            b.set(&Tensor::from_vec(bias, 2 * dim, &dev)?)?;
        }
        let q1 = Mlp::new(&[1 + dim, h, h, 1], &mut rng, &dev)?;
        let q2 = Mlp::new(&[1 + dim, h, h, 1], &mut rng, &dev)?;
        let log_alpha = Var::from_tensor(&Tensor::zeros(1, DType::F64, &dev)?)?;
        let opt_actor = adam(actor.vars(), cfg.actor_lr)?;
        let mut qv = q1.vars();
        qv.extend(q2.vars());
        let opt_q = adam(qv, cfg.critic_lr)?;
        let opt_alpha = adam(vec![log_alpha.clone()], cfg.alpha_lr)?;
        Ok(Sac {
            cfg,
            dev,
            actor,
            q1,
            q2,
            log_alpha,
            opt_actor,
            opt_q,
            opt_alpha,
            buffer: Vec::new(),
            rng,
            theta_init: theta_init.to_vec(),
        })
    }

    /// d, the dimension of Θ.
    fn dim(&self) -> usize {
        self.theta_init.len()
    }

    /// Mean and clamped log-std of the policy at observations `s` (`[n, 1]`).
    fn policy(&self, s: &Tensor) -> Result<(Tensor, Tensor)> {
        let out = self.actor.forward(s)?;
        let d = self.dim();
        let mu = out.narrow(1, 0, d)?;
        let ls = out.narrow(1, d, d)?.clamp(LOG_STD_MIN, LOG_STD_MAX)?;
        Ok((mu, ls))
    }

    fn normals(&mut self, n: usize) -> Vec<f64> {
        (0..n).map(|_| self.rng.normal()).collect()
    }

    /// The Θ of the next rollout: Θ_init for the first, a policy sample after that.
    pub fn act(&mut self) -> Result<Vec<f64>> {
        if self.buffer.is_empty() {
            return Ok(self.theta_init.clone());
        }
        let d = self.dim();
        let s = Tensor::ones((1, 1), DType::F64, &self.dev)?;
        let (mu, ls) = self.policy(&s)?;
        let eps = Tensor::from_vec(self.normals(d), (1, d), &self.dev)?;
        let a = (mu + (ls.exp()? * eps)?)?.tanh()?;
        a.flatten_all()?.to_vec1::<f64>()
    }

    /// Adds a finished rollout and trains on the buffer.
    pub fn observe(&mut self, theta: &[f64], loss: f64) -> Result<()> {
        self.buffer.push((theta.to_vec(), loss));
        if self.buffer.len() >= self.cfg.batch {
            for _ in 0..self.cfg.updates_per_rollout {
                self.update()?;
            }
        }
        Ok(())
    }

    /// One gradient step of the critics, the actor and the temperature.
    fn update(&mut self) -> Result<()> {
        let (b, d) = (self.cfg.batch, self.dim());
        let (mean, std) = self.loss_stats();
        let idx: Vec<usize> = (0..b).map(|_| self.rng.index(self.buffer.len())).collect();
        let a: Vec<f64> = idx
            .iter()
            .flat_map(|&i| self.buffer[i].0.iter().copied())
            .collect();
        let r: Vec<f64> = idx
            .iter()
            .map(|&i| -(self.buffer[i].1 - mean) / std)
            .collect();
        let a = Tensor::from_vec(a, (b, d), &self.dev)?;
        let y = Tensor::from_vec(r, (b, 1), &self.dev)?;
        let s = Tensor::ones((b, 1), DType::F64, &self.dev)?;

        // Critics: every transition is terminal, so the target is the reward.
        let sa = Tensor::cat(&[&s, &a], 1)?;
        let l1 = (self.q1.forward(&sa)? - &y)?.sqr()?.mean_all()?;
        let l2 = (self.q2.forward(&sa)? - &y)?.sqr()?.mean_all()?;
        self.opt_q.backward_step(&(l1 + l2)?)?;

        // Actor: minimise E[α·log π(Θ) − min(Q₁, Q₂)(Θ)] with the reparameterised sample.
        let eps = Tensor::from_vec(self.normals(b * d), (b, d), &self.dev)?;
        let (mu, ls) = self.policy(&s)?;
        let theta = (mu + (ls.exp()? * &eps)?)?.tanh()?;
        let gauss = (eps.sqr()?.affine(-0.5, -0.5 * std::f64::consts::TAU.ln())? - &ls)?;
        let squash = theta.sqr()?.affine(-1.0, 1.0 + SQUASH_EPS)?.log()?;
        let log_pi = (gauss.sum_keepdim(1)? - squash.sum_keepdim(1)?)?;
        let sa_new = Tensor::cat(&[&s, &theta], 1)?;
        let q = self
            .q1
            .forward(&sa_new)?
            .minimum(&self.q2.forward(&sa_new)?)?;
        let alpha = self.log_alpha.as_tensor().exp()?.detach();
        let actor_loss = (log_pi.broadcast_mul(&alpha)? - q)?.mean_all()?;
        self.opt_actor.backward_step(&actor_loss)?;

        // Temperature: minimise −log α·(log π + target entropy).
        // The target entropy is −dim Θ.
        let target = log_pi.detach().affine(1.0, -(d as f64))?;
        let alpha_loss = (target
            .broadcast_mul(self.log_alpha.as_tensor())?
            .mean_all()?
            * -1.0)?;
        self.opt_alpha.backward_step(&alpha_loss)?;
        Ok(())
    }

    /// Mean and standard deviation of the losses in the buffer; the deviation is floored at
    /// 1e-12 of the mean's size, so equal losses give rewards of 0 rather than NaN.
    fn loss_stats(&self) -> (f64, f64) {
        let n = self.buffer.len().max(1) as f64;
        let mean = self.buffer.iter().map(|e| e.1).sum::<f64>() / n;
        let var = self
            .buffer
            .iter()
            .map(|e| (e.1 - mean) * (e.1 - mean))
            .sum::<f64>()
            / n;
        (mean, var.sqrt().max(1e-12 * mean.abs().max(1.0)))
    }

    /// The temperature α and the mean and standard deviation of the losses the rewards are
    /// standardised with.
    pub fn stats(&self) -> Result<(f64, f64, f64)> {
        let (m, s) = self.loss_stats();
        Ok((self.alpha()?, m, s))
    }

    /// The current temperature α.
    pub fn alpha(&self) -> Result<f64> {
        self.log_alpha
            .as_tensor()
            .exp()?
            .to_vec1::<f64>()
            .map(|v| v[0])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 120 episodes of `sac` on `loss`: the actions (each checked to lie inside the box) and
    /// their losses.
    fn episodes(sac: &mut Sac, loss: impl Fn(&[f64]) -> f64) -> (Vec<Vec<f64>>, Vec<f64>) {
        (0..120)
            .map(|_| {
                let t = sac.act().unwrap();
                assert!(t.iter().all(|x| x.abs() < 1.0 && x.is_finite()), "{t:?}");
                let l = loss(&t);
                sac.observe(&t, l).unwrap();
                (t, l)
            })
            .unzip()
    }

    /// The mean of episodes 2–21 (after the start) and of the last 20.
    fn first_and_last(v: &[f64]) -> (f64, f64) {
        (
            v[1..21].iter().sum::<f64>() / 20.0,
            v[v.len() - 20..].iter().sum::<f64>() / 20.0,
        )
    }

    /// On a smooth bowl over Θ, a handful of SAC episodes move the policy towards the minimum:
    /// the mean loss of the last samples is below that of the first ones.
    #[test]
    fn sac_improves_on_a_quadratic_bowl() {
        let best = [0.6, -0.4, 0.2, 0.0, -0.7];
        let loss = |t: &[f64]| {
            1.0 + t
                .iter()
                .zip(best)
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f64>()
        };
        let mut sac = Sac::new(SacConfig::default(), &[-0.5, 0.5, -0.5, 0.5, 0.5], 3).unwrap();
        let (_, losses) = episodes(&mut sac, loss);
        let (first, last) = first_and_last(&losses);
        assert!(last < 0.8 * first, "first {first} last {last}");
        assert!(sac.alpha().unwrap().is_finite());
    }

    /// A bandit like the transport task's: the loss varies by a few percent of its size (440 at
    /// the best Θ, up to about 5 % more at the box's far corner). SAC must still move towards
    /// the best Θ: the excess over 440 of the last samples is well below that of the first.
    #[test]
    fn sac_learns_a_bandit_whose_losses_differ_by_a_few_percent() {
        let best = [0.5, -0.3, 0.4, 0.1, -0.6];
        let loss = |t: &[f64]| {
            440.0
                + 1.0
                    * t.iter()
                        .zip(best)
                        .map(|(a, b)| (a - b) * (a - b))
                        .sum::<f64>()
        };
        let mut sac = Sac::new(SacConfig::default(), &[-0.5, 0.5, -0.5, 0.5, 0.5], 7).unwrap();
        let (_, losses) = episodes(&mut sac, loss);
        let excess: Vec<f64> = losses.iter().map(|l| l - 440.0).collect();
        let (first, last) = first_and_last(&excess);
        let (alpha, mean, std) = sac.stats().unwrap();
        assert!(alpha.is_finite() && mean > 440.0 && std > 0.0);
        assert!(last < 0.6 * first, "first {first} last {last}");
    }

    /// The same agent over 30 parameters (a refined trajectory's residuals): its first action
    /// is the start, every action stays in the box, and it moves towards a bowl's minimum.
    #[test]
    fn sac_acts_in_thirty_dimensions_and_improves_on_a_bowl() {
        let best: Vec<f64> = (0..30).map(|i| 0.5 * ((i as f64) * 0.7).sin()).collect();
        let loss = |t: &[f64]| {
            1.0 + t
                .iter()
                .zip(&best)
                .map(|(a, b)| (a - b).powi(2))
                .sum::<f64>()
        };
        let mut sac = Sac::new(SacConfig::default(), &[0.0; 30], 5).unwrap();
        let (actions, losses) = episodes(&mut sac, loss);
        assert!(actions.iter().all(|t| t.len() == 30));
        assert!(
            actions[0].iter().all(|x| *x == 0.0),
            "the first action is the start"
        );
        let (first, last) = first_and_last(&losses);
        assert!(last < 0.8 * first, "first {first} last {last}");
    }

    #[test]
    fn a_seed_fixes_the_run() {
        let run = || {
            let mut sac = Sac::new(SacConfig::default(), &[0.1; 5], 11).unwrap();
            let mut out = Vec::new();
            for k in 0..12 {
                let t = sac.act().unwrap();
                sac.observe(&t, 1.0 + k as f64 * 0.1 + t[0]).unwrap();
                out.push(t);
            }
            out
        };
        assert_eq!(run(), run());
    }
}
