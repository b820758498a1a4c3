//! The `powderlab` command line.

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use powderlab::metrics::frame_metrics;
use powderlab::sim::{SimOptions, Simulation};
use powderlab::study;
use powderlab::util::{check_output_file, peak_rss_bytes, write_atomic};
use powderlab::validate;
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Parser)]
#[command(
    name = "powderlab",
    version,
    about = "Differentiable MPM simulation of powders"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a scene forward, optionally recording it to a Rerun .rrd file.
    Simulate {
        scene: PathBuf,
        /// Global steps (default: the scene's horizon).
        #[arg(long)]
        steps: Option<usize>,
        /// Rerun recording to write.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Worker threads (default: the scene's setting; 0 = all cores).
        #[arg(long, value_parser = threads_arg)]
        threads: Option<usize>,
        /// Write the final particle positions and velocities as PLY.
        #[arg(long)]
        save_state: Option<PathBuf>,
    },
    /// Measure throughput (particle-substeps per second), wall time, peak memory and stages.
    Bench {
        scene: PathBuf,
        /// Global steps to time (default: the scene's horizon).
        #[arg(long)]
        steps: Option<usize>,
        #[arg(long, value_parser = threads_arg)]
        threads: Option<usize>,
        /// Time each stage separately (adds a little overhead).
        #[arg(long)]
        stages: bool,
        /// Time forward + backward (the gradient of the scene's loss) instead of the forward.
        #[arg(long)]
        backward: bool,
        /// Memory budget of the backward tape in MB.
        #[arg(long, default_value_t = 4096)]
        budget_mb: usize,
        /// Print one JSON object.
        #[arg(long)]
        json: bool,
    },
    /// Compare adjoint gradients with central differences (f64), per parameter.
    Gradcheck {
        scene: PathBuf,
        /// Parameter groups: v0, x0, material, friction, gravity, tool, skill (comma separated).
        #[arg(
            long,
            value_delimiter = ',',
            default_value = "v0,x0,material,friction,gravity"
        )]
        params: Vec<String>,
        /// Global steps (default: the scene's horizon).
        #[arg(long)]
        steps: Option<usize>,
        #[arg(long, value_parser = threads_arg)]
        threads: Option<usize>,
        /// Memory budget of the tape in MB.
        #[arg(long, default_value_t = 1024)]
        budget_mb: usize,
        /// Largest relative error that passes.
        #[arg(long, default_value_t = 1e-3)]
        tol: f64,
        /// Print one JSON object.
        #[arg(long)]
        json: bool,
    },
    /// Optimise the skill parameters of the scene's tool (gradient descent, and the baselines
    /// on the same rollout budget); writes metrics.csv, summary.json, indicator.svg, best.rrd.
    Optimize(OptimizeArgs),
    /// Check against exact solutions and published experiments.
    Validate {
        /// free_fall, bar, self_weight, incline, column_collapse, pile_angle, stability, or all
        /// (every case but stability, which has its own table).
        #[arg(default_value = "all")]
        case: String,
        /// Grid cells across the collapsing column (default 20, the published check: every
        /// large-a column, and the tallest small-a one, whose band stands 1.5× as many cells
        /// high) or the pile's column (default 40, at least 10).
        #[arg(long)]
        cells: Option<usize>,
        #[arg(long, value_parser = threads_arg)]
        threads: Option<usize>,
        /// Print one JSON object.
        #[arg(long)]
        json: bool,
        /// Also write the JSON report here.
        #[arg(long)]
        report: Option<PathBuf>,
    },
    /// Accuracy and cost. `error-vs-time` sweeps the grid resolution, the particles per cell
    /// and the substeps on the column collapse and the transport task, and writes
    /// results.json, error_vs_time.csv, error_vs_time.md and error_vs_time.svg to --out;
    /// `growth` times a substep of `sand_box` variants against the particle count and the grid
    /// and writes growth.json, growth.csv and growth.svg.
    Study(StudyArgs),
}

/// Parses `--threads`: 0 (all cores) up to [`powderlab::scene::MAX_THREADS`].
fn threads_arg(s: &str) -> Result<usize, String> {
    let max = powderlab::scene::MAX_THREADS;
    match s.parse::<usize>() {
        Ok(n) if n <= max => Ok(n),
        _ => Err(format!(
            "expected a whole number from 0 (all cores) to {max}, got '{s}'"
        )),
    }
}

