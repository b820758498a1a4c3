//! The policy network: an MLP (candle) from the scene's features, standardised by the training
//! set's mean and spread, to its outputs in [−1, 1]; its supervised fit to a dataset; and its
//! safetensors file.
//!
//! **The dosing policy's output is the knob**, the scoop depth of [`super::knob`]'s family, and
//! Θ is that family's member on the scene ([`super::knob::family`]). Every label of the dataset
//! lies on the family, whose other four components are fixed or a known function of the scene
//! (the transport distance is the cup distance), so a network that also predicted them could
//! only add its own error there, and a fine-tune that explored them would push Θ off the
//! family, where no label ever was. The network and REINFORCE ([`super::reinforce`]) take any
//! number of outputs.
//!
//! **An ensemble.** A policy is the mean of [`TrainConfig::members`] networks fitted to the same
//! samples from different initial weights (a deep ensemble, Lakshminarayanan et al. 2017). With
//! some sixty training scenes the fit's error on unseen scenes is mostly its variance, which the
//! mean cuts: on the validation split of the 80-scene dataset one 8-wide network's knob MSE was
//! 0.0051 and five averaged 0.0031; on the held-out scenes of the 160-scene study the ensemble
//! misses by 0.077 g, its first network alone by 0.113 g (docs/results/policy.md). REINFORCE
//! moves the mean, so every member.

use super::dataset::Sample;
use super::knob::KNOB;
use crate::lab::optim::mlp::Mlp;
use crate::lab::optim::problem::Problem;
use crate::scene::randomize::Draw;
use crate::skills::Theta;
use crate::util::SplitMix64;
use anyhow::Context;
use candle_core::{Device, Tensor, Var};
use candle_nn::{AdamW, Optimizer, ParamsAdamW};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::Path;

/// The policy file's format tag.
pub const FORMAT: &str = "powderlab-policy/2";
/// A feature whose training spread is below this is passed through centred, not scaled (a
/// constant feature, such as the delivered mass of single scoops).
const MIN_SPREAD: f64 = 1e-9;

/// Features → outputs (the dosing policy's one output is the knob): the mean of its members.
pub struct Policy {
    pub members: Vec<Mlp>,
    pub x_mean: Vec<f64>,
    pub x_std: Vec<f64>,
    pub outputs: usize,
    pub hidden: usize,
    pub layout: Vec<String>,
}

/// How to fit.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainConfig {
    /// Full-batch AdamW steps.
    pub epochs: usize,
    pub lr: f64,
    pub weight_decay: f64,
    /// Units per hidden layer (two layers).
    pub hidden: usize,
    /// Every `val_every`-th scene (all its copies) is held out to choose the epoch; 0 keeps
    /// none and the last epoch's weights.
    pub val_every: usize,
    /// A label is learnt when it is its scene's answer: its Θ doses within this (g) of the
    /// target, or the target lies beyond the family's end and Θ is at that end ([`usable`]).
    /// A perturbed copy whose refinement did not reach its target is no answer to learn.
    pub max_label_error_g: f64,
    /// Networks in the ensemble, each from its own initial weights (`seed + m`).
    pub members: usize,
    pub seed: u64,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            epochs: 3000,
            lr: 3e-3,
            weight_decay: 1e-3,
            hidden: 64,
            val_every: 5,
            max_label_error_g: LABEL_TOLERANCE_G,
            members: MEMBERS,
            seed: 0,
        }
    }
}

/// The default [`TrainConfig::max_label_error_g`] (g): the results' own bar for a dose ("within
/// 0.1 g"), and above what the grains' packing alone costs a known answer (0.07 g on the held-out
/// scenes, docs/results/policy.md). The search's labels close far inside it (median 0.01 g).
pub const LABEL_TOLERANCE_G: f64 = 0.1;

/// The outputs of a dosing policy: the knob alone.
pub const OUTPUTS: usize = 1;

/// The default [`TrainConfig::members`]: the usual size of a deep ensemble; most of the
/// variance a mean removes is gone by five.
pub const MEMBERS: usize = 5;

/// One point of the training curve.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
pub struct TrainPoint {
    pub epoch: usize,
    pub train_mse: f64,
    pub val_mse: f64,
}

