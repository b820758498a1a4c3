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

use super::dataset::Sample;
use super::knob::KNOB;
use crate::optim::mlp::Mlp;
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

/// Features → outputs (the dosing policy's one output is the knob).
pub struct Policy {
    pub mlp: Mlp,
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
            seed: 0,
        }
    }
}

/// The default [`TrainConfig::max_label_error_g`] (g): the results' own bar for a dose ("within
/// 0.1 g"), and above what the grains' packing alone costs a known answer (0.07 g on the held-out
/// scenes, docs/results/policy.md). The search's labels close far inside it (median 0.01 g).
pub const LABEL_TOLERANCE_G: f64 = 0.1;

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
            mlp,
            x_mean,
            x_std,
            outputs,
            hidden,
            layout,
        })
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

    /// The network's outputs (before clamping) for standardised inputs.
    pub fn forward(&self, x: &Tensor) -> anyhow::Result<Tensor> {
        Ok(self.mlp.forward(x)?)
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
        for var in self.mlp.vars() {
            push(&var.as_tensor().flatten_all()?.to_vec1::<f64>()?);
        }
        Ok(crate::optim::fnv1a(&text))
    }

    /// Writes the network, its standardisation and its layout (atomically).
    pub fn save(&self, path: &Path) -> anyhow::Result<()> {
        let dev = Device::Cpu;
        let mut t: Vec<(String, Tensor)> = Vec::new();
        for (k, (w, b)) in self.mlp.layers.iter().enumerate() {
            t.push((format!("layer{k}.weight"), w.as_tensor().clone()));
            t.push((format!("layer{k}.bias"), b.as_tensor().clone()));
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
        let mut layers = Vec::new();
        for k in 0..3 {
            let (w, b) = (
                get(&format!("layer{k}.weight"))?,
                get(&format!("layer{k}.bias"))?,
            );
            layers.push((Var::from_tensor(&w)?, Var::from_tensor(&b)?));
        }
        let sizes = [layout.len(), hidden, hidden, outputs];
        for (k, (w, _)) in layers.iter().enumerate() {
            anyhow::ensure!(
                w.dims() == [sizes[k + 1], sizes[k]],
                "{}: field layer{k}.weight: shape {:?}, expected {:?} for {} features and {hidden} hidden units",
                path.display(),
                w.dims(),
                [sizes[k + 1], sizes[k]],
                layout.len()
            );
        }
        Ok(Policy {
            mlp: Mlp { layers },
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

/// Fits a policy of the knob to the [`usable`] samples by full-batch AdamW on the mean squared
/// error. With a validation split, the weights of the epoch of lowest validation error are
/// kept.
pub fn train(samples: &[Sample], cfg: &TrainConfig) -> anyhow::Result<(Policy, Vec<TrainPoint>)> {
    let samples = usable(samples, cfg);
    anyhow::ensure!(
        !samples.is_empty(),
        "no sample of the dataset is its scene's answer within {} g",
        cfg.max_label_error_g
    );
    let is_val = |s: &Sample| cfg.val_every > 0 && s.scene % cfg.val_every == cfg.val_every - 1;
    let (val, tr): (Vec<&Sample>, Vec<&Sample>) = samples.iter().partition(|s| is_val(s));
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
        policy.mlp.vars(),
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
                .mlp
                .vars()
                .iter()
                .map(|w| w.as_tensor().copy())
                .collect::<candle_core::Result<_>>()?;
            best = Some((v, copy));
        }
    }
    if let Some((_, weights)) = best {
        for (var, w) in policy.mlp.vars().iter().zip(weights) {
            var.set(&w)?;
        }
    }
    Ok((policy, curve))
}

/// Each width [`select`] tried and its lowest validation MSE.
pub type Widths = Vec<(usize, f64)>;

/// The hidden widths [`select`] chooses among.
pub const WIDTHS: [usize; 4] = [8, 16, 32, 64];

/// One fit per width in `widths` ([`train`] with `cfg.hidden` replaced); keeps the one of lowest
/// validation error on the training set's own split (no held-out scene is seen), the first on
/// a tie. Returns it, its curve, and each width's lowest validation MSE.
pub fn select(
    samples: &[Sample],
    cfg: &TrainConfig,
    widths: &[usize],
) -> anyhow::Result<(Policy, Vec<TrainPoint>, Widths)> {
    let mut best: Option<(f64, Policy, Vec<TrainPoint>)> = None;
    let mut table = Vec::new();
    for &hidden in widths {
        let (p, curve) = train(samples, &TrainConfig { hidden, ..*cfg })?;
        let v = curve
            .iter()
            .map(|c| c.val_mse)
            .fold(f64::INFINITY, f64::min);
        table.push((hidden, v));
        if best.as_ref().is_none_or(|(b, _, _)| v < *b) {
            best = Some((v, p, curve));
        }
    }
    let (_, p, curve) = best.context("no width to choose from")?;
    Ok((p, curve, table))
}
