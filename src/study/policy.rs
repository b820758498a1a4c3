//! `study policy`: the whole of seed B's Sim2Real step on the randomised dosing scene, and its
//! page (docs/results/policy.md, policy.svg).
//!
//! The steps: the dataset (`policy::dataset`); the held-out baselines (the per-scene optimiser
//! and a random Θ); the supervised fit; the REINFORCE fine-tune; both policies and the warm
//! start on the held-out scenes. Every step keeps what it computed under `dir`, so a killed
//! study resumes; the fit is deterministic and seconds long, so it is simply redone.

use super::optimizers::{p_text, wilcoxon_less};
use crate::optim::rmsprop::median;
use crate::policy::anchor::{self, AnchorConfig};
use crate::policy::dataset::{self, Sample};
use crate::policy::eval::{self, Candidate, EvalConfig, SceneEval};
use crate::policy::net::{self, Policy, TrainConfig, TrainPoint};
use crate::policy::reinforce::{Iteration, ReinforceConfig};
use crate::policy::{features, tune};
use crate::scene::Scene;
use plotters::prelude::*;
use serde::{Deserialize, Serialize};
use std::fmt::Write;
use std::path::Path;

/// Every setting of the study.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Settings {
    pub dataset: dataset::Config,
    pub train: TrainConfig,
    pub anchor: AnchorConfig,
    pub finetune: ReinforceConfig,
    pub eval: EvalConfig,
}

/// What the study found.
pub struct Outcome {
    pub samples: Vec<Sample>,
    /// The optimised scenes with their labels searched again from the first fit's Θ.
    pub anchored: Vec<Sample>,
    /// The first fit's curve (on the dataset's labels) and the policy's (on the anchored ones).
    pub first_curve: Vec<TrainPoint>,
    pub curve: Vec<TrainPoint>,
    pub iterations: Vec<Iteration>,
    /// Particle-substeps the fine-tune's episodes simulated.
    pub finetune_cost: f64,
    pub rows: Vec<SceneEval>,
}

/// Runs (or resumes) the study of `base` in `dir`; `progress(step, done, of)` hears of it.
pub fn run(
    base: &Scene,
    s: &Settings,
    dir: &Path,
    progress: &(dyn Fn(&str, usize, usize) + Sync),
) -> anyhow::Result<Outcome> {
    crate::util::create_output_dir(dir, "--out")?;
    let n = s.dataset.scenes;
    let samples = dataset::generate(base, &s.dataset, &dir.join("dataset"), &|k| {
        progress("dataset", k, n)
    })?;
    dataset::write(&dir.join("dataset/dataset.safetensors"), &samples)?;
    let m = s.eval.scenes;
    eval::run(base, &s.eval, &dir.join("eval"), &[], &|k| {
        progress("held-out optimiser and random Θ", k, m)
    })?;
    progress("fit", 0, 1);
    let (first, first_curve) = net::train(&samples, &s.train)?;
    first.save(&dir.join("policy-dataset-labels.safetensors"))?;
    let n_opt = samples.iter().filter(|x| x.copy == 0).count();
    let anchored = anchor::anchor(
        base,
        &first,
        &samples,
        &s.anchor,
        &dir.join(format!("anchor-{}", first.fingerprint()?)),
        &|k| progress("anchoring the labels", k, n_opt),
    )?;
    let (policy, curve) = net::train(&anchored, &s.train)?;
    let distilled = dir.join("policy.safetensors");
    policy.save(&distilled)?;
    let fp = policy.fingerprint()?;
    let tuned = Policy::load(&distilled, &features::layout())?;
    let iters = s.finetune.iterations;
    let (iterations, finetune_cost) = tune::finetune_scenes(
        base,
        &tuned,
        &samples,
        &s.finetune,
        &dir.join(format!("finetune-{fp}")),
        &mut |it| progress("fine-tune", it.iteration + 1, iters),
    )?;
    let finetuned = dir.join("finetuned.safetensors");
    tuned.save(&finetuned)?;
    let candidates = [
        Candidate {
            name: "policy",
            policy: &policy,
            fingerprint: fp,
        },
        Candidate {
            name: "finetuned",
            policy: &tuned,
            fingerprint: tuned.fingerprint()?,
        },
        Candidate {
            name: "first",
            policy: &first,
            fingerprint: first.fingerprint()?,
        },
    ];
    let rows = eval::run(base, &s.eval, &dir.join("eval"), &candidates, &|k| {
        progress("held-out policies", k, m)
    })?;
    Ok(Outcome {
        samples,
        anchored,
        first_curve,
        curve,
        iterations,
        finetune_cost,
        rows,
    })
}