impl Policy {
    /// A fresh network whose outputs start at `out_mean` (one value per output) for every input.
    pub fn new(
        layout: Vec<String>,
        hidden: usize,
        x_mean: Vec<f64>,
        x_std: Vec<f64>,
        out_mean: &[f64],
        seed: u64,
    ) -> anyhow::Result<Policy> {
        let dev = Device::Cpu;
        let mut rng = SplitMix64(seed);
        let outputs = out_mean.len();
        anyhow::ensure!(outputs > 0, "a policy needs at least one output");
        let mlp = Mlp::new(&[layout.len(), hidden, hidden, outputs], &mut rng, &dev)?;
        let (w, b) = mlp.layers.last().context("three layers")?;
        w.set(&(w.as_tensor() * 0.1)?)?;
        b.set(&Tensor::from_vec(out_mean.to_vec(), outputs, &dev)?)?;
        Ok(Policy {
            members: vec![mlp],
            x_mean,
            x_std,
            outputs,
            hidden,
            layout,
        })
    }

    /// One policy of all the members of `parts`, which must share their layout, standardisation
    /// and shape.
    pub fn ensemble(parts: Vec<Policy>) -> anyhow::Result<Policy> {
        let mut it = parts.into_iter();
        let mut first = it.next().context("an ensemble of no policy")?;
        for p in it {
            anyhow::ensure!(
                p.layout == first.layout
                    && p.x_mean == first.x_mean
                    && p.x_std == first.x_std
                    && p.hidden == first.hidden
                    && p.outputs == first.outputs,
                "the members of an ensemble must share their features, standardisation and shape"
            );
            first.members.extend(p.members);
        }
        Ok(first)
    }

    /// Member `m` alone, as a policy of its own (its weights copied).
    pub fn member(&self, m: usize) -> anyhow::Result<Policy> {
        let mlp = self.members.get(m).context("no such member")?;
        let layers = mlp
            .layers
            .iter()
            .map(|(w, b)| {
                Ok((
                    Var::from_tensor(&w.as_tensor().copy()?)?,
                    Var::from_tensor(&b.as_tensor().copy()?)?,
                ))
            })
            .collect::<candle_core::Result<Vec<_>>>()?;
        Ok(Policy {
            members: vec![Mlp { layers }],
            x_mean: self.x_mean.clone(),
            x_std: self.x_std.clone(),
            outputs: self.outputs,
            hidden: self.hidden,
            layout: self.layout.clone(),
        })
    }

    /// A dosing policy's Θ on scene `d` (with `features`): the knob family's member at the
    /// network's knob.
    pub fn theta(&self, problem: &Problem, d: &Draw, features: &[f64]) -> anyhow::Result<Theta> {
        let out = self.act(features)?;
        anyhow::ensure!(
            out.len() == OUTPUTS,
            "a policy of {} outputs; a dosing policy gives the knob alone",
            out.len()
        );
        Ok(super::knob::family(problem, d, out[0]))
    }

    /// Every member's weights and biases.
    pub fn vars(&self) -> Vec<Var> {
        self.members.iter().flat_map(|m| m.vars()).collect()
    }

    /// Standardised features `[n, F]` of raw rows.
    pub fn inputs(&self, rows: &[Vec<f64>]) -> anyhow::Result<Tensor> {
        let f = self.layout.len();
        let flat: Vec<f64> = rows
            .iter()
            .flat_map(|r| {
                r.iter().enumerate().map(|(i, v)| {
                    let s = if self.x_std[i] > MIN_SPREAD {
                        self.x_std[i]
                    } else {
                        1.0
                    };
                    (v - self.x_mean[i]) / s
                })
            })
            .collect();
        Ok(Tensor::from_vec(flat, (rows.len(), f), &Device::Cpu)?)
    }

    /// The members' mean outputs (before clamping) for standardised inputs.
    pub fn forward(&self, x: &Tensor) -> anyhow::Result<Tensor> {
        let mut sum = self.members[0].forward(x)?;
        for m in &self.members[1..] {
            sum = (sum + m.forward(x)?)?;
        }
        Ok((sum / self.members.len() as f64)?)
    }

    /// The outputs for one scene's features, clamped into [−1, 1].
    pub fn act(&self, features: &[f64]) -> anyhow::Result<Vec<f64>> {
        anyhow::ensure!(
            features.len() == self.layout.len(),
            "{} features given, the policy takes {}",
            features.len(),
            self.layout.len()
        );
        let out = self
            .forward(&self.inputs(&[features.to_vec()])?)?
            .to_vec2::<f64>()?;
        Ok(out[0].iter().map(|v| v.clamp(-1.0, 1.0)).collect())
    }

