//! `powderlab optimize`: skill optimisation of a scene's tool by gradient descent through the
//! simulation, and the baselines on the same rollout budget.

use anyhow::{bail, Context, Result};
use powderlab::skills::Theta;
use std::path::PathBuf;

/// Optimise the skill parameters of the scene's tool (gradient descent, and the baselines
/// on the same rollout budget); writes metrics.csv, summary.json, indicator.svg, best.rrd.
#[derive(clap::Args)]
pub struct Args {
    /// The scene whose tool has a skill control.
    scene: PathBuf,
    /// grad, cmaes, sac, random, smoothed, hybrid, carry, line, ray, paper (the first four, 30 rollouts
    /// each), default (line, sac, cmaes, random at equal compute: the benchmark's verdict, see
    /// docs/results/optimisation.md) or all (comma separated). Default: default.
    #[arg(long, value_delimiter = ',')]
    method: Vec<String>,
    /// Rollouts per seed and method (the gradient method's epochs); with --equal-compute, the
    /// compute of that many forward rollouts. Default: 20 for the default set, else 30.
    #[arg(long)]
    epochs: Option<usize>,
    /// Seeds, each with its own Θ_init.
    #[arg(long, default_value_t = 3)]
    seeds: usize,
    /// The first seed: the run's seeds are first-seed, first-seed + 1, … (seeds 0–9 chose the
    /// optimisers' settings; a verdict on fresh data starts at 10).
    #[arg(long, default_value_t = 0)]
    first_seed: usize,
    /// Run directory (default: runs/<scene name>).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Continue an interrupted run in --out.
    #[arg(long)]
    resume: bool,
    /// Worker threads (default: the scene's setting; 0 = all cores).
    #[arg(long, value_parser = super::threads_arg)]
    threads: Option<usize>,
    /// RMSprop learning rate.
    #[arg(long, default_value_t = 0.05)]
    lr: f64,
    /// Last epoch of the curriculum's scoop-only phase (θ_d, θ_s, θ_l).
    #[arg(long, default_value_t = 15)]
    curriculum_switch: usize,
    /// Scale each gradient to unit length before RMSprop (not the paper's method; see
    /// `docs/results/skill_optimisation.md`).
    #[arg(long)]
    grad_normalize: bool,
    /// Clip each gradient to the median length of the seed's gradients so far before RMSprop
    /// (not the paper's method; see `docs/results/skill_optimisation.md`).
    #[arg(long)]
    grad_clip_median: bool,
    /// CMA-ES samples per generation.
    #[arg(long, default_value_t = 6)]
    cmaes_population: usize,
    /// CMA-ES initial step size (Θ units).
    #[arg(long, default_value_t = 0.5)]
    cmaes_sigma: f64,
    /// SAC minibatch size.
    #[arg(long, default_value_t = 8)]
    sac_batch: usize,
    /// SAC gradient steps after each rollout.
    #[arg(long, default_value_t = 20)]
    sac_updates: usize,
    /// The smoothed method's gradient rollouts per step.
    #[arg(long, default_value_t = 4)]
    smooth_samples: usize,
    /// The smoothed method's noise on Θ (standard deviation).
    #[arg(long, default_value_t = 0.05)]
    smooth_sigma: f64,
    /// The smoothed method's noise on the powder's initial positions, as a fraction of the
    /// particle spacing (seed B's initial-state noise; 0 = Θ's noise only).
    #[arg(long, default_value_t = 0.0)]
    smooth_packing: f64,
    /// Give every method the compute of --epochs forward rollouts: grad and smoothed run
    /// --epochs/(1 + backward cost) gradient rollouts. The hybrid always counts this way, and
    /// the default set always runs so.
    #[arg(long)]
    equal_compute: bool,
    /// The hybrid's share of the budget spent on its Sobol points before the trust region
    /// (in (0, 1)).
    #[arg(long, default_value_t = 0.5)]
    hybrid_global: f64,
    /// Memory budget of a backward pass's tape in MB.
    #[arg(long, default_value_t = 1024)]
    budget_mb: usize,
    /// Start every seed at the Θ in this JSON file (`demo fit`'s fit.json, or any object with
    /// a "theta" of five values in [-1, 1]) instead of at the seed's random Θ_init.
    #[arg(long)]
    init: Option<PathBuf>,
    /// Print the summary as one JSON object.
    #[arg(long)]
    json: bool,
}