fn bar(len: u64, quiet: bool) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(len);
    pb.set_style(
        ProgressStyle::with_template("{elapsed_precise} [{bar:40}] {pos}/{len} {msg} (eta {eta})")
            .expect("static template")
            .progress_chars("=> "),
    );
    pb
}

/// Runs `run` with a progress bar (hidden when `quiet`) that it moves from 0 to 1.
fn with_progress<T>(
    quiet: bool,
    message: String,
    run: impl FnOnce(&mut dyn FnMut(f64)) -> Result<T>,
) -> Result<T> {
    let pb = bar(1000, quiet);
    pb.set_message(message);
    let r = run(&mut |f| pb.set_position((f * 1000.0) as u64));
    pb.finish_and_clear();
    r
}

fn describe_stability(sim: &Simulation) {
    let s = &sim.stability;
    let p = sim.params();
    eprintln!(
        "stability: wave speed {:.3} m/s, largest speed {:.3} m/s, stable substep {:.3e} s",
        s.wave_speed, s.max_speed, s.dt_max
    );
    if s.raised() {
        eprintln!(
            "stability: Auto raised substeps from {} to {} (Δt_sub = {:.3e} s)",
            s.substeps_requested, s.substeps, p.dt_sub
        );
    }
}

fn simulate(
    scene: PathBuf,
    steps: Option<usize>,
    out: Option<PathBuf>,
    threads: Option<usize>,
    save_state: Option<PathBuf>,
) -> Result<()> {
    // Refuse an unwritable output before the run, not after it.
    if let Some(p) = &out {
        check_output_file(p, "--out")?;
    }
    if let Some(p) = &save_state {
        check_output_file(p, "--save-state")?;
    }
    let mut sim = Simulation::from_file(
        &scene,
        &SimOptions {
            threads,
            ..Default::default()
        },
    )?;
    describe_stability(&sim);
    let steps = steps.unwrap_or(sim.horizon);
    let n = sim.particle_count();
    eprintln!(
        "{}: {} particles, {} steps × {} substeps, {} threads; systems: {}",
        scene.display(),
        n,
        steps,
        sim.params().substeps,
        sim.threads(),
        sim.system_names().join(" → ")
    );
    let target = sim.scene.task.as_ref().map(|t| t.target.clone());
    #[cfg(feature = "rerun")]
    let mut recorder = match &out {
        Some(path) => {
            let mut r = powderlab::record::Recorder::for_scene(path, &mut sim.world, &sim.scene)?;
            r.frame(&mut sim.world)?;
            Some(r)
        }
        None => None,
    };
    #[cfg(not(feature = "rerun"))]
    if out.is_some() {
        bail!("--out needs the `rerun` feature: rebuild without --no-default-features");
    }
    let pb = bar(steps as u64, false);
    let start = Instant::now();
    // One set of frame metrics per step serves the energy monitor, the recording and the
    // final report.
    let mut energy = powderlab::metrics::EnergyMonitor::default();
    let mut m = frame_metrics(&mut sim.world, target.as_deref());
    energy.observe(&m);
    for _ in 0..steps {
        sim.step()?;
        m = frame_metrics(&mut sim.world, target.as_deref());
        energy.observe(&m);
        #[cfg(feature = "rerun")]
        if let Some(r) = recorder.as_mut() {
            r.frame_with(&mut sim.world, &m)?;
        }
        pb.inc(1);
    }
    pb.finish_and_clear();
    let wall = start.elapsed().as_secs_f64();
    #[cfg(feature = "rerun")]
    if let Some(r) = recorder {
        r.finish()?;
    }
    if let Some(path) = &save_state {
        powderlab::ply::write_ply(path, &sim.body_states())
            .with_context(|| format!("writing {}", path.display()))?;
    }
    let ps = n as f64 * sim.clock().total_substeps as f64;
    eprintln!(
        "done: {steps} steps in {wall:.2} s ({:.3} M particle-substeps/s); mean height {:.4} m{}",
        ps / wall / 1e6,
        m.mean_height,
        target.map_or(String::new(), |t| format!(
            "; {} particles in '{t}'",
            m.transported
        ))
    );
    report_energy(&energy, &sim.scene);
    if let Some(p) = &out {
        eprintln!("recording: {}", p.display());
    }
    if let Some(p) = &save_state {
        eprintln!("state: {}", p.display());
    }
    Ok(())
}