    /// A fingerprint of the network: FNV-1a of its layout, its standardisation and every
    /// weight's bits. (A file's bytes will not do: safetensors writes its metadata map in hash
    /// order, which differs between processes.)
    pub fn fingerprint(&self) -> anyhow::Result<String> {
        let mut text = format!("{}|{}|", self.layout.join(","), self.hidden);
        let mut push = |v: &[f64]| {
            for x in v {
                text.push_str(&format!("{:016x}", x.to_bits()));
            }
        };
        push(&self.x_mean);
        push(&self.x_std);
        for var in self.vars() {
            push(&var.as_tensor().flatten_all()?.to_vec1::<f64>()?);
        }
        Ok(crate::util::fnv1a(&text))
    }

    /// Writes the network, its standardisation and its layout (atomically).
    pub fn save(&self, path: &Path) -> anyhow::Result<()> {
        let dev = Device::Cpu;
        let mut t: Vec<(String, Tensor)> = Vec::new();
        for (m, mlp) in self.members.iter().enumerate() {
            for (k, (w, b)) in mlp.layers.iter().enumerate() {
                t.push((format!("member{m}.layer{k}.weight"), w.as_tensor().clone()));
                t.push((format!("member{m}.layer{k}.bias"), b.as_tensor().clone()));
            }
        }
        t.push((
            "x_mean".into(),
            Tensor::from_vec(self.x_mean.clone(), self.x_mean.len(), &dev)?,
        ));
        t.push((
            "x_std".into(),
            Tensor::from_vec(self.x_std.clone(), self.x_std.len(), &dev)?,
        ));
        let meta = HashMap::from([
            ("format".to_string(), FORMAT.to_string()),
            ("features".to_string(), self.layout.join(",")),
            ("hidden".to_string(), self.hidden.to_string()),
            ("outputs".to_string(), self.outputs.to_string()),
            ("members".to_string(), self.members.len().to_string()),
        ]);
        let bytes = safetensors::serialize(t, Some(meta))
            .map_err(|e| anyhow::anyhow!("{}: writing safetensors: {e}", path.display()))?;
        crate::util::write_atomic(path, &bytes)?;
        Ok(())
    }

    /// Reads a policy file, refusing another format, a layout other than `expected`, or another
    /// number of outputs than `outputs`.
    pub fn load(path: &Path, expected: &[String], outputs: usize) -> anyhow::Result<Policy> {
        let bytes = std::fs::read(path)
            .with_context(|| format!("{}: cannot read the policy file", path.display()))?;
        let (meta, t) = super::file::open(path, &bytes, FORMAT)?;
        let layout: Vec<String> = meta
            .get("features")
            .map(|s| s.split(',').map(String::from).collect())
            .unwrap_or_default();
        super::features::check_layout(path, &layout, expected)?;
        let hidden: usize = meta
            .get("hidden")
            .and_then(|h| h.parse().ok())
            .with_context(|| {
                format!(
                    "{}: field metadata.hidden: missing or not a count",
                    path.display()
                )
            })?;
        let found: Option<usize> = meta.get("outputs").and_then(|h| h.parse().ok());
        anyhow::ensure!(
            found == Some(outputs),
            "{}: field metadata.outputs: {}, expected {outputs}; retrain with `powderlab policy train`",
            path.display(),
            found.map_or("missing".to_string(), |n| n.to_string()),
        );
        let get = |n: &str| {
            t.get(n).cloned().with_context(|| {
                format!(
                    "{}: field {n}: missing; retrain with `powderlab policy train`",
                    path.display()
                )
            })
        };
        let count: usize = meta
            .get("members")
            .and_then(|h| h.parse().ok())
            .filter(|&n| n > 0)
            .with_context(|| {
                format!(
                    "{}: field metadata.members: missing or not a positive count; retrain with \
                     `powderlab policy train`",
                    path.display()
                )
            })?;
        let sizes = [layout.len(), hidden, hidden, outputs];
        let mut members = Vec::new();
        for m in 0..count {
            let mut layers = Vec::new();
            for k in 0..3 {
                let name = format!("member{m}.layer{k}");
                let (w, b) = (
                    get(&format!("{name}.weight"))?,
                    get(&format!("{name}.bias"))?,
                );
                anyhow::ensure!(
                    w.dims() == [sizes[k + 1], sizes[k]],
                    "{}: field {name}.weight: shape {:?}, expected {:?} for {} features and {hidden} hidden units",
                    path.display(),
                    w.dims(),
                    [sizes[k + 1], sizes[k]],
                    layout.len()
                );
                layers.push((Var::from_tensor(&w)?, Var::from_tensor(&b)?));
            }
            members.push(Mlp { layers });
        }
        Ok(Policy {
            members,
            x_mean: get("x_mean")?.to_vec1()?,
            x_std: get("x_std")?.to_vec1()?,
            outputs,
            hidden,
            layout,
        })
    }
}

