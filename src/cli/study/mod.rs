//! `powderlab study`: error against run time, and time per substep against the problem size.
//! Each configuration runs in a child process (this executable with `--config`), so that its
//! peak memory is its own.

mod args;
mod optimisation;
mod tasks;

use anyhow::{bail, Context, Result};
use powderlab::lab::study;
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

/// The studies behind `docs/results/`, one subcommand each with its own arguments
/// (`powderlab study NAME --help`).
#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    study: args::Study,
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

/// Runs the command: the study the table names.
pub fn run(a: Args) -> Result<()> {
    use args::Study;
    match a.study {
        Study::ErrorVsTime(a) => error_vs_time_cmd(a),
        Study::Growth(a) => growth_cmd(a),
        Study::Landscape(a) => optimisation::landscape_cmd(a),
        Study::Optimizers(a) => optimisation::optimizers_cmd(a),
        Study::Directions(a) => optimisation::directions_cmd(a),
        Study::Refine(a) => optimisation::refine_cmd(a),
        Study::Calibration(a) => tasks::calibration_cmd(a),
        Study::Demonstration(a) => tasks::demonstration_cmd(a),
        Study::Planning(a) => tasks::planning_cmd(a),
        Study::Policy(a) => tasks::policy_cmd(a),
        Study::Pour(a) => tasks::pour_cmd(a),
        Study::Weighing(a) => tasks::weighing_cmd(a),
        Study::Reliability(a) => tasks::reliability_cmd(a),
    }
}

/// `powderlab study error-vs-time` (`powderlab::lab::study`): each configuration in a child
/// process.
fn error_vs_time_cmd(a: args::ErrorVsTime) -> Result<()> {
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
    let plan = study::plan(a.run.quick, &scene, a.run.threads)?;
    // Fail fast on a scene the transport configurations cannot use.
    if let Some(cfg) = plan.iter().find(|c| c.case == study::Case::PowderTransport) {
        powderlab::lab::optim::problem::Problem::new(
            study::transport_scene(cfg)?,
            study::TAPE_BUDGET,
        )?;
    }
    let exe = std::env::current_exe().context("cannot find this executable")?;
    let pb = super::bar(plan.len() as u64, a.common.json);
    let start = Instant::now();
    let (results, rows) = study::run_study(
        &plan,
        &a.common.out,
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
    let outputs = study::Outputs::in_dir(&a.common.out);
    if a.common.json {
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
fn growth_cmd(a: args::Growth) -> Result<()> {
    use powderlab::lab::study::growth;
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
    let plan = growth::plan(a.run.quick, a.run.threads.or(Some(2)));
    for cfg in &plan {
        growth::growth_scene(&base, cfg)?;
    }
    let exe = std::env::current_exe().context("cannot find this executable")?;
    powderlab::util::create_output_dir(&a.common.out, "--out")?;
    let outputs = growth::GrowthOutputs::in_dir(&a.common.out);
    let pb = super::bar(plan.len() as u64, a.common.json);
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
    if a.common.json {
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
    scene: &Option<PathBuf>,
    threads: Option<usize>,
    default: &str,
) -> Result<(
    PathBuf,
    powderlab::lab::optim::problem::Problem,
    &'static str,
)> {
    let scene = scene.clone().unwrap_or_else(|| PathBuf::from(default));
    let sc = powderlab::scene::Scene::load(&scene)?;
    let problem = powderlab::lab::optim::problem::Problem::new(sc, 1 << 30)?;
    let unit = match problem.target {
        powderlab::scene::TargetValue::Particles(_) => "particles",
        powderlab::scene::TargetValue::Grams(_) => "g",
    };
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads.unwrap_or(0))
        .build_global()
        .context("starting the worker threads")?;
    Ok((scene, problem, unit))
}

/// Prints a study's page (or, with `--json`, one object: its wall time, `extra`'s fields and
/// the page) and says what was written where.
pub(super) fn print_page(
    json: bool,
    results: &std::path::Path,
    md: &str,
    start: Instant,
    wrote: &str,
    extra: serde_json::Value,
) {
    let wall_s = start.elapsed().as_secs_f64();
    if json {
        let mut o = json!({ "wall_s": wall_s, "markdown": md });
        if let (Some(o), Some(e)) = (o.as_object_mut(), extra.as_object()) {
            o.extend(e.clone());
        }
        println!("{o}");
    } else {
        print!("{md}");
        eprintln!("{wall_s:.0} s; wrote {wrote} to {}", results.display());
    }
}