/// Prints the energy budget of a run and flags a spurious gain.
fn report_energy(e: &powderlab::metrics::EnergyMonitor, scene: &powderlab::scene::Scene) {
    let driven = scene.colliders.iter().any(|c| c.control.is_some());
    let verdict = if driven {
        "a driven tool does work on the powder, so a gain is not flagged"
    } else if e.spurious_gain() {
        "SPURIOUS ENERGY GAIN: the total rose above its lowest value by more than 10 % of the energy in play; reduce dt or raise substeps"
    } else {
        "no spurious gain"
    };
    eprintln!(
        "energy (kinetic + gravitational + elastic): {:.6e} J -> {:.6e} J; largest rise {:.3e} J at step {} ({:.3} % of the {:.3e} J in play): {verdict}",
        e.initial.unwrap_or(0.0),
        e.last,
        e.largest_gain,
        e.largest_gain_frame,
        100.0 * e.gain_fraction(),
        e.scale
    );
}

fn bench_backward(
    scene: PathBuf,
    steps: Option<usize>,
    threads: Option<usize>,
    budget_mb: usize,
    json_out: bool,
) -> Result<()> {
    let sc = powderlab::scene::Scene::load(&scene)?;
    let mut sim = Simulation::new(
        &sc,
        &SimOptions {
            threads,
            ..Default::default()
        },
    )?;
    let steps = steps.unwrap_or(sim.horizon);
    let n = sim.particle_count();
    let loss = powderlab::gradcheck::scene_loss(&sc);
    let start = Instant::now();
    let g = powderlab::adjoint::tape::gradient(
        &mut sim,
        steps,
        &loss,
        powderlab::adjoint::tape::Tape::Budget(budget_mb << 20),
    )?;
    let wall = start.elapsed().as_secs_f64();
    let substeps = steps * sim.params().substeps;
    let rate = n as f64 * substeps as f64 / wall;
    let peak = peak_rss_bytes();
    let dt = sc.simulation.dt;
    let tool_v: Vec<serde_json::Value> = g
        .controls
        .iter()
        .map(|(name, u)| {
            let s: [f64; 3] = std::array::from_fn(|k| u.iter().map(|u| u[k] * dt).sum());
            json!({ "tool": name, "dloss_dvelocity": s })
        })
        .collect();
    let gv0: glam::DVec3 = g.v0.iter().flatten().copied().sum();
    if json_out {
        println!(
            "{}",
            json!({
                "scene": scene.display().to_string(),
                "particles": n,
                "steps": steps,
                "substeps_total": substeps,
                "threads": sim.threads(),
                "wall_s": wall,
                "particle_substeps_per_s_forward_backward": rate,
                "peak_rss_bytes": peak,
                "tape_bytes": g.tape_bytes,
                "checkpoint_every": g.checkpoint_every,
                "loss": g.loss,
                "grad_tool_velocity": tool_v,
                "grad_v0_sum": [gv0.x, gv0.y, gv0.z],
                "timing_s": g.timing.iter().map(|(k, v)| (k.clone(), json!(v))).collect::<serde_json::Map<_, _>>(),
            })
        );
    } else {
        println!("scene            {}", scene.display());
        println!("particles        {n}, {substeps} substeps ({steps} steps)");
        println!("loss             {:.9e}", g.loss);
        println!(
            "forward+backward {wall:.3} s ({:.3} M particle-substeps/s)",
            rate / 1e6
        );
        println!(
            "tape             {:.1} MB (checkpoint every {} steps); peak RSS {:.1} MB",
            g.tape_bytes as f64 / 1e6,
            g.checkpoint_every,
            peak as f64 / 1e6
        );
        for t in &tool_v {
            println!("dL/d tool velocity {t}");
        }
        println!(
            "sum of dL/dv0    ({:.6e}, {:.6e}, {:.6e})",
            gv0.x, gv0.y, gv0.z
        );
        let total: f64 = g.timing.iter().map(|e| e.1).sum();
        for (k, v) in &g.timing {
            println!("  {k:<34} {v:>8.3} s  {:>5.1} %", 100.0 * v / total);
        }
    }
    Ok(())
}