/// Mean and spread of each column.
fn moments(rows: &[Vec<f64>]) -> (Vec<f64>, Vec<f64>) {
    let n = rows.len().max(1) as f64;
    let f = rows.first().map_or(0, Vec::len);
    let mean: Vec<f64> = (0..f)
        .map(|i| rows.iter().map(|r| r[i]).sum::<f64>() / n)
        .collect();
    let std = (0..f)
        .map(|i| (rows.iter().map(|r| (r[i] - mean[i]).powi(2)).sum::<f64>() / n).sqrt())
        .collect();
    (mean, std)
}

/// Whether a sample's Θ is its scene's answer: it doses within `tolerance_g` of the target, or
/// the target lies beyond the family's end and Θ's knob is at that end (the deepest scoop when
/// it holds less than the target, `indicator > 0`; the shallowest when it holds more).
pub fn is_answer(s: &Sample, tolerance_g: f64) -> bool {
    let k = s.theta[KNOB];
    s.indicator.abs() <= tolerance_g
        || (k >= 1.0 && s.indicator > 0.0)
        || (k <= -1.0 && s.indicator < 0.0)
}

/// The samples [`train`] learns from: those that are their scene's answer ([`is_answer`]).
pub fn usable<'a>(samples: &'a [Sample], cfg: &TrainConfig) -> Vec<&'a Sample> {
    samples
        .iter()
        .filter(|s| is_answer(s, cfg.max_label_error_g))
        .collect()
}

/// What the network learns of a sample: its knob.
fn label(s: &Sample) -> f64 {
    s.theta[KNOB]
}

/// The validation split of `samples` (every `val_every`-th scene, all its copies and hindsight
/// samples) and the rest.
fn split<'a>(samples: &[&'a Sample], cfg: &TrainConfig) -> (Vec<&'a Sample>, Vec<&'a Sample>) {
    let is_val = |s: &Sample| cfg.val_every > 0 && s.scene % cfg.val_every == cfg.val_every - 1;
    samples.iter().partition(|s| is_val(s))
}

/// Fits one network of the knob (seeded by `cfg.seed`) to the [`usable`] samples by full-batch
/// AdamW on the mean squared error. With a validation split, the weights of the epoch of
/// lowest validation error are kept.
pub fn train(samples: &[Sample], cfg: &TrainConfig) -> anyhow::Result<(Policy, Vec<TrainPoint>)> {
    let samples = usable(samples, cfg);
    anyhow::ensure!(
        !samples.is_empty(),
        "no sample of the dataset is its scene's answer within {} g",
        cfg.max_label_error_g
    );
    let (val, tr) = split(&samples, cfg);
    anyhow::ensure!(
        !tr.is_empty(),
        "no training samples outside the validation split"
    );
    let xs: Vec<Vec<f64>> = tr.iter().map(|s| s.features.clone()).collect();
    let (x_mean, x_std) = moments(&xs);
    let mean = tr.iter().map(|s| label(s)).sum::<f64>() / tr.len() as f64;
    let policy = Policy::new(
        super::features::layout(),
        cfg.hidden,
        x_mean,
        x_std,
        &[mean],
        cfg.seed,
    )?;
    let dev = Device::Cpu;
    let targets = |set: &[&Sample]| -> anyhow::Result<Tensor> {
        let flat: Vec<f64> = set.iter().map(|s| label(s)).collect();
        Ok(Tensor::from_vec(flat, (set.len(), 1), &dev)?)
    };
    let (x_tr, y_tr) = (policy.inputs(&xs)?, targets(&tr)?);
    let x_val = policy.inputs(&val.iter().map(|s| s.features.clone()).collect::<Vec<_>>())?;
    let y_val = targets(&val)?;
    let mut opt = AdamW::new(
        policy.vars(),
        ParamsAdamW {
            lr: cfg.lr,
            weight_decay: cfg.weight_decay,
            ..Default::default()
        },
    )?;
    let mse = |x: &Tensor, y: &Tensor| -> anyhow::Result<Tensor> {
        Ok((policy.forward(x)? - y)?.sqr()?.mean_all()?)
    };
    let mut curve = Vec::new();
    let mut best: Option<(f64, Vec<Tensor>)> = None;
    for epoch in 1..=cfg.epochs {
        let loss = mse(&x_tr, &y_tr)?;
        opt.backward_step(&loss)?;
        let v = if val.is_empty() {
            f64::NAN
        } else {
            mse(&x_val, &y_val)?.to_scalar::<f64>()?
        };
        if epoch == 1 || epoch % 10 == 0 || epoch == cfg.epochs {
            curve.push(TrainPoint {
                epoch,
                train_mse: loss.to_scalar::<f64>()?,
                val_mse: v,
            });
        }
        if !val.is_empty() && best.as_ref().is_none_or(|(b, _)| v < *b) {
            let copy = policy
                .vars()
                .iter()
                .map(|w| w.as_tensor().copy())
                .collect::<candle_core::Result<_>>()?;
            best = Some((v, copy));
        }
    }
    if let Some((_, weights)) = best {
        for (var, w) in policy.vars().iter().zip(weights) {
            var.set(&w)?;
        }
    }
    Ok((policy, curve))
}

