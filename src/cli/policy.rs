//! `powderlab policy`: a skill policy over randomised scenes (seed B's Sim2Real step). `dataset`
//! optimises randomised scenes, `train` fits the network, `finetune` improves it with
//! REINFORCE, `eval` compares it on held-out scenes, `apply` gives one scene's Θ.

use anyhow::Result;
use powderlab::lab::policy::dataset::{self, Config};
use powderlab::lab::policy::eval::{self, Candidate, EvalConfig};
use powderlab::lab::policy::features::layout;
use powderlab::lab::policy::net::{self, Policy, TrainConfig};
use powderlab::lab::policy::reinforce::{self, ReinforceConfig};
use powderlab::lab::policy::tune;
use powderlab::scene::Scene;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    command: Sub,
}

#[derive(clap::Subcommand)]
enum Sub {
    /// Draw randomised scenes from the scene's `randomize` ranges, label each by a root search
    /// of the dose along the scoop depth, add perturbed copies refined by Gauss–Newton steps
    /// along the adjoint gradient and every rollout's own mass as a hindsight label, and write
    /// DIR/dataset.safetensors. Resumes after a kill.
    Dataset(DatasetArgs),
    /// Fit the MLP from features to Θ on DIR/dataset.safetensors (candle, full-batch AdamW);
    /// writes DIR/policy.safetensors and DIR/train.csv.
    Train(TrainArgs),
    /// Fine-tune DIR/policy.safetensors with REINFORCE on freshly drawn scenes (reward −L);
    /// writes DIR/finetuned.safetensors and DIR/finetune.csv. Resumes after a kill.
    Finetune(FinetuneArgs),
    /// Compare the policy (and the fine-tuned one, if there is one) with a random Θ, the
    /// per-scene optimiser and the optimiser warm-started from the policy, on held-out
    /// randomised scenes; writes DIR/eval.md. Resumes after a kill.
    Eval(EvalArgs),
    /// Print the policy's Θ for a scene (its own values, not a random draw); --write writes
    /// the scene with that Θ.
    Apply(ApplyArgs),
}

#[derive(clap::Args)]
struct TrainArgs {
    #[arg(long, default_value = "runs/policy")]
    dir: PathBuf,
    /// The dataset file in DIR to fit.
    #[arg(long, default_value = "dataset.safetensors")]
    data: String,
    /// Full-batch AdamW steps.
    #[arg(long, default_value_t = 3000)]
    epochs: usize,
    /// Units in each of the two hidden layers; without it, the width of lowest validation
    /// error among 8, 16, 32 and 64.
    #[arg(long)]
    hidden: Option<usize>,
    /// Learn a sample when its Θ doses within this (g) of its target, or sits at the family's
    /// end with the target beyond it.
    #[arg(long, default_value_t = net::LABEL_TOLERANCE_G)]
    max_label_error_g: f64,
    /// Networks in the ensemble.
    #[arg(long, default_value_t = net::MEMBERS)]
    members: usize,
}

#[derive(clap::Args)]
struct FinetuneArgs {
    /// The scene the dataset was made from.
    scene: PathBuf,
    #[arg(long, default_value = "runs/policy")]
    dir: PathBuf,
    #[arg(long, default_value_t = reinforce::ITERATIONS)]
    iterations: usize,
    /// Episodes (rollouts) per iteration.
    #[arg(long, default_value_t = reinforce::BATCH)]
    batch: usize,
    /// The Gaussian's standard deviation, in the knob's units.
    #[arg(long, default_value_t = reinforce::SIGMA)]
    sigma: f64,
    #[arg(long, default_value_t = reinforce::LR)]
    lr: f64,
}

#[derive(clap::Args)]
struct EvalArgs {
    /// The scene the dataset was made from.
    scene: PathBuf,
    #[arg(long, default_value = "runs/policy")]
    dir: PathBuf,
    /// Held-out randomised scenes.
    #[arg(long, default_value_t = 20)]
    scenes: usize,
    /// The per-scene optimiser's full budget (forward rollouts).
    #[arg(long, default_value_t = 30)]
    budget: usize,
    /// The dataset's seed (the held-out scenes come from a stream derived from it).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// The first held-out draw: draws 0–19 chose the policy's design; 20 and above are fresh.
    #[arg(long, default_value_t = 0)]
    first_draw: usize,
}

#[derive(clap::Args)]
struct ApplyArgs {
    /// A scene whose features match the policy's (a skill scene with a `randomize` section).
    scene: PathBuf,
    /// The policy file.
    #[arg(long, default_value = "runs/policy/policy.safetensors")]
    policy: PathBuf,
    /// Write the scene with the policy's Θ here (RON).
    #[arg(long)]
    write: Option<PathBuf>,
}