fn bench(
    scene: PathBuf,
    steps: Option<usize>,
    threads: Option<usize>,
    stages: bool,
    json_out: bool,
) -> Result<()> {
    let mut sim = Simulation::from_file(
        &scene,
        &SimOptions {
            threads,
            stage_timers: stages,
            ..Default::default()
        },
    )?;
    if !json_out {
        describe_stability(&sim);
    }
    let steps = steps.unwrap_or(sim.horizon);
    let n = sim.particle_count();
    let start = Instant::now();
    let pb = bar(steps as u64, json_out);
    for _ in 0..steps {
        sim.step()?;
        pb.inc(1);
    }
    pb.finish_and_clear();
    let wall = start.elapsed().as_secs_f64();
    let substeps = sim.clock().total_substeps;
    let rate = n as f64 * substeps as f64 / wall;
    let stage_s = sim.stage_seconds();
    let peak = peak_rss_bytes();
    let mean_pos = {
        let st = sim.body_states();
        let all: Vec<_> = st.iter().flat_map(|b| b.x.iter().copied()).collect();
        all.iter().copied().sum::<glam::DVec3>() / all.len().max(1) as f64
    };
    if json_out {
        let stages_obj: serde_json::Map<String, serde_json::Value> = stage_s
            .iter()
            .map(|(k, v)| (format!("{k}_s"), json!(v)))
            .collect();
        println!(
            "{}",
            json!({
                "scene": scene.display().to_string(),
                "particles": n,
                "steps": steps,
                "substeps_total": substeps,
                "threads": sim.threads(),
                "wall_s": wall,
                "particle_substeps_per_s": rate,
                "peak_rss_bytes": peak,
                "final_mean_position_m": [mean_pos.x, mean_pos.y, mean_pos.z],
                "stages": stages_obj,
            })
        );
    } else {
        println!("scene            {}", scene.display());
        println!("particles        {n}");
        println!(
            "substeps         {substeps} ({steps} steps, {} threads)",
            sim.threads()
        );
        println!("wall time        {wall:.3} s");
        println!("throughput       {:.3} M particle-substeps/s", rate / 1e6);
        println!("peak RSS         {:.1} MB", peak as f64 / 1e6);
        println!(
            "final mean x     ({:.6}, {:.6}, {:.6}) m",
            mean_pos.x, mean_pos.y, mean_pos.z
        );
        if !stage_s.is_empty() {
            let total: f64 = stage_s.iter().map(|s| s.1).sum();
            for (k, v) in &stage_s {
                println!("  {k:<20} {v:>8.3} s  {:>5.1} %", 100.0 * v / total);
            }
        }
    }
    Ok(())
}