fn mean(v: &[f64]) -> f64 {
    super::planning::mean_std(v).0
}

fn std(v: &[f64]) -> f64 {
    super::planning::mean_std(v).1
}

/// The rows' column of `method` (a trial's field).
fn column(rows: &[SceneEval], method: &str, f: impl Fn(&eval::Trial) -> f64) -> Vec<f64> {
    rows.iter().filter_map(|r| r.get(method).map(&f)).collect()
}

/// The page.
pub fn report(o: &Outcome, s: &Settings, scene: &Scene, command: &str, machine: &str) -> String {
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# A skill policy over randomised scenes (seed B's Sim2Real step)\n"
    );
    let _ = writeln!(md, "Regenerate: `{command}` (about two hours on this machine from scratch, about half of it the dataset; it keeps every rollout's result under its `--out` and resumes after a kill).  ");
    let _ = writeln!(md, "Machine: {machine}.\n");
    let r = scene.randomize.as_ref();
    let range = |v: Option<(f64, f64)>, scale: f64, unit: &str| {
        v.map_or("fixed".to_string(), |(a, b)| {
            format!("{}–{} {unit}", a * scale, b * scale)
        })
    };
    let _ = writeln!(
        md,
        "**The task.** `{}`: one scoop and a partial pour, dosing a target mass into the target cup. Every scene is drawn from the file's `randomize` ranges: fill height {}, friction angle {}, density {}, Young's modulus {} (log-uniform), source cup at x = {}, cup distance {}, target {}, and a fresh packing seed. The policy sees {} features: these seven (ln E for E), the mass delivered so far (0 for one scoop) and a {}×{} height field of the powder in the source cup.\n",
        scene.path.display(),
        range(r.and_then(|r| r.fill_height), 1000.0, "mm"),
        range(r.and_then(|r| r.friction_deg), 1.0, "°"),
        range(r.and_then(|r| r.density), 1.0, "kg/m³"),
        range(r.and_then(|r| r.youngs_modulus), 1e-3, "kPa"),
        range(r.and_then(|r| r.source_x), 1000.0, "mm"),
        range(r.and_then(|r| r.cup_distance), 1000.0, "mm"),
        range(r.and_then(|r| r.target_g), 1.0, "g"),
        features::layout().len(),
        features::HEIGHT_CELLS,
        features::HEIGHT_CELLS,
    );
    // The dataset.
    let opt: Vec<&Sample> = o.samples.iter().filter(|x| x.copy == 0).collect();
    let aug: Vec<&Sample> = o.samples.iter().filter(|x| x.copy > 0).collect();
    let improved = aug.iter().filter(|x| x.loss < x.start_loss).count();
    let opt_err: Vec<f64> = opt.iter().map(|x| x.indicator.abs()).collect();
    let aug_err: Vec<f64> = aug.iter().map(|x| x.indicator.abs()).collect();
    let d = &s.dataset;
    let _ = writeln!(md, "## The dataset\n");
    let _ = writeln!(
        md,
        "- **{} randomised scenes**, each optimised by CMA-ES with {} forward rollouts from the scene's Θ (CMA-ES has the lowest dose error at equal compute on this task, [optimisation.md](optimisation.md); no gradient-informed method beats it). Θ\\*'s dose error: {:.3} ± {:.3} g (median {:.3} g).",
        opt.len(), d.budget, mean(&opt_err), std(&opt_err), median(&opt_err)
    );
    let _ = writeln!(
        md,
        "- **{} perturbed copies** (seed B's augmentation: {} per scene, each range moved by a normal step of {} of its width, a new packing seed), each refined from its scene's Θ\\* by {} Gauss–Newton step(s) along the adjoint gradient of the dosing loss. The step lowered the loss on {} of {} copies; the copies' labels have a dose error of {:.3} ± {:.3} g (median {:.3} g). A copy costs {:.1} forward rollouts against a scene's {}.",
        aug.len(), d.augment, d.perturb, d.augment_steps, improved, aug.len(), mean(&aug_err), std(&aug_err), median(&aug_err),
        mean(&aug.iter().map(|x| x.rollouts).collect::<Vec<_>>()), d.budget
    );
    let _ = writeln!(
        md,
        "- Stored as `dataset.safetensors` (features, Θ, the drawn parameters, loss, indicator, compute; the layout in its metadata).\n"
    );
    // The fit and the fine-tune.
    let t = &s.train;
    let last = o.curve.last();
    let best_val = o
        .curve
        .iter()
        .map(|p| p.val_mse)
        .fold(f64::INFINITY, f64::min);
    let _ = writeln!(md, "## The policy\n");
    let used = |set: &[Sample]| net::usable(set, t).len();
    let first_val = o
        .first_curve
        .iter()
        .map(|p| p.val_mse)
        .fold(f64::INFINITY, f64::min);
    let a = &s.anchor;
    let moved = o
        .anchored
        .iter()
        .filter(|x| opt.iter().any(|y| y.scene == x.scene && y.theta != x.theta))
        .count();
    let anch_err: Vec<f64> = o.anchored.iter().map(|x| x.indicator.abs()).collect();
    let _ = writeln!(
        md,
        "- **The network:** an MLP {}→{}→{}→5 (candle), inputs standardised by the training set, fitted by full-batch AdamW (lr {}, weight decay {}) for {} epochs on the mean squared error in Θ; every {}th scene (with its copies) is held out to choose the epoch. Samples whose Θ misses by more than {} g are not learnt.",
        features::layout().len(), t.hidden, t.hidden, t.lr, t.weight_decay, t.epochs, t.val_every, t.max_label_error_g
    );
    let _ = writeln!(
        md,
        "- **First fit, on the dataset's labels** ({} of {} samples usable): lowest validation MSE {:.4}. The labels lie in different modes of the landscape (similar scenes, Θ\\* far apart), so this fit learns little beyond their mean.",
        used(&o.samples), o.samples.len(), first_val
    );
    let _ = writeln!(
        md,
        "- **Anchored labels:** each optimised scene searched again by CMA-ES from the first fit's own Θ ({} rollouts, first step σ = {}), the new label kept when it doses within {} g: {} of {} scenes took one; their dose error is {:.3} ± {:.3} g (median {:.3} g).",
        a.budget, a.sigma, a.max_error_g, moved, o.anchored.len(), mean(&anch_err), std(&anch_err), median(&anch_err)
    );
    let _ = writeln!(
        md,
        "- **The distilled policy,** fitted to the anchored labels ({} of {} usable): training MSE at the end {:.4}, lowest validation MSE {:.4}.",
        used(&o.anchored), o.anchored.len(), last.map_or(f64::NAN, |p| p.train_mse), best_val
    );
    let f = &s.finetune;
    let first = o.iterations.first().map_or(f64::NAN, |i| i.mean_reward);
    let final_ = o.iterations.last().map_or(f64::NAN, |i| i.mean_reward);
    let _ = writeln!(
        md,
        "- **Fine-tuned:** REINFORCE from the distilled network, a Gaussian of σ = {} around its Θ, a leave-one-out batch baseline, reward −L (the dosing loss), {} iterations of {} episodes on the training scenes (AdamW, lr {}): {} rollouts, {:.2} G particle-substeps. The batch's mean reward went from {:.4} (first) to {:.4} (last); the batches draw different scenes, so the held-out test below is what decides.\n",
        f.sigma, f.iterations, f.batch, f.lr, f.iterations * f.batch, o.finetune_cost / 1e9, first, final_
    );
    let _ = writeln!(md, "![training and fine-tuning curves](policy.svg)\n");
    // The held-out comparison.
    let e = &s.eval;
    let rows = &o.rows;
    let opt_ps = mean(&column(rows, "optimiser", |t| t.particle_substeps));
    let _ = writeln!(md, "## On {} held-out scenes\n", rows.len());
    let _ = writeln!(
        md,
        "Scenes drawn from a stream the dataset never used. The per-scene optimiser is CMA-ES with its full budget of {} rollouts from the scene's Θ; the warm start is CMA-ES from the distilled policy's Θ with a quarter of it ({} rollouts, first step σ = {}). A method's dose error is |target − delivered| of its rollout of lowest loss. Compute is in simulated particle-substeps (a rollout's steps × substeps × particles; scenes differ in their particles and substeps).\n",
        e.budget, e.warm_budget(), eval::SIGMA_WARM
    );
    let _ = writeln!(md, "| method | dose error (g), mean ± std | median | within 0.1 g | rollouts | G particle-substeps | compute / optimiser's |");
    let _ = writeln!(md, "|---|---|---|---|---|---|---|");
    let names = [
        ("first", "first fit (dataset's labels), one rollout"),
        ("policy", "policy (distilled), one rollout"),
        ("finetuned", "policy (fine-tuned), one rollout"),
        ("random", "random Θ, one rollout"),
        ("optimiser", "per-scene optimiser, full budget"),
        ("warm", "optimiser from the policy, ¼ budget"),
    ];
    for (key, label) in names {
        let err = eval::errors(rows, key);
        if err.is_empty() {
            continue;
        }
        let ps = mean(&column(rows, key, |t| t.particle_substeps));
        let _ = writeln!(
            md,
            "| {label} | {:.3} ± {:.3} | {:.3} | {}/{} | {:.1} | {:.3} | {:.3} |",
            mean(&err),
            std(&err),
            median(&err),
            err.iter().filter(|x| **x <= 0.1).count(),
            err.len(),
            mean(&column(rows, key, |t| t.rollouts)),
            ps / 1e9,
            ps / opt_ps
        );
    }
    let (pol, ran, optm, tun, warm) = (
        eval::errors(rows, "policy"),
        eval::errors(rows, "random"),
        eval::errors(rows, "optimiser"),
        eval::errors(rows, "finetuned"),
        eval::errors(rows, "warm"),
    );
    let ratio = mean(&pol) / mean(&optm);
    let compute = mean(&column(rows, "policy", |t| t.particle_substeps)) / opt_ps;
    let p_random = wilcoxon_less(&pol, &ran);
    let p_tuned = wilcoxon_less(&tun, &pol);
    let verdict = |ok: bool| if ok { "**met**" } else { "**missed**" };
    let _ = writeln!(md, "\nThe acceptance, one line each (p: one-sided exact Wilcoxon signed-rank over the paired scenes):\n");
    let _ = writeln!(
        md,
        "- **The policy beats a random Θ:** {:.3} g against {:.3} g, p = {} — {}.",
        mean(&pol),
        mean(&ran),
        p_text(p_random),
        verdict(p_random.is_some_and(|p| p < 0.05))
    );
    let _ = writeln!(
        md,
        "- **Within 2× the optimiser's dose error at 1/30 of its compute:** {:.2}× its error ({:.3} g against {:.3} g) at {:.3} of its compute (1/{:.0}) — {}.",
        ratio, mean(&pol), mean(&optm), compute, 1.0 / compute, verdict(ratio <= 2.0 && compute <= 1.0 / 30.0 + 1e-9)
    );
    let _ = writeln!(
        md,
        "- **The fine-tune improves on the distilled policy:** {:.3} g against {:.3} g, p = {} — {}.",
        mean(&tun), mean(&pol), p_text(p_tuned), verdict(mean(&tun) < mean(&pol) && p_tuned.is_some_and(|p| p < 0.05))
    );
    let _ = writeln!(
        md,
        "- The warm start at a quarter of the budget: {:.3} g against the full optimiser's {:.3} g (p = {} that it is lower; p = {} that the full one is).",
        mean(&warm), mean(&optm), p_text(wilcoxon_less(&warm, &optm)), p_text(wilcoxon_less(&optm, &warm))
    );
    md
}

