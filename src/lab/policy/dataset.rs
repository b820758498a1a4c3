//! The policy's training pairs (seed B's Sim2Real data): randomised scenes, each with the skill
//! Θ* the per-scene optimiser found for it, and seed B's cheap augmentation.
//!
//! 1. **Scene k** is drawn from the scene's `randomize` ranges with its own generator
//!    ([`draw_scene`]), so scene k is the same whatever the count.
//! 2. **Θ\*** is the lowest-loss rollout of the root search of the dose along the scene's
//!    family of skills ([`super::knob`]), with the given budget of forward rollouts: one knob,
//!    the scoop depth, so that similar scenes get similar labels.
//! 3. **Augmentation:** the scene perturbed ([`Randomization::perturb`]), then a few
//!    warm-started steps from Θ\* along the adjoint gradient of the dosing loss, projected on
//!    the knob. Each step is a Gauss–Newton step on the relative dose error
//!    `r = (M − m*)/m*` (`L = r²`): `ΔΘ = −2L ∇L/|∇L|²`, at most [`AUGMENT_STEP`] long. The
//!    label is the lowest-loss Θ visited, Θ\* itself included.
//! 4. **Hindsight:** every rollout of 2 and 3 that delivers a mass M within the target's range
//!    is also kept as the label of its scene with target M, exact and free ([`hindsight`]).
//!
//! Each scene's samples are written to `scene-K.json` when it is done, so a killed run resumes
//! at the scene it was on; [`write`] gathers them into one safetensors file.

use super::features::{features, layout};
use super::knob;
use crate::lab::optim::problem::{Outcome, Problem};
use crate::lab::optim::report::BACKWARD_COST;
use crate::scene::randomize::{Draw, Randomization};
use crate::scene::Scene;
use crate::skills::Theta;
use crate::util::SplitMix64;
use anyhow::Context;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::Path;

/// Tape memory of a backward pass (bytes).
pub const TAPE_BUDGET: usize = 2 << 30;
/// The longest augmentation step in Θ (the box is [−1, 1]⁵).
pub const AUGMENT_STEP: f64 = 0.1;

/// The default count of randomised scenes: the held-out error fell from 0.17 g to 0.14 g from 40
/// to 80, so the data was doubled again.
pub const SCENES: usize = 160;

/// How a dataset is made; a resumed run must use the same.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Config {
    /// The scene's fingerprint (`Scene::fingerprint`: its parsed fields, not its text).
    pub scene_hash: String,
    /// Randomised scenes.
    pub scenes: usize,
    /// The most forward rollouts the root search spends on each.
    pub budget: usize,
    /// Perturbed copies of each scene.
    pub augment: usize,
    /// Gradient steps on each perturbed copy.
    pub augment_steps: usize,
    /// The perturbation's standard deviation, as a share of each range's width.
    pub perturb: f64,
    /// The stream scenes are drawn from.
    pub seed: u64,
}

/// One training pair and what it cost.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Sample {
    /// The randomised scene's index.
    pub scene: usize,
    /// 0 for the optimised scene, k for its k-th perturbed copy.
    pub copy: usize,
    pub draw: Draw,
    pub features: Vec<f64>,
    pub theta: Theta,
    pub loss: f64,
    /// `target − delivered` (g) at Θ.
    pub indicator: f64,
    /// The loss of the search's first rollout: for a perturbed copy, Θ\* of its scene on the
    /// copy, before the gradient steps.
    pub start_loss: f64,
    /// Compute spent to find Θ, in forward rollouts (a backward pass counted at its cost).
    pub rollouts: f64,
    /// The same in simulated particle-substeps.
    pub particle_substeps: f64,
    /// A rollout's own mass taken as the target ([`hindsight`]): exact, and free (its compute
    /// is its search's).
    #[serde(default)]
    pub hindsight: bool,
}

