//! `powderlab study`: error against run time, and time per substep against the problem size.
//! Each configuration runs in a child process (this executable with `--config`), so that its
//! peak memory is its own.

mod optimisation;
mod tasks;

use anyhow::{bail, Context, Result};
use powderlab::lab::study;
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

/// Accuracy and cost. `error-vs-time` sweeps the grid resolution, the particles per cell
/// and the substeps on the column collapse and the transport task, and writes
/// results.json, error_vs_time.csv, error_vs_time.md and error_vs_time.svg to --out;
/// `growth` times a substep of `sand_box` variants against the particle count and the grid
/// and writes growth.json, growth.csv and growth.svg.
#[derive(clap::Args)]
pub struct Args {
    /// The study to run: error-vs-time, or growth (time per substep against particles and grid).
    study: String,
    /// Output folder.
    #[arg(long, default_value = "study")]
    out: PathBuf,
    /// The transport task's scene (error-vs-time; default scenes/powder_transport.ron).
    #[arg(long)]
    scene: Option<PathBuf>,
    /// A seconds-long version of the study (tests and CI).
    #[arg(long)]
    quick: bool,
    /// landscape: quasi-random rollouts to run (default 256; 16 with --quick).
    #[arg(long)]
    samples: Option<usize>,
    /// optimizers: the skill scenes to benchmark (comma separated; default the transport task
    /// and the precise-dosing task). planning: the plan scenes (default
    /// scenes/multi_scoop_dosing.ron and scenes/plate_push.ron).
    #[arg(long, value_delimiter = ',')]
    tasks: Vec<PathBuf>,
    /// optimizers: paired seeds per task.
    #[arg(long, default_value_t = 10)]
    seeds: usize,
    /// optimizers: compute per seed and method, in forward rollouts.
    #[arg(long, default_value_t = 20)]
    budget: usize,
    /// optimizers: the methods (comma separated, or all).
    #[arg(long, value_delimiter = ',', default_value = "all")]
    method: Vec<String>,
    /// refine: knots per control channel of each dimension tried (6 parameters per knot).
    #[arg(long, value_delimiter = ',', default_values_t = [1usize, 5, 16])]
    knots: Vec<usize>,
    /// refine: start each seed from a Sobol point whose plain skill delivers at least this much
    /// more than the target (the target's unit), instead of Θ_init(k).
    #[arg(long)]
    over: Option<f64>,
    /// optimizers, refine, directions: where the page goes.
    #[arg(long, default_value = "docs/results")]
    results: PathBuf,
    /// optimizers: the page's name: NAME.md, NAME.svg and NAME.csv in --results.
    #[arg(long, default_value = "optimisation")]
    page: String,
    /// reliability: mutated scenes to run through `simulate`.
    #[arg(long, default_value_t = 10_000)]
    cases: usize,
    /// reliability: address-space cap per process, in GB.
    #[arg(long, default_value_t = 8.0)]
    cap_gb: f64,
    /// reliability: wall-clock limit per process, in seconds.
    #[arg(long, default_value_t = 20.0)]
    timeout_s: f64,
    /// reliability: processes side by side.
    #[arg(long, default_value_t = 2)]
    jobs: usize,
    /// Keep the configurations already finished in OUT/results.json.
    #[arg(long)]
    resume: bool,
    #[arg(long, value_parser = super::threads_arg)]
    threads: Option<usize>,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
    /// Run one configuration (JSON) and print its result: the study runs each
    /// configuration in a process of its own, so that its peak memory is its own.
    #[arg(long, hide = true)]
    config: Option<String>,
}

/// Runs one configuration of `study` in a child process (this executable with `--config`), so
/// that its peak memory is its own, and reads the result it prints as its last line.
fn run_in_child<C: serde::Serialize, R: serde::de::DeserializeOwned>(
    exe: &std::path::Path,
    study: &str,
    cfg: &C,
) -> Result<R> {
    let out = std::process::Command::new(exe)
        .args(["study", study, "--config"])
        .arg(serde_json::to_string(cfg)?)
        .stdin(std::process::Stdio::null())
        .output()
        .with_context(|| format!("cannot start {}", exe.display()))?;
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        bail!(
            "{} ({})",
            err.lines().last().unwrap_or("no message").trim(),
            out.status
        );
    }
    let text = String::from_utf8_lossy(&out.stdout);
    serde_json::from_str(text.lines().last().unwrap_or(""))
        .context("the configuration's child printed no result")
}

