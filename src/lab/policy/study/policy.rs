//! `study policy`: the whole of seed B's Sim2Real step on the randomised dosing scene, and its
//! page (docs/results/policy.md, policy.svg).
//!
//! The steps: the dataset (`policy::dataset`); the held-out baselines (the per-scene optimiser,
//! its answer repacked, and a random Θ); the supervised fit; the REINFORCE fine-tune; both
//! policies and the warm start on the held-out scenes. Every step keeps what it computed under `dir`, so a killed
//! study resumes; the fit is deterministic and seconds long, so it is simply redone.

use crate::lab::chart;
use crate::lab::policy::dataset::{self, Sample};
use crate::lab::policy::eval::{self, Candidate, EvalConfig, SceneEval};
use crate::lab::policy::net::{self, Policy, TrainConfig, TrainPoint};
use crate::lab::policy::reinforce::{Iteration, ReinforceConfig};
use crate::lab::policy::{features, tune};
use crate::lab::stats::median;
use crate::lab::stats::{mean, p_text, sd as std, wilcoxon_less};
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
    pub finetune: ReinforceConfig,
    pub eval: EvalConfig,
}

/// What the study found.
pub struct Outcome {
    pub samples: Vec<Sample>,
    /// The chosen fit's curve (its members' mean).
    pub curve: Vec<TrainPoint>,
    /// The chosen ensemble's validation MSE.
    pub val_mse: f64,
    /// Each hidden width tried and its ensemble's validation MSE.
    pub widths: Vec<(usize, f64)>,
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
    eval::run(base, &s.eval, &dir.join(s.eval.dir_name()), &[], &|k| {
        progress("held-out optimiser and random Θ", k, m)
    })?;
    progress("fit", 0, 1);
    let (
        net::Fit {
            policy,
            curve,
            val_mse,
        },
        widths,
    ) = net::select(&samples, &s.train, &net::WIDTHS)?;
    let distilled = dir.join("policy.safetensors");
    policy.save(&distilled)?;
    let fp = policy.fingerprint()?;
    let tuned = Policy::load(&distilled, &features::layout(), net::OUTPUTS)?;
    let iters = s.finetune.iterations;
    let contexts =
        tune::fresh_contexts(base, s.dataset.seed, (iters * s.finetune.batch / 2).max(1))?;
    let (iterations, finetune_cost) = tune::finetune_scenes(
        base,
        &tuned,
        &contexts,
        &s.finetune,
        &dir.join(format!("finetune-{fp}")),
        &mut |it| progress("fine-tune", it.iteration + 1, iters),
    )?;
    let finetuned = dir.join("finetuned.safetensors");
    tuned.save(&finetuned)?;
    let member = policy.member(0)?;
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
            name: "member",
            policy: &member,
            fingerprint: member.fingerprint()?,
        },
    ];
    let rows = eval::run(
        base,
        &s.eval,
        &dir.join(s.eval.dir_name()),
        &candidates,
        &|k| progress("held-out policies", k, m),
    )?;
    Ok(Outcome {
        samples,
        curve,
        val_mse,
        widths,
        iterations,
        finetune_cost,
        rows,
    })
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
    let _ = writeln!(md, "Regenerate: `{command}` (about two and a half hours on this machine from scratch: 92 min for the dataset, 27 for the held-out optimiser, 15 for the fine-tune; it keeps every rollout's result under its `--out` and resumes after a kill).  ");
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
    let opt: Vec<&Sample> = o
        .samples
        .iter()
        .filter(|x| x.copy == 0 && !x.hindsight)
        .collect();
    let aug: Vec<&Sample> = o
        .samples
        .iter()
        .filter(|x| x.copy > 0 && !x.hindsight)
        .collect();
    let hind = o.samples.iter().filter(|x| x.hindsight).count();
    let improved = aug.iter().filter(|x| x.loss < x.start_loss).count();
    let opt_err: Vec<f64> = opt.iter().map(|x| x.indicator.abs()).collect();
    let aug_err: Vec<f64> = aug.iter().map(|x| x.indicator.abs()).collect();
    let reach = opt.iter().filter(|x| x.indicator > 0.1).count();
    let d = &s.dataset;
    let total: f64 = o.samples.iter().map(|x| x.particle_substeps).sum();
    let _ = writeln!(md, "## The dataset\n");
    let _ = writeln!(
        md,
        "- **{} randomised scenes**, each labelled by a root search of the dose along one family of skills: scoop to a depth, carry the spoon over the target cup, empty it (scoop angle, lift and pour angle fixed, transport = the cup distance; `policy::knob`). The mass scooped rises with the depth, so similar scenes get similar labels; an optimiser over all five parameters lands in different modes on similar scenes, and a network fitted to those learns their mean. At most {} forward rollouts per scene: the shallowest and deepest scoops, then Illinois regula falsi on the depth. Θ\\*'s dose error: {:.3} ± {:.3} g (median {:.3} g); on {} scenes the deepest scoop holds less than the target (more than 0.1 g short).",
        opt.len(), d.budget, mean(&opt_err), std(&opt_err), median(&opt_err), reach
    );
    let _ = writeln!(
        md,
        "- **{} perturbed copies** (seed B's augmentation: {} per scene, each range moved by a normal step of {} of its width, a new packing seed), each refined from its scene's Θ\\* by {} Gauss–Newton step(s) along the adjoint gradient of the dosing loss, projected on the depth. The step lowered the loss on {} of {} copies; the copies' labels have a dose error of {:.3} ± {:.3} g (median {:.3} g). A copy costs {:.1} forward rollouts.",
        aug.len(), d.augment, d.perturb, d.augment_steps, improved, aug.len(), mean(&aug_err), std(&aug_err), median(&aug_err),
        mean(&aug.iter().map(|x| x.rollouts).collect::<Vec<_>>())
    );
    let _ = writeln!(
        md,
        "- **{hind} hindsight samples:** every rollout of those searches that delivered a mass M within the target's range, kept as the exact label of its scene with target M (the target does not change the physics), at no extra rollout.\n- The dataset cost {:.2} G particle-substeps. Stored as `dataset.safetensors` (features, Θ, the drawn parameters, loss, indicator, compute, hindsight; the layout in its metadata).\n",
        total / 1e9
    );
    // The fit and the fine-tune.
    let t = &s.train;
    let last = o.curve.last();
    let best_val = o
        .curve
        .iter()
        .map(|p| p.val_mse)
        .fold(f64::INFINITY, f64::min);
    let tol = t.max_label_error_g;
    let _ = writeln!(md, "## The policy\n");
    let used = net::usable(&o.samples, t).len();
    let _ = writeln!(
        md,
        "- **The network:** the mean of {} MLPs {}→h→h→1 (candle; a deep ensemble, each member from its own initial weights), whose one output is the scoop depth; Θ is the family's member at that depth. Inputs are standardised by the training set. Each member is fitted by full-batch AdamW (lr {}, weight decay {}) for {} epochs on the mean squared error of the depth; every {}th scene (with its copies and hindsight samples) is held out to choose each member's epoch and the width h. A sample is learnt when it is its scene's answer: it doses within {tol} g of its target, or the target lies beyond the family's end and its depth is at that end. {} of {} samples are used.",
        t.members, features::layout().len(), t.lr, t.weight_decay, t.epochs, t.val_every, used, o.samples.len()
    );
    let table: Vec<String> = o
        .widths
        .iter()
        .map(|(h, v)| format!("h = {h}: {v:.5}"))
        .collect();
    let _ = writeln!(
        md,
        "- **The width,** by each ensemble's validation MSE (of the depth): {}. The chosen one is {} wide.",
        table.join(", "),
        o.widths
            .iter()
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map_or(0, |w| w.0)
    );
    let _ = writeln!(
        md,
        "- **The distilled policy:** its members' mean training MSE at the end {:.5}, and their mean validation MSE at its lowest epoch {:.5} (each member keeps its own best epoch); the ensemble's validation MSE {:.5}.",
        last.map_or(f64::NAN, |p| p.train_mse),
        best_val,
        o.val_mse
    );
    let f = &s.finetune;
    let first = o.iterations.first().map_or(f64::NAN, |i| i.mean_reward);
    let final_ = o.iterations.last().map_or(f64::NAN, |i| i.mean_reward);
    let _ = writeln!(
        md,
        "- **Fine-tuned:** REINFORCE from the distilled ensemble (every member moves with the mean), a Gaussian of σ = {} around its depth, episodes in mirrored pairs on one scene, each the other's baseline (seed B's smoothed gradient), reward −L (the dosing loss), {} iterations of {} episodes on freshly drawn scenes, neither the dataset's nor the held-out ones (AdamW, lr {}): {} rollouts, {:.2} G particle-substeps. The batch's mean reward went from {:.4} (first) to {:.4} (last); the batches draw different scenes, so the held-out test below is what decides.\n",
        f.sigma, f.iterations, f.batch, f.lr, f.iterations * f.batch, o.finetune_cost / 1e9, first, final_
    );
    let _ = writeln!(md, "![training and fine-tuning curves](policy.svg)\n");
    // The held-out comparison.
    let e = &s.eval;
    let rows = &o.rows;
    let opt_ps = mean(&column(rows, "optimiser", |t| t.particle_substeps));
    let _ = writeln!(md, "## On {} held-out scenes\n", rows.len());
    let _ = writeln!(md, "**Stream.** {}\n", s.eval.stream_text());
    let _ = writeln!(
        md,
        "Scenes drawn from a stream the dataset never used. The per-scene optimiser is `line` on all five parameters with its full budget of {} rollouts' compute (half on the scene's Θ and Sobol points, half on the root search of the dose along the adjoint's axis, a backward pass at its cost; the project's default method, compared with the others on [optimisation.md](optimisation.md)); *repacked* is its Θ run again on the same scene with another packing seed: the error of a policy that knew the optimiser's answer exactly but, like every policy here, not the grains' packing; the warm start is `line`'s root search from the distilled policy's Θ with a quarter of the budget ({}). A method's dose error is |target − delivered| of its rollout of lowest loss. Compute is in simulated particle-substeps (a rollout's steps × substeps × particles; scenes differ in their particles and substeps).\n",
        e.budget, e.warm_budget()
    );
    let _ = writeln!(md, "| method | dose error (g), mean ± std | median | within 0.1 g | rollouts | G particle-substeps | compute / optimiser's |");
    let _ = writeln!(md, "|---|---|---|---|---|---|---|");
    let names = [
        ("policy", "policy (distilled), one rollout"),
        ("member", "its first network alone, one rollout"),
        ("finetuned", "policy (fine-tuned), one rollout"),
        ("random", "random Θ, one rollout"),
        ("optimiser", "per-scene optimiser, full budget"),
        ("repacked", "optimiser's Θ, repacked, one rollout"),
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
    let one = eval::errors(rows, "member");
    if !one.is_empty() {
        let _ = writeln!(
            md,
            "- What the ensemble buys: its first network alone misses by {:.3} g, the ensemble of {} by {:.3} g (p = {} that the ensemble is better).",
            mean(&one), s.train.members, mean(&pol), p_text(wilcoxon_less(&pol, &one))
        );
    }
    let rep = eval::errors(rows, "repacked");
    let _ = writeln!(
        md,
        "- What the packing alone costs a one-rollout answer: the optimiser's own Θ on the scene repacked misses by {:.3} g, {:.2}× the optimiser's error{} (p = {} that the policy does worse than this reference).",
        mean(&rep),
        mean(&rep) / mean(&optm),
        if mean(&rep) > 2.0 * mean(&optm) {
            ", beyond the 2× target by itself: a policy blind to the grains' packing starts above it"
        } else {
            ", within the 2× target"
        },
        p_text(wilcoxon_less(&rep, &pol))
    );
    let _ = writeln!(
        md,
        "- Whether a loop closed within the one rollout does better, the spoon's pour weighed by a load cell on these draws: [pour.md](pour.md) (`powderlab study pour`)."
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
pub fn figure(path: &Path, curve: &[TrainPoint], its: &[Iteration]) -> anyhow::Result<()> {
    chart::write_svg(path, (1100, 420), |root| {
        let (l, r) = root.split_horizontally(550);
        let ys: Vec<f64> = curve
            .iter()
            .flat_map(|p| [p.train_mse, p.val_mse])
            .filter(|v| v.is_finite() && *v > 0.0)
            .collect();
        let (lo, hi) = ys
            .iter()
            .fold((f64::MAX, 0.0f64), |(a, b), v| (a.min(*v), b.max(*v)));
        let xmax = curve.last().map_or(1, |p| p.epoch) as f64;
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
            (
                "validation (every 5th training scene)",
                RED,
                |p: &TrainPoint| p.val_mse,
            ),
        ] {
            c.draw_series(LineSeries::new(
                curve
                    .iter()
                    .filter(|p| get(p).is_finite())
                    .map(|p| (p.epoch as f64, get(p))),
                colour.stroke_width(2),
            ))?
            .label(name)
            .legend(chart::key(colour.stroke_width(2)));
        }
        chart::legend(&mut c, SeriesLabelPosition::MiddleRight, None)?;
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
        Ok(())
    })
}