/// Scene `k` of the stream `seed`.
pub fn draw_scene(spec: &Randomization, base: &Scene, seed: u64, k: usize) -> Draw {
    let mut rng = SplitMix64(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (k as u64 + 1));
    spec.draw(base, &mut rng)
}

/// The scene's `randomize` section, or a one-line error naming the file.
pub fn spec_of(scene: &Scene) -> anyhow::Result<&Randomization> {
    scene.randomize.as_ref().ok_or_else(|| {
        anyhow::anyhow!(
            "{}: field randomize: missing; a policy needs the ranges to draw scenes from (see \
             scenes/policy_dosing.ron)",
            scene.path.display()
        )
    })
}

/// A rollout's compute in forward rollouts: 1, or `1 + BACKWARD_COST` with its backward pass.
pub fn forward_equivalents(o: &Outcome) -> f64 {
    if o.grad.is_some() {
        1.0 + BACKWARD_COST
    } else {
        1.0
    }
}

/// The simulated particle-substeps of a rollout, counting the backward pass at its cost.
pub fn cost(o: &Outcome) -> f64 {
    (o.steps * o.substeps * o.particles) as f64 * forward_equivalents(o)
}

/// A search's result: its lowest-loss rollout and what the search spent.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Search {
    pub theta: Theta,
    pub best: Outcome,
    pub rollouts: f64,
    pub particle_substeps: f64,
    /// Every rollout's Θ and outcome, in order.
    pub trace: Vec<(Theta, Outcome)>,
}

/// Gauss–Newton steps on the dose from `theta` along the knob (see the module's notes): `steps`
/// gradient rollouts and a last forward one.
pub fn refine(problem: &Problem, theta: Theta, steps: usize) -> anyhow::Result<Search> {
    let mut t = theta;
    let mut best: Option<(Theta, Outcome)> = None;
    let (mut rollouts, mut spent) = (0.0, 0.0);
    let mut trace = Vec::new();
    for s in 0..=steps {
        let o = problem.evaluate(t, s < steps, true)?;
        rollouts += forward_equivalents(&o);
        spent += cost(&o);
        trace.push((t, o.clone()));
        let next = o.grad.map(|g| {
            let mut along = [0.0; 5];
            along[knob::KNOB] = g[knob::KNOB];
            gauss_newton(t, o.loss, along)
        });
        if best.as_ref().is_none_or(|(_, b)| o.loss < b.loss) {
            best = Some((t, o));
        }
        match next {
            Some(n) => t = n,
            None => break,
        }
    }
    let (theta, best) = best.context("no rollout")?;
    Ok(Search {
        theta,
        best,
        rollouts,
        particle_substeps: spent,
        trace,
    })
}

/// `θ − 2L ∇L/|∇L|²`, at most [`AUGMENT_STEP`] long, kept in the box.
pub fn gauss_newton(theta: Theta, loss: f64, g: [f64; 5]) -> Theta {
    let n2: f64 = g.iter().map(|v| v * v).sum();
    if !(n2 > 0.0 && n2.is_finite()) {
        return theta;
    }
    let mut d: [f64; 5] = std::array::from_fn(|i| -2.0 * loss * g[i] / n2);
    let len = d.iter().map(|v| v * v).sum::<f64>().sqrt();
    if len > AUGMENT_STEP {
        d.iter_mut().for_each(|v| *v *= AUGMENT_STEP / len);
    }
    Theta(std::array::from_fn(|i| (theta[i] + d[i]).clamp(-1.0, 1.0)))
}

/// The problem of scene `d` drawn from `base`, and its features.
pub fn problem_of(base: &Scene, d: &Draw) -> anyhow::Result<(Problem, Vec<f64>)> {
    let spec = spec_of(base)?;
    let scene = spec.apply(base, d)?;
    let problem = Problem::new(scene.clone(), TAPE_BUDGET)?;
    let x = problem.initial_positions();
    let f = features(spec, &scene, d, &x, 0.0);
    Ok((problem, f))
}