#[derive(clap::Args)]
struct DatasetArgs {
    /// A scene with a `randomize` section (scenes/policy_dosing.ron).
    scene: PathBuf,
    /// The policy's folder.
    #[arg(long, default_value = "runs/policy")]
    dir: PathBuf,
    /// Randomised scenes to label.
    #[arg(long, default_value_t = dataset::SCENES)]
    scenes: usize,
    /// At most this many forward rollouts for the root search on each scene.
    #[arg(long, default_value_t = 10)]
    budget: usize,
    /// Perturbed copies of each scene (seed B's augmentation).
    #[arg(long, default_value_t = 2)]
    augment: usize,
    /// Gradient steps on each perturbed copy.
    #[arg(long, default_value_t = 1)]
    augment_steps: usize,
    /// The perturbation's standard deviation, as a share of each range's width.
    #[arg(long, default_value_t = 0.1)]
    perturb: f64,
    /// The stream the scenes are drawn from.
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

pub fn run(a: Args) -> Result<()> {
    match a.command {
        Sub::Dataset(d) => dataset_cmd(d),
        Sub::Train(t) => train_cmd(t),
        Sub::Finetune(f) => finetune_cmd(f),
        Sub::Eval(e) => eval_cmd(e),
        Sub::Apply(a) => apply_cmd(a),
    }
}

/// The settings of a dataset of `scene`.
fn dataset_config(scene: &Scene, d: &DatasetArgs) -> Config {
    Config {
        scene_hash: scene.fingerprint(),
        scenes: d.scenes,
        budget: d.budget,
        augment: d.augment,
        augment_steps: d.augment_steps,
        perturb: d.perturb,
        seed: d.seed,
    }
}

fn dataset_cmd(d: DatasetArgs) -> Result<()> {
    let scene = Scene::load(&d.scene)?;
    dataset::spec_of(&scene)?;
    let cfg = dataset_config(&scene, &d);
    let per_scene = d.budget as f64
        + d.augment as f64
            * (d.augment_steps as f64 * (1.0 + powderlab::lab::optim::report::BACKWARD_COST) + 1.0);
    eprintln!(
        "{}: {} randomised scenes, at most {:.0} forward rollouts each ({} by the root search of the dose, {} perturbed copies of {} gradient steps); {} threads",
        d.scene.display(),
        d.scenes,
        per_scene,
        d.budget,
        d.augment,
        d.augment_steps,
        rayon::current_num_threads()
    );
    let pb = super::bar(d.scenes as u64, false);
    let samples = dataset::generate(&scene, &cfg, &d.dir, &|n| pb.set_position(n as u64))?;
    pb.finish_and_clear();
    let path = d.dir.join("dataset.safetensors");
    dataset::write(&path, &samples)?;
    let errs: Vec<f64> = samples
        .iter()
        .filter(|s| s.copy == 0 && !s.hindsight)
        .map(|s| s.indicator.abs())
        .collect();
    let aug: Vec<f64> = samples
        .iter()
        .filter(|s| s.copy > 0 && !s.hindsight)
        .map(|s| s.indicator.abs())
        .collect();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    println!(
        "{}: {} samples ({} hindsight); labelled scenes' dose error {:.3} g on average, perturbed copies' {:.3} g",
        path.display(),
        samples.len(),
        samples.iter().filter(|s| s.hindsight).count(),
        mean(&errs),
        mean(&aug)
    );
    Ok(())
}

fn train_cmd(t: TrainArgs) -> Result<()> {
    let samples = dataset::read(&t.dir.join(&t.data))?;
    let cfg = TrainConfig {
        epochs: t.epochs,
        max_label_error_g: t.max_label_error_g,
        members: t.members,
        ..TrainConfig::default()
    };
    let used = net::usable(&samples, &cfg).len();
    let widths = t.hidden.map_or(net::WIDTHS.to_vec(), |h| vec![h]);
    let (
        net::Fit {
            policy,
            curve,
            val_mse,
        },
        _,
    ) = net::select(&samples, &cfg, &widths)?;
    let path = t.dir.join("policy.safetensors");
    policy.save(&path)?;
    let mut csv = String::from("epoch,train_mse,val_mse\n");
    for p in &curve {
        csv += &format!("{},{},{}\n", p.epoch, p.train_mse, p.val_mse);
    }
    powderlab::util::write_atomic(&t.dir.join("train.csv"), csv.as_bytes())?;
    let last = curve.last().map_or(f64::NAN, |p| p.train_mse);
    println!(
        "{}: {} networks {} wide, fitted on {used} of {} samples (their scene's answers, within {} g); training MSE {last:.4}, the ensemble's validation MSE {val_mse:.4}",
        path.display(),
        policy.members.len(),
        policy.hidden,
        samples.len(),
        cfg.max_label_error_g
    );
    Ok(())
}

fn finetune_cmd(f: FinetuneArgs) -> Result<()> {
    let scene = Scene::load(&f.scene)?;
    dataset::spec_of(&scene)?;
    let distilled = f.dir.join("policy.safetensors");
    let policy = Policy::load(&distilled, &layout(), net::OUTPUTS)?;
    let cfg = ReinforceConfig {
        iterations: f.iterations,
        batch: f.batch,
        sigma: f.sigma,
        lr: f.lr,
        seed: 0,
    };
    let fp = policy.fingerprint()?;
    let contexts = tune::fresh_contexts(&scene, 0, (f.iterations * f.batch / 2).max(1))?;
    let pb = super::bar(f.iterations as u64, false);
    let mut csv = String::from("iteration,mean_reward\n");
    let (_, spent) = tune::finetune_scenes(
        &scene,
        &policy,
        &contexts,
        &cfg,
        &f.dir.join(format!("finetune-{fp}")),
        &mut |it| {
            pb.inc(1);
            pb.set_message(format!("mean reward {:.4}", it.mean_reward));
            csv += &format!("{},{}\n", it.iteration, it.mean_reward);
        },
    )?;
    pb.finish_and_clear();
    let path = f.dir.join("finetuned.safetensors");
    policy.save(&path)?;
    powderlab::util::write_atomic(&f.dir.join("finetune.csv"), csv.as_bytes())?;
    println!(
        "{}: {} episodes, {:.2} G particle-substeps",
        path.display(),
        f.iterations * f.batch,
        spent / 1e9
    );
    Ok(())
}

fn eval_cmd(e: EvalArgs) -> Result<()> {
    let scene = Scene::load(&e.scene)?;
    dataset::spec_of(&scene)?;
    let cfg = EvalConfig {
        scenes: e.scenes,
        budget: e.budget,
        seed: e.seed,
        first_draw: e.first_draw,
    };
    let mut loaded = Vec::new();
    for name in ["policy", "finetuned"] {
        let path = e.dir.join(format!("{name}.safetensors"));
        if name == "policy" || path.exists() {
            let p = Policy::load(&path, &layout(), net::OUTPUTS)?;
            let fp = p.fingerprint()?;
            loaded.push((name, p, fp));
        }
    }
    let candidates: Vec<Candidate> = loaded
        .iter()
        .map(|(name, p, fp)| Candidate {
            name,
            policy: p,
            fingerprint: fp.clone(),
        })
        .collect();
    let pb = super::bar(e.scenes as u64, false);
    let rows = eval::run(
        &scene,
        &cfg,
        &e.dir.join(cfg.dir_name()),
        &candidates,
        &|k| pb.set_position(k as u64),
    )?;
    pb.finish_and_clear();
    let mut md =
        String::from("| method | dose error (g), mean | median | rollouts |\n|---|---|---|---|\n");
    for m in eval::METHODS {
        let err = eval::errors(&rows, m);
        if err.is_empty() {
            continue;
        }
        let ro: f64 = rows
            .iter()
            .filter_map(|r| r.get(m))
            .map(|t| t.rollouts)
            .sum::<f64>()
            / err.len() as f64;
        md += &format!(
            "| {m} | {:.3} | {:.3} | {ro:.1} |\n",
            err.iter().sum::<f64>() / err.len() as f64,
            powderlab::lab::stats::median(&err),
        );
    }
    powderlab::util::write_atomic(&e.dir.join("eval.md"), md.as_bytes())?;
    print!("{md}");
    Ok(())
}

fn apply_cmd(a: ApplyArgs) -> Result<()> {
    let scene = Scene::load(&a.scene)?;
    let spec = dataset::spec_of(&scene)?;
    let policy = Policy::load(&a.policy, &layout(), net::OUTPUTS)?;
    let draw = spec.base(&scene);
    let (problem, f) = dataset::problem_of(&scene, &draw)?;
    let theta = policy.theta(&problem, &draw, &f)?;
    println!(
        "theta: ({:.4}, {:.4}, {:.4}, {:.4}, {:.4})",
        theta[0], theta[1], theta[2], theta[3], theta[4]
    );
    if let Some(out) = a.write {
        let s = problem.scene_at(theta);
        let text = ron::ser::to_string_pretty(&s, ron::ser::PrettyConfig::default())?;
        powderlab::util::write_atomic(&out, text.as_bytes())?;
        println!("wrote {}", out.display());
    }
    Ok(())
}