/// The Θ of a JSON file's "theta" field, or a one-line error naming the file and the field.
pub fn read_theta(path: &std::path::Path) -> Result<Theta> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("{}: cannot read the file", path.display()))?;
    let v: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| anyhow::anyhow!("{}: not JSON ({e})", path.display()))?;
    let theta: Option<Theta> = v["theta"].as_array().and_then(|a| {
        let xs: Vec<f64> = a.iter().filter_map(|x| x.as_f64()).collect();
        <[f64; 5]>::try_from(xs.as_slice()).ok().map(Theta)
    });
    match theta {
        Some(t) if t.iter().all(|x| (-1.0..=1.0).contains(x)) => Ok(t),
        _ => bail!(
            "{}: theta = {}: expected five numbers in [-1, 1] (the fit.json of `powderlab demo fit`)",
            path.display(),
            v["theta"]
        ),
    }
}

/// Runs the command.
pub fn run(args: Args) -> Result<()> {
    let Args {
        scene,
        method,
        epochs,
        seeds,
        first_seed,
        out,
        resume,
        threads,
        lr,
        curriculum_switch,
        grad_normalize,
        grad_clip_median,
        cmaes_population,
        cmaes_sigma,
        sac_batch,
        sac_updates,
        smooth_samples,
        smooth_sigma,
        smooth_packing,
        equal_compute,
        hybrid_global,
        budget_mb,
        init,
        json: json_out,
    } = args;
    let init = init.as_deref().map(read_theta).transpose()?;
    use powderlab::lab::optim::{self, Method};
    // No --method, or `default`: the benchmark's verdict at equal compute.
    let default_set = method.is_empty() || method == ["default"];
    let method = if method.is_empty() {
        vec!["default".to_string()]
    } else {
        method
    };
    let equal_compute = equal_compute || default_set;
    let epochs = epochs.unwrap_or(if default_set {
        Method::DEFAULT_BUDGET
    } else {
        30
    });
    // Each method once, in the order first named (`--method grad,all` runs grad once).
    let mut methods: Vec<Method> = Vec::new();
    for m in &method {
        match Method::parse_list(m) {
            Some(ms) => {
                for m in ms {
                    if !methods.contains(&m) {
                        methods.push(m);
                    }
                }
            }
            None => {
                bail!("--method {m}: expected grad, cmaes, sac, random, smoothed, hybrid, carry, line, ray, paper, default or all")
            }
        }
    }
    if !(lr > 0.0 && lr.is_finite()) {
        bail!("--lr {lr}: expected a positive learning rate");
    }
    if !(cmaes_sigma > 0.0 && cmaes_sigma.is_finite()) {
        bail!("--cmaes-sigma {cmaes_sigma}: expected a positive step size");
    }
    if cmaes_population < 2 {
        bail!("--cmaes-population {cmaes_population}: expected at least 2");
    }
    if sac_batch == 0 {
        bail!("--sac-batch 0: expected at least 1");
    }
    if smooth_samples < 2 {
        bail!(
            "--smooth-samples {smooth_samples}: expected at least 2 (the estimates need a spread)"
        );
    }
    if !(smooth_sigma > 0.0 && smooth_sigma.is_finite()) {
        bail!(
            "--smooth-sigma {smooth_sigma}: expected a positive standard deviation, such as 0.05"
        );
    }
    if !(hybrid_global > 0.0 && hybrid_global < 1.0) {
        bail!("--hybrid-global {hybrid_global}: expected a share of the budget in (0, 1), such as 0.5");
    }
    if !(smooth_packing >= 0.0 && smooth_packing.is_finite()) {
        bail!("--smooth-packing {smooth_packing}: expected a fraction of the particle spacing, 0 or more, such as 0.1");
    }
    let sc = powderlab::scene::Scene::load(&scene)?;
    let problem = optim::problem::Problem::new(sc.clone(), budget_mb << 20)?;
    let threads = threads.unwrap_or(sc.simulation.threads);
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build_global()
        .context("starting the worker threads")?;
    let out =
        out.unwrap_or_else(|| PathBuf::from("runs").join(scene.file_stem().unwrap_or_default()));
    let settings = optim::Settings {
        scene_hash: sc.fingerprint(),
        methods,
        epochs,
        seeds,
        first_seed,
        rmsprop: optim::rmsprop::RmsProp {
            lr,
            switch_epoch: curriculum_switch,
            normalize: grad_normalize,
            clip_median: grad_clip_median,
            ..Default::default()
        },
        cmaes: optim::cma::CmaConfig {
            sigma0: cmaes_sigma,
            population: cmaes_population,
        },
        sac: optim::sac::SacConfig {
            batch: sac_batch,
            updates_per_rollout: sac_updates,
            ..Default::default()
        },
        smoothing: optim::SmoothingConfig {
            samples: smooth_samples,
            sigma: smooth_sigma,
            packing: smooth_packing,
        },
        hybrid: optim::HybridConfig {
            global: hybrid_global,
            ..Default::default()
        },
        equal_compute,
        tape_budget: budget_mb << 20,
        init,
    };
    if !json_out {
        // What the run may cost: each rollout at most the longest horizon any Θ gives.
        let mut sim = problem.simulation(problem.scene_theta(), true)?;
        let longest = match &sc.colliders[problem.tool].control {
            Some(powderlab::scene::ControlSpec::Skill(sk)) => {
                sc.simulation.steps.unwrap_or_else(|| {
                    let bound = sk.step_bound(
                        sc.simulation.dt,
                        powderlab::scene::Scene::tool_bottom(&sc.colliders[problem.tool]),
                    );
                    bound.iter().map(|b| b.0).sum::<f64>().ceil() as usize
                })
            }
            _ => sim.horizon,
        };
        let rollout = sim.work(longest);
        let all = settings.forward_rollouts();
        let total = rollout.times(all);
        eprintln!(
            "work: a rollout at most {}; {all:.0} forward rollouts' worth in all: at most {:.2e} particle-substeps, about {} at that rate",
            rollout.describe(),
            total.particle_substeps(),
            total.duration()
        );
        eprintln!(
            "{}: {} × {seeds} seeds × {epochs} {}, {} threads, out {}",
            scene.display(),
            settings
                .methods
                .iter()
                .map(|m| m.name())
                .collect::<Vec<_>>()
                .join(", "),
            if equal_compute {
                "forward rollouts' compute"
            } else {
                "rollouts"
            },
            rayon::current_num_threads(),
            out.display()
        );
    }
    let r = optim::run(
        &problem,
        &optim::Options {
            settings,
            out: out.clone(),
            resume,
            quiet: json_out,
        },
    )?;
    if json_out {
        println!("{}", r.summary);
        return Ok(());
    }
    let unit = r.summary["indicator_unit"].as_str().unwrap_or("");
    println!(
        "{:<8} {:>24} {:>18} {:>24} {:>14} {:>9} {:>9}",
        "method",
        format!("dose error ({unit})"),
        "signed indicator",
        "dose error, equal compute",
        "G p-substeps",
        "rollouts",
        "wall s"
    );
    if let Some(ms) = r.summary["methods"].as_object() {
        for (name, m) in ms {
            let f = |k: &str| m[k].as_f64().unwrap_or(f64::NAN);
            let e = |k: &str| m["equal_compute"][k].as_f64().unwrap_or(f64::NAN);
            println!(
                "{:<8} {:>24} {:>18} {:>24} {:>14.3} {:>9} {:>9.1}",
                name,
                format!(
                    "{:.3} ± {:.3}",
                    f("final_dose_error_mean"),
                    f("final_dose_error_std")
                ),
                format!("{:+.3}", f("final_indicator_mean")),
                format!(
                    "{:.3} ± {:.3} ({:.1})",
                    e("dose_error_mean"),
                    e("dose_error_std"),
                    e("rollouts_mean")
                ),
                f("particle_substeps_per_seed_mean") / 1e9,
                m["rollouts_per_seed"].as_u64().unwrap_or(0) * seeds as u64,
                f("wall_s")
            );
        }
    }
    eprintln!(
        "best so far = {}; equal compute = each seed's rollouts up to the fewest particle-substeps any method spent on it (a backward pass at {}x a forward), with the mean rollouts that fit in brackets",
        r.summary["selection"].as_str().unwrap_or(""),
        r.summary["backward_cost"]
    );
    eprintln!(
        "{} rollouts simulated, {} replayed from the journal; results in {}",
        r.ran,
        r.replayed,
        out.display()
    );
    Ok(())
}