/// The hindsight samples of `rollouts` on scene `d` (see the module's notes): each rollout
/// whose delivered mass lies in the target's range, with that mass as the target.
pub fn hindsight(
    spec: &Randomization,
    problem: &Problem,
    (scene, copy): (usize, usize),
    d: &Draw,
    rollouts: &[(Theta, Outcome)],
) -> Vec<Sample> {
    let (lo, hi) = spec.target_g.unwrap_or((d.target_g, d.target_g));
    let x = problem.initial_positions();
    rollouts
        .iter()
        .filter(|(_, o)| o.transported >= lo && o.transported <= hi)
        .map(|(theta, o)| {
            let draw = Draw {
                target_g: o.transported,
                ..d.clone()
            };
            Sample {
                scene,
                copy,
                features: features(spec, problem.scene(), &draw, &x, 0.0),
                draw,
                theta: *theta,
                loss: 0.0,
                indicator: 0.0,
                start_loss: 0.0,
                rollouts: 0.0,
                particle_substeps: 0.0,
                hindsight: true,
            }
        })
        .collect()
}

/// Scene `k`'s samples: the optimised scene, its perturbed copies and their hindsight samples.
/// This is the unit of work a machine runs; `powderlab.distributed.map_dataset` runs it as Ray
/// tasks.
pub fn scene_samples(base: &Scene, cfg: &Config, k: usize) -> anyhow::Result<Vec<Sample>> {
    let spec = spec_of(base)?;
    let d = draw_scene(spec, base, cfg.seed, k);
    let (problem, f) = problem_of(base, &d)?;
    let trace = knob::search(&problem, &d, cfg.budget)?;
    let (s_star, best) = knob::best(&trace).context("the search ran no rollout")?;
    let rollouts: Vec<(Theta, Outcome)> = trace
        .iter()
        .map(|(s, o)| (knob::family(&problem, &d, *s), o.clone()))
        .collect();
    let mut out = vec![Sample {
        scene: k,
        copy: 0,
        draw: d.clone(),
        features: f,
        theta: knob::family(&problem, &d, *s_star),
        loss: best.loss,
        indicator: best.indicator,
        start_loss: trace[0].1.loss,
        rollouts: trace.len() as f64,
        particle_substeps: trace.iter().map(|(_, o)| cost(o)).sum(),
        hindsight: false,
    }];
    out.extend(hindsight(spec, &problem, (k, 0), &d, &rollouts));
    let mut rng = SplitMix64(cfg.seed ^ (0xA11C_E5ED << 16) ^ k as u64);
    for copy in 1..=cfg.augment {
        let p = spec.perturb(&d, cfg.perturb, &mut rng);
        let (pp, pf) = problem_of(base, &p)?;
        let r = refine(&pp, knob::family(&pp, &p, *s_star), cfg.augment_steps)?;
        out.push(Sample {
            scene: k,
            copy,
            draw: p.clone(),
            features: pf,
            theta: r.theta,
            loss: r.best.loss,
            indicator: r.best.indicator,
            start_loss: r.trace[0].1.loss,
            rollouts: r.rollouts,
            particle_substeps: r.particle_substeps,
            hindsight: false,
        });
        out.extend(hindsight(spec, &pp, (k, copy), &p, &r.trace));
    }
    Ok(out)
}

/// Where scene `k`'s samples are kept, and their text there.
pub fn scene_file(dir: &Path, k: usize) -> std::path::PathBuf {
    dir.join(format!("scene-{k}.json"))
}

/// The text [`generate`] keeps for a scene's samples.
pub fn scene_text(samples: &[Sample]) -> anyhow::Result<String> {
    Ok(serde_json::to_string(samples)?)
}