/// `powderlab study`'s command line.
#[derive(clap::Args)]
struct StudyArgs {
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
    /// Keep the configurations already finished in OUT/results.json.
    #[arg(long)]
    resume: bool,
    #[arg(long, value_parser = threads_arg)]
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

fn study_cmd(a: StudyArgs) -> Result<()> {
    if a.study == "growth" {
        return growth_cmd(a);
    }
    if a.study != "error-vs-time" {
        bail!(
            "unknown study '{}': expected error-vs-time or growth",
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
        powderlab::optim::problem::Problem::new(study::transport_scene(cfg)?, study::TAPE_BUDGET)?;
    }
    let exe = std::env::current_exe().context("cannot find this executable")?;
    let pb = bar(plan.len() as u64, a.json);
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

/// `powderlab study growth` (`powderlab::study::growth`): each configuration in a child process.
fn growth_cmd(a: StudyArgs) -> Result<()> {
    use powderlab::study::growth;
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
    let pb = bar(plan.len() as u64, a.json);
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
    if a.json {
        println!(
            "{}",
            json!({
                "results": results,
                "particle_series_max_over_min_throughput": spread,
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

fn validate_cmd(
    case: String,
    cells: Option<usize>,
    threads: Option<usize>,
    json_out: bool,
    report: Option<PathBuf>,
) -> Result<()> {
    if let Some(p) = &report {
        check_output_file(p, "--report")?;
    }
    let mut checks = Vec::new();
    let known = [
        "all",
        "free_fall",
        "bar",
        "self_weight",
        "incline",
        "column_collapse",
        "pile_angle",
        "stability",
    ];
    if !known.contains(&case.as_str()) {
        bail!("unknown validation case '{case}': expected one of {known:?}");
    }
    if case == "stability" {
        return stability_cmd(threads, json_out, report);
    }
    let wants = |c: &str| case == "all" || case == c;
    if wants("free_fall") {
        checks.extend(validate::free_fall(threads)?);
    }
    if wants("bar") {
        for n in [16, 32, 64] {
            let r = validate::bar::run_bar(&validate::bar::Bar::new(n), threads)?;
            checks.extend(validate::bar::bar_checks(&r));
        }
    }
    if wants("self_weight") {
        for ppc in [1, 8] {
            let mut rs = Vec::new();
            for n in [8, 16, 32] {
                rs.push(validate::column::run_column(
                    &validate::column::Column::new(n, ppc),
                    threads,
                )?);
            }
            checks.extend(validate::column::column_checks(&rs));
        }
    }
    if wants("incline") {
        for ratio in [0.95, 1.05] {
            let r =
                validate::incline::run_incline(&validate::incline::Incline::new(ratio), threads)?;
            checks.extend(validate::incline::incline_checks(&r));
        }
    }
    if case == "all" || case == "column_collapse" {
        let cells = cells.unwrap_or(validate::COLLAPSE_CELLS);
        if cells < 4 {
            bail!(
                "--cells {cells} is too coarse: use at least 4 ({} for the published check)",
                validate::COLLAPSE_CELLS
            );
        }
        let collapse = |a: f64, cells: usize| {
            with_progress(
                json_out,
                format!("column collapse a = {a}, {cells} cells"),
                |progress| {
                    validate::run_collapse(&validate::Collapse::new(a, cells), threads, progress)
                },
            )
        };
        let (small, at_one) = validate::small_a_band(cells, &collapse)?;
        checks.extend(small);
        let mut large = Vec::new();
        for a in validate::LARGE_A {
            large.push(collapse(a, cells)?);
        }
        checks.extend(validate::collapse_checks(
            "large-a",
            &large,
            validate::LARGE_A_SLOPE,
            validate::LARGE_A_SLOPE_TOL,
            &format!("{cells} cells across L0 at every a"),
        ));
        let fine = collapse(1.0, 2 * cells)?;
        checks.push(validate::halving_check(&at_one, &fine, cells));
        checks.push(validate::scale_invariance(1.0, cells, threads)?);
    }
    if wants("pile_angle") {
        use validate::pile::{run_pile, Pile, MIN_PILE_CELLS, PILE_CELLS, PILE_FRICTION_DEG};
        let cells = cells.unwrap_or(PILE_CELLS);
        if cells < MIN_PILE_CELLS {
            bail!(
                "--cells {cells} is too coarse for a pile: use at least {MIN_PILE_CELLS} \
                 ({PILE_CELLS} for the published check)"
            );
        }
        let mut rs = Vec::new();
        for phi in PILE_FRICTION_DEG {
            let p = Pile {
                friction_deg: phi,
                cells_across: cells,
            };
            rs.push(with_progress(
                json_out,
                format!("pile at φ = {phi}°, {cells} cells"),
                |progress| run_pile(&p, threads, progress),
            )?);
        }
        checks.extend(validate::pile::pile_checks(&rs));
    }
    let passed = checks.iter().all(|c| c.passed);
    let obj = json!({ "passed": passed, "checks": checks });
    if report_or_json(&obj, report.as_deref(), json_out)? {
        println!(
            "{:<16} {:<40} {:>12} {:>12} {:>10} {:<12} result",
            "case", "quantity", "measured", "published", "tolerance", "kind"
        );
        for c in &checks {
            println!(
                "{:<16} {:<40} {:>12.5e} {:>12.5e} {:>10.3e} {:<12} {}  {}",
                c.case,
                c.quantity,
                c.measured,
                c.published,
                c.tolerance,
                c.kind,
                if c.passed { "PASS" } else { "FAIL" },
                c.note
            );
        }
    }
    if !passed {
        std::process::exit(1);
    }
    Ok(())
}

/// Writes a validation report to `report` (atomically) if asked, and prints it as one JSON
/// object with `--json`; returns whether the caller should print its text form instead.
fn report_or_json(
    obj: &serde_json::Value,
    report: Option<&std::path::Path>,
    json_out: bool,
) -> Result<bool> {
    if let Some(p) = report {
        write_atomic(p, serde_json::to_string_pretty(obj)?.as_bytes())?;
    }
    if json_out {
        println!("{obj}");
    }
    Ok(!json_out)
}

/// `validate stability`: every case of the suite, as a Markdown table (and JSON).
fn stability_cmd(threads: Option<usize>, json_out: bool, report: Option<PathBuf>) -> Result<()> {
    use validate::stability::{cases, markdown, run_case};
    let cases = cases();
    let pb = bar(cases.len() as u64, json_out);
    let mut results = Vec::new();
    for c in &cases {
        pb.set_message(c.name.clone());
        results.push(run_case(c, threads));
        pb.inc(1);
    }
    pb.finish_and_clear();
    let passed = results.iter().all(|r| r.outcome.acceptable());
    let obj = json!({ "passed": passed, "stability": results });
    if report_or_json(&obj, report.as_deref(), json_out)? {
        print!("{}", markdown(&results));
    }
    if !passed {
        eprintln!("a case ended unstable or non-finite (see the table)");
        std::process::exit(1);
    }
    Ok(())
}

fn gradcheck_cmd(
    scene: PathBuf,
    params: Vec<String>,
    steps: Option<usize>,
    threads: Option<usize>,
    budget_mb: usize,
    tol: f64,
    json_out: bool,
) -> Result<()> {
    if !(tol.is_finite() && tol > 0.0) {
        bail!("--tol {tol}: expected a positive relative error, such as 1e-3");
    }
    let sc = powderlab::scene::Scene::load(&scene)?;
    let steps = match steps {
        Some(s) => s,
        None => {
            Simulation::new(
                &sc,
                &SimOptions {
                    threads,
                    ..Default::default()
                },
            )?
            .horizon
        }
    };
    if !json_out {
        eprintln!(
            "{}: gradients over {steps} steps, loss Σ‖x_p(T) − t‖ ...",
            scene.display()
        );
    }
    let r = powderlab::gradcheck::run(&sc, steps, &params, threads, budget_mb << 20)?;
    let passed = r.max_rel_error <= tol;
    if json_out {
        let mut v = serde_json::to_value(&r)?;
        v["passed"] = json!(passed);
        v["tolerance"] = json!(tol);
        println!("{v}");
    } else {
        println!("loss {:.9e} at target ({:.4}, {:.4}, {:.4}) m; checkpoint every {} steps; tape {:.1} MB", r.loss, r.target_m[0], r.target_m[1], r.target_m[2], r.checkpoint_every, r.tape_bytes as f64 / 1e6);
        println!(
            "forward {:.2} s, forward + backward {:.2} s (ratio {:.2})",
            r.forward_s,
            r.forward_backward_s,
            r.forward_backward_s / r.forward_s
        );
        println!(
            "{:<40} {:>18} {:>18} {:>10} {:>8}",
            "parameter", "adjoint", "finite difference", "rel error", "eps"
        );
        for row in &r.rows {
            let note = if row.noise_limited {
                format!(
                    "zero gradient: both below the round-off floor {:.1e}",
                    row.noise_floor
                )
            } else {
                String::new()
            };
            println!(
                "{:<40} {:>18.10e} {:>18.10e} {:>10.2e} {:>8.0e}  {note}",
                row.parameter, row.adjoint, row.finite_difference, row.rel_error, row.eps
            );
        }
        println!(
            "max relative error (non-zero gradients) {:.2e}: {}",
            r.max_rel_error,
            if passed { "PASS" } else { "FAIL" }
        );
    }
    if !passed {
        std::process::exit(1);
    }
    Ok(())
}

/// `powderlab optimize`'s command line.
#[derive(clap::Args)]
struct OptimizeArgs {
    /// The scene whose tool has a skill control.
    scene: PathBuf,
    /// grad, cmaes, sac, random or all (comma separated).
    #[arg(long, value_delimiter = ',', default_value = "all")]
    method: Vec<String>,
    /// Rollouts per seed and method (the gradient method's epochs).
    #[arg(long, default_value_t = 30)]
    epochs: usize,
    /// Seeds, each with its own Θ_init.
    #[arg(long, default_value_t = 3)]
    seeds: usize,
    /// Run directory (default: runs/<scene name>).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Continue an interrupted run in --out.
    #[arg(long)]
    resume: bool,
    /// Worker threads (default: the scene's setting; 0 = all cores).
    #[arg(long, value_parser = threads_arg)]
    threads: Option<usize>,
    /// RMSprop learning rate.
    #[arg(long, default_value_t = 0.05)]
    lr: f64,
    /// Last epoch of the curriculum's scoop-only phase (θ_d, θ_s, θ_l).
    #[arg(long, default_value_t = 15)]
    curriculum_switch: usize,
    /// Scale each gradient to unit length before RMSprop (not the paper's method; see the
    /// README's skill-optimisation section).
    #[arg(long)]
    grad_normalize: bool,
    /// Clip each gradient to the median length of the seed's gradients so far before RMSprop
    /// (not the paper's method; see the README's skill-optimisation section).
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
    /// Memory budget of a backward pass's tape in MB.
    #[arg(long, default_value_t = 1024)]
    budget_mb: usize,
    /// Print the summary as one JSON object.
    #[arg(long)]
    json: bool,
}

fn optimize_cmd(args: OptimizeArgs) -> Result<()> {
    let OptimizeArgs {
        scene,
        method,
        epochs,
        seeds,
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
        budget_mb,
        json: json_out,
    } = args;
    use powderlab::optim::{self, Method};
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
            None => bail!("--method {m}: expected grad, cmaes, sac, random or all"),
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
        scene_hash: optim::fnv1a(&sc.source),
        methods,
        epochs,
        seeds,
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
        tape_budget: budget_mb << 20,
    };
    if !json_out {
        eprintln!(
            "{}: {} × {seeds} seeds × {epochs} rollouts, {} threads, out {}",
            scene.display(),
            settings
                .methods
                .iter()
                .map(|m| m.name())
                .collect::<Vec<_>>()
                .join(", "),
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
        "{:<8} {:>26} {:>26} {:>9} {:>9}",
        "method",
        format!("initial indicator ({unit})"),
        format!("final indicator ({unit})"),
        "rollouts",
        "wall s"
    );
    if let Some(ms) = r.summary["methods"].as_object() {
        for (name, m) in ms {
            let f = |k: &str| m[k].as_f64().unwrap_or(f64::NAN);
            println!(
                "{:<8} {:>26} {:>26} {:>9} {:>9.1}",
                name,
                format!(
                    "{:.3} ± {:.3}",
                    f("initial_indicator_mean"),
                    f("initial_indicator_std")
                ),
                format!(
                    "{:.3} ± {:.3}",
                    f("final_indicator_mean"),
                    f("final_indicator_std")
                ),
                m["rollouts_per_seed"].as_u64().unwrap_or(0) * seeds as u64,
                f("wall_s")
            );
        }
    }
    eprintln!(
        "{} rollouts simulated, {} replayed from the journal; results in {}",
        r.ran,
        r.replayed,
        out.display()
    );
    Ok(())
}

fn main() {
    let cli = Cli::parse();
    let r = match cli.command {
        Command::Simulate {
            scene,
            steps,
            out,
            threads,
            save_state,
        } => simulate(scene, steps, out, threads, save_state),
        Command::Gradcheck {
            scene,
            params,
            steps,
            threads,
            budget_mb,
            tol,
            json,
        } => gradcheck_cmd(scene, params, steps, threads, budget_mb, tol, json),
        Command::Bench {
            scene,
            steps,
            threads,
            stages,
            backward,
            budget_mb,
            json,
        } => {
            if backward {
                bench_backward(scene, steps, threads, budget_mb, json)
            } else {
                bench(scene, steps, threads, stages, json)
            }
        }
        Command::Optimize(args) => optimize_cmd(args),
        Command::Validate {
            case,
            cells,
            threads,
            json,
            report,
        } => validate_cmd(case, cells, threads, json, report),
        Command::Study(args) => study_cmd(args),
    };
    if let Err(e) = r {
        eprintln!("error: {e:#}");
        std::process::exit(2);
    }
}