/// The training curve (train and validation MSE against epoch) and the fine-tune's mean reward
/// per iteration, side by side.
pub fn figure(
    path: &Path,
    first: &[TrainPoint],
    curve: &[TrainPoint],
    its: &[Iteration],
) -> anyhow::Result<()> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (1100, 420)).into_drawing_area();
        root.fill(&WHITE)?;
        let (l, r) = root.split_horizontally(550);
        let ys: Vec<f64> = curve
            .iter()
            .chain(first)
            .flat_map(|p| [p.train_mse, p.val_mse])
            .filter(|v| v.is_finite() && *v > 0.0)
            .collect();
        let (lo, hi) = ys
            .iter()
            .fold((f64::MAX, 0.0f64), |(a, b), v| (a.min(*v), b.max(*v)));
        let xmax = curve
            .last()
            .map_or(1, |p| p.epoch)
            .max(first.last().map_or(1, |p| p.epoch)) as f64;
        let mut c = ChartBuilder::on(&l)
            .caption("distillation: MSE in Θ", ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(36)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..xmax, (lo / 1.5..hi * 1.5).log_scale())?;
        c.configure_mesh()
            .x_desc("epoch")
            .y_desc("mean squared error")
            .light_line_style(WHITE)
            .draw()?;
        for (name, colour, get) in [
            (
                "training",
                BLUE,
                (|p: &TrainPoint| p.train_mse) as fn(&TrainPoint) -> f64,
            ),
            ("validation (anchored labels)", RED, |p: &TrainPoint| {
                p.val_mse
            }),
        ] {
            c.draw_series(LineSeries::new(
                curve
                    .iter()
                    .filter(|p| get(p).is_finite())
                    .map(|p| (p.epoch as f64, get(p))),
                colour.stroke_width(2),
            ))?
            .label(name)
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(2))
            });
        }
        let grey = RGBColor(150, 150, 150);
        c.draw_series(LineSeries::new(
            first
                .iter()
                .filter(|p| p.val_mse.is_finite())
                .map(|p| (p.epoch as f64, p.val_mse)),
            grey.stroke_width(2),
        ))?
        .label("validation, first fit (dataset's labels)")
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], grey.stroke_width(2)));
        c.configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
        let pts: Vec<(f64, f64)> = its
            .iter()
            .map(|i| (i.iteration as f64 + 1.0, i.mean_reward))
            .collect();
        let all: Vec<f64> = its.iter().flat_map(|i| i.rewards.clone()).collect();
        let (rlo, rhi) = all
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), v| (a.min(*v), b.max(*v)));
        let (rlo, rhi) = if rlo < rhi { (rlo, rhi) } else { (-1.0, 0.0) };
        let pad = 0.05 * (rhi - rlo);
        let mut c = ChartBuilder::on(&r)
            .caption(
                "fine-tune: reward −L per episode, batch mean",
                ("sans-serif", 16),
            )
            .margin(10)
            .x_label_area_size(36)
            .y_label_area_size(60)
            .build_cartesian_2d(0.5..its.len() as f64 + 0.5, rlo - pad..rhi + pad)?;
        c.configure_mesh()
            .x_desc("iteration")
            .y_desc("reward")
            .light_line_style(WHITE)
            .draw()?;
        c.draw_series(its.iter().flat_map(|i| {
            i.rewards.iter().map(move |r| {
                Circle::new((i.iteration as f64 + 1.0, *r), 2, BLUE.mix(0.4).filled())
            })
        }))?;
        c.draw_series(LineSeries::new(pts, BLACK.stroke_width(2)))?;
    }
    crate::util::write_atomic(path, svg.as_bytes())?;
    Ok(())
}