/// A fitted ensemble ([`fit`]).
pub struct Fit {
    pub policy: Policy,
    /// The members' mean training and validation MSE by epoch.
    pub curve: Vec<TrainPoint>,
    /// The ensemble's MSE on the validation split (NaN without one).
    pub val_mse: f64,
}

/// An ensemble of `cfg.members` networks ([`train`], seeds `cfg.seed + m`), and its error on
/// the validation split.
pub fn fit(samples: &[Sample], cfg: &TrainConfig) -> anyhow::Result<Fit> {
    anyhow::ensure!(cfg.members > 0, "an ensemble needs at least one member");
    let mut parts = Vec::new();
    let mut curves = Vec::new();
    for m in 0..cfg.members {
        let (p, c) = train(
            samples,
            &TrainConfig {
                seed: cfg.seed.wrapping_add(m as u64),
                ..*cfg
            },
        )?;
        parts.push(p);
        curves.push(c);
    }
    let policy = Policy::ensemble(parts)?;
    let n = curves.len() as f64;
    let curve = (0..curves[0].len())
        .map(|i| TrainPoint {
            epoch: curves[0][i].epoch,
            train_mse: curves.iter().map(|c| c[i].train_mse).sum::<f64>() / n,
            val_mse: curves.iter().map(|c| c[i].val_mse).sum::<f64>() / n,
        })
        .collect();
    let (val, _) = split(&usable(samples, cfg), cfg);
    let val_mse = if val.is_empty() {
        f64::NAN
    } else {
        let x = policy.inputs(&val.iter().map(|s| s.features.clone()).collect::<Vec<_>>())?;
        let out = policy.forward(&x)?.to_vec2::<f64>()?;
        val.iter()
            .zip(&out)
            .map(|(s, o)| (o[0] - label(s)).powi(2))
            .sum::<f64>()
            / val.len() as f64
    };
    Ok(Fit {
        policy,
        curve,
        val_mse,
    })
}

/// Each width [`select`] tried and its lowest validation MSE.
pub type Widths = Vec<(usize, f64)>;

/// The hidden widths [`select`] chooses among.
pub const WIDTHS: [usize; 4] = [8, 16, 32, 64];

/// One ensemble per width in `widths` ([`fit`] with `cfg.hidden` replaced); keeps the one of
/// lowest validation error on the training set's own split (no held-out scene is seen), the
/// first on a tie. Returns it and each width's ensemble validation MSE.
pub fn select(
    samples: &[Sample],
    cfg: &TrainConfig,
    widths: &[usize],
) -> anyhow::Result<(Fit, Widths)> {
    let mut best: Option<Fit> = None;
    let mut table = Vec::new();
    for &hidden in widths {
        let f = fit(samples, &TrainConfig { hidden, ..*cfg })?;
        table.push((hidden, f.val_mse));
        if best.as_ref().is_none_or(|b| f.val_mse < b.val_mse) {
            best = Some(f);
        }
    }
    Ok((best.context("no width to choose from")?, table))
}