/// Makes `dir` a dataset folder of `cfg`: writes its settings there, or checks that the ones
/// there are the same (a resumed run, or the Ray path's tasks, must not mix two datasets).
/// Only the count of scenes may differ: scene k does not depend on it, so a dataset grows by
/// the scenes it lacks.
pub fn claim(dir: &Path, cfg: &Config) -> anyhow::Result<()> {
    crate::util::create_output_dir(dir, "--dir")?;
    let cfg_path = dir.join("dataset-config.json");
    match std::fs::read_to_string(&cfg_path) {
        Ok(text) => {
            let old: Config = serde_json::from_str(&text)
                .with_context(|| format!("reading {}", cfg_path.display()))?;
            let same_but_count = Config {
                scenes: cfg.scenes,
                ..old.clone()
            } == *cfg;
            if same_but_count && old.scenes != cfg.scenes {
                crate::util::write_atomic(&cfg_path, serde_json::to_string_pretty(cfg)?.as_bytes())?
            } else if !same_but_count {
                anyhow::bail!(
                    "{}: this folder holds a dataset of other settings or another scene file; \
                     rerun with the same ones, or choose another --dir",
                    cfg_path.display()
                );
            }
        }
        Err(_) => {
            crate::util::write_atomic(&cfg_path, serde_json::to_string_pretty(cfg)?.as_bytes())?
        }
    }
    Ok(())
}

/// Makes (or resumes) the dataset of `base` in `dir`; `progress(done)` hears of each scene.
/// Scenes run side by side on the rayon pool.
pub fn generate(
    base: &Scene,
    cfg: &Config,
    dir: &Path,
    progress: &(dyn Fn(usize) + Sync),
) -> anyhow::Result<Vec<Sample>> {
    claim(dir, cfg)?;
    let done = std::sync::atomic::AtomicUsize::new(0);
    let per_scene: Vec<Vec<Sample>> = (0..cfg.scenes)
        .into_par_iter()
        .map(|k| {
            let path = scene_file(dir, k);
            let samples = super::file::kept(
                &path,
                |_: &Vec<Sample>| true,
                || scene_samples(base, cfg, k).with_context(|| format!("randomised scene {k}")),
            )?;
            progress(done.fetch_add(1, std::sync::atomic::Ordering::SeqCst) + 1);
            Ok(samples)
        })
        .collect::<anyhow::Result<_>>()?;
    Ok(per_scene.into_iter().flatten().collect())
}

/// The dataset file's format tag.
pub const FORMAT: &str = "powderlab-policy-dataset/2";

fn matrix(rows: &[Vec<f64>], width: usize) -> anyhow::Result<candle_core::Tensor> {
    let flat: Vec<f64> = rows.iter().flatten().copied().collect();
    Ok(candle_core::Tensor::from_vec(
        flat,
        (rows.len(), width),
        &candle_core::Device::Cpu,
    )?)
}