/// One error-vs-time configuration in a child process; a failure becomes a failed result.
fn study_child(exe: &std::path::Path, cfg: &study::Config) -> study::ConfigResult {
    run_in_child(exe, "error-vs-time", cfg).unwrap_or_else(|e| study::failed(cfg, format!("{e:#}")))
}

/// Runs the command.
pub fn run(a: Args) -> Result<()> {
    if a.study == "growth" {
        return growth_cmd(a);
    }
    if a.study == "landscape" {
        return optimisation::landscape_cmd(a);
    }
    if a.study == "optimizers" {
        return optimisation::optimizers_cmd(a);
    }
    if a.study == "directions" {
        return optimisation::directions_cmd(a);
    }
    if a.study == "refine" {
        return optimisation::refine_cmd(a);
    }
    if a.study == "calibration" {
        return tasks::calibration_cmd(a);
    }
    if a.study == "demonstration" {
        return tasks::demonstration_cmd(a);
    }
    if a.study == "planning" {
        return tasks::planning_cmd(a);
    }
    if a.study == "policy" {
        return tasks::policy_cmd(a);
    }
    if a.study == "pour" {
        return tasks::pour_cmd(a);
    }
    if a.study == "reliability" {
        return tasks::reliability_cmd(a);
    }
    if a.study != "error-vs-time" {
        bail!(
            "unknown study '{}': expected error-vs-time, growth, landscape, optimizers, directions, refine, calibration, demonstration, planning, policy, pour or reliability",
            a.study
        );
    }
    if let Some(c) = &a.config {
        let cfg: study::Config = serde_json::from_str(c).context("--config")?;
        let r = study::run_config(&cfg)?;
        println!("{}", serde_json::to_string(&r)?);
        return Ok(());
    }
    let scene = a
        .scene
        .clone()
        .unwrap_or_else(|| PathBuf::from("scenes/powder_transport.ron"));
    let plan = study::plan(a.quick, &scene, a.threads)?;
    // Fail fast on a scene the transport configurations cannot use.
    if let Some(cfg) = plan.iter().find(|c| c.case == study::Case::PowderTransport) {
        powderlab::lab::optim::problem::Problem::new(
            study::transport_scene(cfg)?,
            study::TAPE_BUDGET,
        )?;
    }
    let exe = std::env::current_exe().context("cannot find this executable")?;
    let pb = super::bar(plan.len() as u64, a.json);
    let start = Instant::now();
    let (results, rows) = study::run_study(
        &plan,
        &a.out,
        a.resume,
        |cfg| study_child(&exe, cfg),
        |i, cfg| {
            pb.set_position(i as u64);
            pb.set_message(cfg.label());
        },
    )?;
    pb.finish_and_clear();
    let failed: Vec<_> = results
        .iter()
        .filter_map(|r| {
            r.failed
                .as_ref()
                .map(|f| json!({ "config": r.config.label(), "error": f }))
        })
        .collect();
    let outputs = study::Outputs::in_dir(&a.out);
    if a.json {
        println!(
            "{}",
            json!({
                "rows": rows,
                "failed": failed,
                "wall_s": start.elapsed().as_secs_f64(),
                "csv": outputs.csv,
                "svg": outputs.svg,
                "results": outputs.results,
            })
        );
    } else {
        print!("{}", study::markdown(&rows));
        for f in &failed {
            eprintln!("FAILED {}: {}", f["config"], f["error"]);
        }
        eprintln!(
            "{} configurations in {:.0} s; wrote {}, {}, {} and {}",
            results.len(),
            start.elapsed().as_secs_f64(),
            outputs.csv.display(),
            outputs.svg.display(),
            outputs.markdown.display(),
            outputs.results.display()
        );
    }
    if !failed.is_empty() {
        std::process::exit(1);
    }
    Ok(())
}

/// `powderlab study growth` (`powderlab::lab::study::growth`): each configuration in a child process.
fn growth_cmd(a: Args) -> Result<()> {
    use powderlab::lab::study::growth;
    if let Some(s) = &a.scene {
        bail!(
            "study growth: --scene {} is not used: the growth study runs its own variants of scenes/sand_box.ron (the Taichi reference's scene); leave --scene out",
            s.display()
        );
    }
    if a.resume {
        bail!(
            "study growth: --resume is not supported: the study reruns every configuration (about 3 minutes); leave --resume out"
        );
    }
    let scene = PathBuf::from("scenes/sand_box.ron");
    let base = powderlab::scene::Scene::load(&scene)?;
    if let Some(c) = &a.config {
        let cfg: growth::GrowthConfig = serde_json::from_str(c).context("--config")?;
        println!(
            "{}",
            serde_json::to_string(&growth::run_config(&base, &cfg)?)?
        );
        return Ok(());
    }
    let plan = growth::plan(a.quick, a.threads.or(Some(2)));
    for cfg in &plan {
        growth::growth_scene(&base, cfg)?;
    }
    let exe = std::env::current_exe().context("cannot find this executable")?;
    powderlab::util::create_output_dir(&a.out, "--out")?;
    let outputs = growth::GrowthOutputs::in_dir(&a.out);
    let pb = super::bar(plan.len() as u64, a.json);
    let start = Instant::now();
    let mut results = Vec::new();
    for cfg in &plan {
        pb.set_message(format!("{:?} {} cells", cfg.series, cfg.cells));
        let r: growth::GrowthResult = run_in_child(&exe, "growth", cfg)
            .with_context(|| format!("growth configuration {cfg:?} failed"))?;
        results.push(r);
        // Everything measured so far is on disk, whenever the study is stopped.
        growth::write_outputs(&outputs, &results)?;
        pb.inc(1);
    }
    pb.finish_and_clear();
    let spread = growth::particle_series_spread(&results);
    let gain = growth::active_grid_gain(&results);
    let (grown, grown_dense) = (
        growth::grid_series_growth(&results, growth::Series::Grid),
        growth::grid_series_growth(&results, growth::Series::GridDense),
    );
    if a.json {
        println!(
            "{}",
            json!({
                "results": results,
                "particle_series_max_over_min_throughput": spread,
                "grid_series_largest_over_smallest": grown,
                "grid_dense_series_largest_over_smallest": grown_dense,
                "active_grid_gain": gain
                    .iter()
                    .map(|(c, r, same)| json!({"cells": c, "dense_over_active": r, "same_bits": same}))
                    .collect::<Vec<_>>(),
                "wall_s": start.elapsed().as_secs_f64(),
                "csv": outputs.csv,
                "svg": outputs.svg,
            })
        );
    } else {
        print!("{}", growth::csv(&results));
        if let Some(s) = spread {
            println!(
                "particle series: fastest/slowest throughput {s:.3} (flat within 20 % is ≤ 1.2: {})",
                if s <= 1.2 { "PASS" } else { "FAIL" }
            );
        }
        if let (Some(g), Some(d)) = (grown, grown_dense) {
            println!(
                "grid series: largest over smallest grid's time per substep {g:.2} (dense sweeps {d:.2})"
            );
        }
        for (cells, r, same) in &gain {
            println!(
                "{cells}³ grid: dense sweeps take {r:.2}× the active grid's time; final states {}",
                if *same { "equal to the bit" } else { "DIFFER" }
            );
        }
        eprintln!(
            "{} configurations in {:.0} s; wrote {}, {} and {}",
            results.len(),
            start.elapsed().as_secs_f64(),
            outputs.csv.display(),
            outputs.svg.display(),
            outputs.results.display()
        );
    }
    Ok(())
}

/// The skill problem of `--scene` (else `default`), its indicator's unit, and the worker pool
/// of `--threads` (default all cores) started.
pub(super) fn skill_problem(
    a: &Args,
    default: &str,
) -> Result<(
    PathBuf,
    powderlab::lab::optim::problem::Problem,
    &'static str,
)> {
    let scene = a.scene.clone().unwrap_or_else(|| PathBuf::from(default));
    let sc = powderlab::scene::Scene::load(&scene)?;
    let problem = powderlab::lab::optim::problem::Problem::new(sc, 1 << 30)?;
    let unit = match problem.target {
        powderlab::scene::TargetValue::Particles(_) => "particles",
        powderlab::scene::TargetValue::Grams(_) => "g",
    };
    rayon::ThreadPoolBuilder::new()
        .num_threads(a.threads.unwrap_or(0))
        .build_global()
        .context("starting the worker threads")?;
    Ok((scene, problem, unit))
}

/// Prints a study's page (or, with `--json`, one object: its wall time, `extra`'s fields and
/// the page) and says what was written where.
pub(super) fn print_page(
    a: &Args,
    md: &str,
    start: Instant,
    wrote: &str,
    extra: serde_json::Value,
) {
    let wall_s = start.elapsed().as_secs_f64();
    if a.json {
        let mut o = json!({ "wall_s": wall_s, "markdown": md });
        if let (Some(o), Some(e)) = (o.as_object_mut(), extra.as_object()) {
            o.extend(e.clone());
        }
        println!("{o}");
    } else {
        print!("{md}");
        eprintln!("{wall_s:.0} s; wrote {wrote} to {}", a.results.display());
    }
}