/// Writes `samples` to a safetensors file (atomically): `features [n, F]`, `theta [n, 5]`,
/// `params [n, 7]` (the draws), `packing_seed [n, 2]` (its two 32-bit halves, which an f64
/// holds exactly), and `loss`, `indicator`, `start_loss`, `rollouts`, `particle_substeps`,
/// `scene`, `copy` and `hindsight` (0 or 1) as `[n, 1]`; the feature and parameter names go in the metadata.
pub fn write(path: &Path, samples: &[Sample]) -> anyhow::Result<()> {
    let names = layout();
    let f = samples.first().map_or(names.len(), |s| s.features.len());
    anyhow::ensure!(
        f == names.len(),
        "samples of {f} features, the layout has {}",
        names.len()
    );
    let col = |g: &dyn Fn(&Sample) -> f64| -> anyhow::Result<candle_core::Tensor> {
        matrix(&samples.iter().map(|s| vec![g(s)]).collect::<Vec<_>>(), 1)
    };
    let mut t: Vec<(String, candle_core::Tensor)> = vec![
        (
            "features".into(),
            matrix(
                &samples
                    .iter()
                    .map(|s| s.features.clone())
                    .collect::<Vec<_>>(),
                f,
            )?,
        ),
        (
            "theta".into(),
            matrix(
                &samples.iter().map(|s| s.theta.to_vec()).collect::<Vec<_>>(),
                5,
            )?,
        ),
        (
            "params".into(),
            matrix(
                &samples
                    .iter()
                    .map(|s| s.draw.values().to_vec())
                    .collect::<Vec<_>>(),
                7,
            )?,
        ),
        (
            "packing_seed".into(),
            matrix(
                &samples
                    .iter()
                    .map(|s| {
                        let v = s.draw.packing_seed;
                        vec![(v >> 32) as f64, (v & 0xFFFF_FFFF) as f64]
                    })
                    .collect::<Vec<_>>(),
                2,
            )?,
        ),
    ];
    t.push(("loss".into(), col(&|s| s.loss)?));
    t.push(("indicator".into(), col(&|s| s.indicator)?));
    t.push(("start_loss".into(), col(&|s| s.start_loss)?));
    t.push(("rollouts".into(), col(&|s| s.rollouts)?));
    t.push(("particle_substeps".into(), col(&|s| s.particle_substeps)?));
    t.push(("scene".into(), col(&|s| s.scene as f64)?));
    t.push(("copy".into(), col(&|s| s.copy as f64)?));
    t.push((
        "hindsight".into(),
        col(&|s| f64::from(u8::from(s.hindsight)))?,
    ));
    let meta = HashMap::from([
        ("format".to_string(), FORMAT.to_string()),
        ("features".to_string(), names.join(",")),
        (
            "params".to_string(),
            crate::scene::randomize::Draw::NAMES.join(","),
        ),
    ]);
    let bytes = safetensors::serialize(t, Some(meta))
        .map_err(|e| anyhow::anyhow!("{}: writing safetensors: {e}", path.display()))?;
    crate::util::write_atomic(path, &bytes)?;
    Ok(())
}

/// Reads what [`write`] wrote, refusing another format or feature layout.
pub fn read(path: &Path) -> anyhow::Result<Vec<Sample>> {
    let bytes = std::fs::read(path)
        .with_context(|| format!("{}: cannot read the dataset", path.display()))?;
    let (meta, tensors) = super::file::open(path, &bytes, FORMAT)?;
    let get = |name: &str| -> anyhow::Result<Vec<Vec<f64>>> {
        let t = tensors.get(name).with_context(|| {
            format!(
                "{}: field {name}: missing; rewrite it with `powderlab policy dataset`",
                path.display()
            )
        })?;
        Ok(t.to_vec2::<f64>()?)
    };
    super::features::check_layout(
        path,
        &meta
            .get("features")
            .map(|s| s.split(',').map(String::from).collect::<Vec<_>>())
            .unwrap_or_default(),
        &layout(),
    )?;
    let (f, th, p, ps) = (
        get("features")?,
        get("theta")?,
        get("params")?,
        get("packing_seed")?,
    );
    let c = |name: &str| -> anyhow::Result<Vec<f64>> {
        Ok(get(name)?.into_iter().map(|r| r[0]).collect())
    };
    let hs = c("hindsight")?;
    let (loss, ind, sl, ro, pss, sc, cp) = (
        c("loss")?,
        c("indicator")?,
        c("start_loss")?,
        c("rollouts")?,
        c("particle_substeps")?,
        c("scene")?,
        c("copy")?,
    );
    Ok((0..f.len())
        .map(|i| Sample {
            scene: sc[i] as usize,
            copy: cp[i] as usize,
            draw: Draw {
                fill_height: p[i][0],
                friction_deg: p[i][1],
                density: p[i][2],
                youngs_modulus: p[i][3],
                source_x: p[i][4],
                cup_distance: p[i][5],
                target_g: p[i][6],
                packing_seed: ((ps[i][0] as u64) << 32) | ps[i][1] as u64,
            },
            features: f[i].clone(),
            theta: Theta(std::array::from_fn(|j| th[i][j])),
            loss: loss[i],
            indicator: ind[i],
            start_loss: sl[i],
            rollouts: ro[i],
            particle_substeps: pss[i],
            hindsight: hs[i] != 0.0,
        })
        .collect())
}
