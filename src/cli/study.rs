// Longer than 600 lines: one function per study, each reading its arguments, running its study and writing its page; they share the argument struct and the page helpers.
//! `powderlab study`: error against run time, and time per substep against the problem size.
//! Each configuration runs in a child process (this executable with `--config`), so that its
//! peak memory is its own.

use anyhow::{bail, Context, Result};
use powderlab::study;
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
        return landscape_cmd(a);
    }
    if a.study == "optimizers" {
        return optimizers_cmd(a);
    }
    if a.study == "directions" {
        return directions_cmd(a);
    }
    if a.study == "refine" {
        return refine_cmd(a);
    }
    if a.study == "calibration" {
        return calibration_cmd(a);
    }
    if a.study == "demonstration" {
        return demonstration_cmd(a);
    }
    if a.study == "planning" {
        return planning_cmd(a);
    }
    if a.study == "policy" {
        return policy_cmd(a);
    }
    if a.study == "pour" {
        return pour_cmd(a);
    }
    if a.study == "reliability" {
        return reliability_cmd(a);
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
        powderlab::optim::problem::Problem::new(study::transport_scene(cfg)?, study::TAPE_BUDGET)?;
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

/// `powderlab study growth` (`powderlab::study::growth`): each configuration in a child process.
fn growth_cmd(a: Args) -> Result<()> {
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

/// `powderlab study landscape`: Sobol rollouts of a skill scene, best-of-k, main effects.
fn landscape_cmd(a: Args) -> Result<()> {
    use powderlab::study::landscape;
    let scene = a
        .scene
        .clone()
        .unwrap_or_else(|| PathBuf::from("scenes/powder_transport.ron"));
    let n = a.samples.unwrap_or(if a.quick { 16 } else { 256 });
    if n < 2 {
        bail!("study landscape: --samples {n}: expected at least 2");
    }
    let sc = powderlab::scene::Scene::load(&scene)?;
    let problem = powderlab::optim::problem::Problem::new(sc, 1 << 30)?;
    let unit = match problem.target {
        powderlab::scene::TargetValue::Particles(_) => "particles",
        powderlab::scene::TargetValue::Grams(_) => "g",
    };
    let threads = a.threads.unwrap_or(problem.scene.simulation.threads);
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build_global()
        .context("starting the worker threads")?;
    super::announce_work(&scene, n as f64)?;
    let thetas = landscape::sobol_thetas(n, 0);
    let pb = super::bar(n as u64, a.json);
    pb.set_position(landscape::load(&a.out)?.len().min(n) as u64);
    let start = Instant::now();
    let points = landscape::run(&problem, &thetas, &a.out, &|| pb.inc(1))?;
    pb.finish_and_clear();
    let md = landscape::write_report(&points, unit, &a.out)?;
    if a.json {
        println!(
            "{}",
            json!({ "rollouts": points.len(), "wall_s": start.elapsed().as_secs_f64(), "markdown": md })
        );
    } else {
        print!("{md}");
        eprintln!(
            "{} rollouts in {:.0} s; wrote landscape.csv and landscape.md to {}",
            points.len(),
            start.elapsed().as_secs_f64(),
            a.out.display()
        );
    }
    Ok(())
}

/// `powderlab study optimizers`: every method on paired seeds at equal compute.
fn optimizers_cmd(a: Args) -> Result<()> {
    use powderlab::optim::Method;
    let tasks = if a.tasks.is_empty() {
        vec![
            PathBuf::from("scenes/powder_transport.ron"),
            PathBuf::from("scenes/precise_dosing.ron"),
        ]
    } else {
        a.tasks.clone()
    };
    let mut methods: Vec<Method> = Vec::new();
    for m in &a.method {
        let Some(ms) = Method::parse_list(m) else {
            bail!(
                "--method {m}: expected grad, cmaes, sac, random, smoothed, hybrid, carry, line, ray, paper, default or all"
            );
        };
        for m in ms {
            if !methods.contains(&m) {
                methods.push(m);
            }
        }
    }
    let threads = a.threads.unwrap_or(0);
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build_global()
        .context("starting the worker threads")?;
    if a.page.is_empty() || a.page.contains(['/', '\\', '.']) {
        bail!(
            "--page {:?}: expected a file name without a folder or extension, such as optimisation",
            a.page
        );
    }
    let mut command = format!(
        "powderlab study optimizers --tasks {} --seeds {} --budget {} --method {}",
        tasks
            .iter()
            .map(|t| t.display().to_string())
            .collect::<Vec<_>>()
            .join(","),
        a.seeds,
        a.budget,
        methods
            .iter()
            .map(|m| m.name())
            .collect::<Vec<_>>()
            .join(",")
    );
    if a.page != "optimisation" {
        command.push_str(&format!(" --page {}", a.page));
    }
    for t in &tasks {
        super::announce_work(t, (a.seeds * a.budget * methods.len()) as f64)?;
    }
    let start = Instant::now();
    let md = study::optimizers::run(&study::optimizers::StudyOptions {
        tasks,
        seeds: a.seeds,
        budget: a.budget,
        methods,
        out: a.out.join("optimizers"),
        results: a.results.clone(),
        page: a.page.clone(),
        command,
        quiet: a.json,
    })?;
    print_page(
        &a,
        &md,
        start,
        &format!("{p}.md, {p}.svg and {p}.csv", p = a.page),
        json!({}),
    );
    Ok(())
}

/// `powderlab study directions`: each loss's gradient against the dose error's secants.
fn directions_cmd(a: Args) -> Result<()> {
    use powderlab::study::directions;
    let (scene, problem, unit) = skill_problem(&a, "scenes/powder_transport.ron")?;
    let landscape = a.results.join("landscape.csv");
    let mut points = directions::default_points(Some(&landscape));
    let steps: Vec<f64> = if a.quick {
        points.truncate(2);
        vec![0.1]
    } else {
        vec![0.1, 0.05]
    };
    let (labels, thetas): (Vec<String>, Vec<[f64; 5]>) = points.into_iter().unzip();
    // Three gradient rollouts, one at Θ and two per parameter and step.
    let n = thetas.len() * (4 + 10 * steps.len());
    let pb = super::bar(n as u64, a.json);
    let dir = a.out.join("directions");
    let start = Instant::now();
    let done = directions::run(&problem, &thetas, &steps, &dir, &|| pb.inc(1))?;
    pb.finish_and_clear();
    let rows = directions::rows(&labels, &thetas, &steps, &done)?;
    let command = format!(
        "powderlab study directions --scene {}{}",
        scene.display(),
        if a.quick { " --quick" } else { "" }
    );
    let md = directions::report(&rows, &steps, &command, unit);
    directions::write(&rows, &md, &a.results)?;
    print_page(
        &a,
        &md,
        start,
        "directions.md and directions.csv",
        json!({}),
    );
    Ok(())
}

/// `powderlab study refine`: trajectory refinement by dimension, the adjoint against CMA-ES
/// and random search at equal compute.
fn refine_cmd(a: Args) -> Result<()> {
    use powderlab::study::refine;
    if a.knots.is_empty() || a.knots.contains(&0) || a.seeds == 0 || a.budget == 0 {
        bail!("study refine: --knots, --seeds and --budget must be at least 1");
    }
    let (scene, problem, unit) = skill_problem(&a, "scenes/precise_dosing.ron")?;
    // At most: trust's rollouts depend on its accepted steps, and never pass the budget.
    let per_seed = 5 * a.budget + refine::gradient_rollouts(a.budget);
    super::announce_work(&scene, (a.knots.len() * a.seeds * 6 * a.budget) as f64)?;
    let pb = super::bar((a.knots.len() * a.seeds * per_seed) as u64, a.json);
    let pb2 = pb.clone();
    let store = refine::Store::open(&a.out.join("refine"), Box::new(move || pb2.inc(1)))?;
    let start = Instant::now();
    if a.over.is_some_and(|g| !(g.is_finite() && g >= 0.0)) {
        bail!("study refine: --over must be a finite amount of at least 0 (the target's unit)");
    }
    let (starts, screen) = refine::starts(&store, &problem, a.over, a.seeds)?;
    // The screening's rollouts ran first (their number is known only now): the methods' follow.
    pb.set_length(pb.position() + (a.knots.len() * a.seeds * per_seed) as u64);
    let cells = refine::run(&problem, &a.knots, &starts, a.budget, &store)?;
    pb.finish_and_clear();
    let over = a.over.map_or(String::new(), |g| format!(" --over {g}"));
    let command = format!(
        "powderlab study refine --scene {}{over} --knots {} --seeds {} --budget {}",
        scene.display(),
        a.knots
            .iter()
            .map(|k| k.to_string())
            .collect::<Vec<_>>()
            .join(","),
        a.seeds,
        a.budget
    );
    let md = refine::report(&cells, &command, unit, a.budget, screen);
    powderlab::util::create_output_dir(&a.results, "--results")?;
    powderlab::util::write_atomic(&a.results.join("refinement.md"), md.as_bytes())?;
    print_page(
        &a,
        &md,
        start,
        "refinement.md",
        json!({ "cells": cells, "screen": screen }),
    );
    Ok(())
}

/// `powderlab study demonstration`: five synthetic demonstrations filmed and fitted back, and
/// an expert's demonstration as the warm start of an optimisation.
fn demonstration_cmd(a: Args) -> Result<()> {
    use powderlab::study::demonstration::{self, Setup};
    let scene_path = "scenes/powder_transport.ron";
    let scene = powderlab::scene::Scene::load(scene_path)?;
    let setup = Setup {
        size: (160, 120),
        every: 4,
        noise: 0.02,
    };
    let pb = super::bar(demonstration::THETAS.len() as u64, a.json);
    let pb2 = pb.clone();
    let start = Instant::now();
    let rows = demonstration::run(&scene, &a.out.join("demonstration"), &setup, &move |k| {
        pb2.set_position(k as u64)
    })?;
    pb.finish_and_clear();
    if !a.json {
        eprintln!(
            "the warm start: an expert's demonstration, then CMA-ES from it and from random starts"
        );
    }
    let warm =
        powderlab::study::warm_start::run(&scene, &a.out.join("demonstration/warm_start"), &setup)?;
    let machine = powderlab::study::optimizers::machine();
    let md = demonstration::report(
        &rows,
        scene_path,
        &setup,
        "powderlab study demonstration",
        &machine,
    ) + &powderlab::study::warm_start::report(&warm);
    powderlab::util::create_output_dir(&a.results, "--results")?;
    powderlab::util::write_atomic(&a.results.join("demonstration.md"), md.as_bytes())?;
    print_page(
        &a,
        &md,
        start,
        "demonstration.md",
        json!({ "rows": rows.len() }),
    );
    Ok(())
}

/// `powderlab study planning`: multi-scoop dosing and the four push/pull classes over
/// randomised instances, A* against greedy and scripted (`--seeds` instances of each, 10 by
/// default).
fn planning_cmd(a: Args) -> Result<()> {
    use powderlab::plan::dosing::Method;
    use powderlab::study::planning;
    // The two tasks' scenes, or those `--tasks` names (a push plan or a dosing plan each).
    let tasks = if a.tasks.is_empty() {
        vec![
            PathBuf::from("scenes/multi_scoop_dosing.ron"),
            PathBuf::from("scenes/plate_push.ron"),
        ]
    } else {
        a.tasks.clone()
    };
    let (mut dosing, mut push) = (None, None);
    for t in &tasks {
        let s = powderlab::scene::Scene::load(t)?;
        match &s.plan {
            Some(powderlab::scene::plan::PlanSpec::Dosing(_)) => dosing = Some(s),
            Some(powderlab::scene::plan::PlanSpec::Push(_)) => push = Some(s),
            None => bail!("--tasks {}: the scene has no `plan` section", t.display()),
        }
    }
    let methods: Vec<Method> = if a.method == ["all"] {
        vec![Method::Astar, Method::Greedy, Method::Scripted]
    } else {
        a.method
            .iter()
            .map(|m| {
                Method::parse(m).ok_or_else(|| {
                    anyhow::anyhow!("--method {m}: expected astar, greedy, scripted or all")
                })
            })
            .collect::<Result<_>>()?
    };
    let instances = dosing
        .as_ref()
        .map_or(Vec::new(), |_| planning::instances(a.seeds, 2026));
    let pushes = push.as_ref().map_or(Vec::new(), |_| {
        powderlab::study::push::push_instances(a.seeds, 2027)
    });
    let pb = super::bar(
        ((instances.len() + pushes.len()) * methods.len()) as u64,
        a.json,
    );
    let pb2 = pb.clone();
    let start = Instant::now();
    let rows = match &dosing {
        Some(scene) => planning::run(
            scene,
            &a.out.join("planning"),
            &instances,
            &methods,
            &|k, m| {
                pb2.inc(1);
                pb2.set_message(format!("dosing instance {k}: {}", m.name()));
            },
        )?,
        None => Vec::new(),
    };
    let push_rows = match &push {
        Some(scene) => powderlab::study::push::run_push(
            scene,
            &a.out.join("planning/push"),
            &pushes,
            &methods,
            &|k, m| {
                pb2.inc(1);
                pb2.set_message(format!("push instance {k}: {}", m.name()));
            },
        )?,
        None => Vec::new(),
    };
    pb.finish_and_clear();
    let command = format!(
        "powderlab study planning --seeds {} --out {}",
        a.seeds,
        a.out.display()
    );
    let md = planning::report(&rows, &command, &powderlab::study::optimizers::machine())
        + &powderlab::study::push::push_report(&push_rows);
    powderlab::util::create_output_dir(&a.results, "--results")?;
    powderlab::util::write_atomic(&a.results.join("planning.md"), md.as_bytes())?;
    print_page(
        &a,
        &md,
        start,
        "planning.md",
        json!({ "instances": rows.len(), "push_instances": push_rows.len() }),
    );
    Ok(())
}

/// `powderlab study policy`: seed B's Sim2Real step on the randomised dosing scene (160
/// labelled scenes with 2 perturbed copies each and their hindsight samples, the fit, the
/// fine-tune, 20 held-out scenes).
fn policy_cmd(a: Args) -> Result<()> {
    use powderlab::policy::{dataset, eval, net, reinforce};
    use powderlab::study::policy;
    let path = a
        .scene
        .clone()
        .unwrap_or_else(|| PathBuf::from("scenes/policy_dosing.ron"));
    let scene = powderlab::scene::Scene::load(&path)?;
    dataset::spec_of(&scene)?;
    let settings = policy::Settings {
        dataset: dataset::Config {
            scene_hash: powderlab::optim::fnv1a(&scene.source),
            scenes: dataset::SCENES,
            budget: 10,
            augment: 2,
            augment_steps: 1,
            perturb: 0.1,
            seed: 0,
        },
        train: net::TrainConfig::default(),
        finetune: reinforce::ReinforceConfig::default(),
        eval: eval::EvalConfig {
            scenes: 20,
            budget: 30,
            seed: 0,
        },
    };
    let pb = super::bar(1, a.json);
    let start = Instant::now();
    let dir = a.out.join("policy");
    let o = policy::run(&scene, &settings, &dir, &|step, k, n| {
        pb.set_length(n as u64);
        pb.set_position(k as u64);
        pb.set_message(step.to_string());
    })?;
    pb.finish_and_clear();
    let command = format!("powderlab study policy --out {}", a.out.display());
    let md = policy::report(
        &o,
        &settings,
        &scene,
        &command,
        &powderlab::study::optimizers::machine(),
    );
    powderlab::util::create_output_dir(&a.results, "--results")?;
    policy::figure(&a.results.join("policy.svg"), &o.curve, &o.iterations)?;
    powderlab::util::write_atomic(&a.results.join("policy.md"), md.as_bytes())?;
    print_page(
        &a,
        &md,
        start,
        "policy.md and policy.svg",
        json!({ "scenes": o.rows.len() }),
    );
    Ok(())
}

/// `powderlab study pour`: the gravimetric pour on the policy page's held-out draws, at dx =
/// 5 mm (20) and 2.5 mm (the first 6).
fn pour_cmd(a: Args) -> Result<()> {
    use powderlab::study::pour;
    let load = |p: &str| powderlab::scene::Scene::load(p);
    let coarse_scene = load("scenes/policy_dosing.ron")?;
    let fine_scene = load("scenes/policy_dosing_fine.ron")?;
    let settings = pour::Settings {
        scenes: 20,
        fine_scenes: 6,
        pour: Default::default(),
        faster_turn_back_deg: 720.0,
        // Taps of half a millimetre past 50°, below where a tilt alone starts the outflow (about
        // 63°), with the tilt creeping at 3°/s so the flow does not stall, up to 70°.
        tapped: powderlab::policy::pour::Gravimetric {
            speed_deg: 3.0,
            fast_to_deg: 50.0,
            max_deg: 70.0,
            tap_mm: Some(0.5),
            ..Default::default()
        },
        seed: 0,
    };
    let start = Instant::now();
    let dir = a.out.join("pour");
    let faster = powderlab::policy::pour::Gravimetric {
        turn_back_deg: Some(settings.faster_turn_back_deg),
        ..settings.pour
    };
    let back = format!("dx-5mm-back-{}", settings.faster_turn_back_deg);
    let mut rows = Vec::new();
    for (scene, g, n, sub) in [
        (&coarse_scene, &settings.pour, settings.scenes, "dx-5mm"),
        (
            &fine_scene,
            &settings.pour,
            settings.fine_scenes,
            "dx-2.5mm",
        ),
        (&coarse_scene, &faster, settings.scenes, back.as_str()),
        (
            &coarse_scene,
            &settings.tapped,
            settings.scenes,
            "dx-5mm-tapped",
        ),
    ] {
        let pb = super::bar(n as u64, a.json);
        pb.set_message(sub.to_string());
        let r = pour::run(scene, g, settings.seed, n, &dir.join(sub), &|k| {
            pb.set_position(k as u64)
        })?;
        pb.finish_and_clear();
        rows.push(r);
    }
    let policy = pour::policy_trials(&a.out.join("policy"));
    let command = format!("powderlab study pour --out {}", a.out.display());
    let md = pour::report(
        &rows[0],
        &rows[1],
        &rows[2],
        &rows[3],
        policy.as_deref(),
        &settings,
        &command,
        &powderlab::study::optimizers::machine(),
        POUR_MINUTES,
        match coarse_scene
            .colliders
            .iter()
            .find_map(|c| c.control.as_ref())
        {
            Some(powderlab::scene::ControlSpec::Skill(sk)) => sk.angular_speed_deg,
            _ => bail!("scenes/policy_dosing.ron: its spoon has no skill"),
        },
    );
    powderlab::util::create_output_dir(&a.results, "--results")?;
    let (c, f) = pour::shown(&rows[0], &rows[1]).unzip();
    pour::figure(&a.results.join("pour.svg"), c, f)?;
    powderlab::util::write_atomic(&a.results.join("pour.md"), md.as_bytes())?;
    print_page(
        &a,
        &md,
        start,
        "pour.md and pour.svg",
        json!({ "scenes": rows[0].len(), "fine_scenes": rows[1].len() }),
    );
    Ok(())
}

/// `study pour`'s run time from scratch on this project's 2-core machine (min), for its page.
const POUR_MINUTES: f64 = 11.0;

/// `powderlab study calibration`: recovery of known parameters from noisy synthetic
/// observations, Adam and BFGS on the adjoint against CMA-ES at equal compute.
fn calibration_cmd(a: Args) -> Result<()> {
    use powderlab::study::calibration;
    if a.seeds == 0 || a.budget == 0 {
        bail!("study calibration: --seeds and --budget must be at least 1");
    }
    let budget = a.budget as f64;
    let runs = calibration::CASES.len() * 5 * a.seeds * calibration::METHODS.len();
    // The pairs, the joint fit and its curvature, and the grain sweep's gradient rollouts.
    let total = runs as f64 * budget + 2.0 * budget + 6.0 * 3.4 + calibration::GRAIN.3 as f64 * 3.4;
    for case in &calibration::CASES {
        super::announce_work(
            std::path::Path::new(case.scene),
            total / calibration::CASES.len() as f64,
        )?;
    }
    // The layered bed: its pairs (and each pair's rollout at the truth) and its curvature.
    let layers = {
        use calibration::layers as l;
        let pairs = (l::PAIRS_PER_SEED * a.seeds) as f64;
        let k = l::LAYERS as f64;
        pairs * l::METHODS.len() as f64 * (l::BUDGET_FACTOR * budget + 1.0) + 1.0 + 2.0 * k * k
    };
    super::announce_work(std::path::Path::new(calibration::layers::SCENE), layers)?;
    let total = total + layers;
    let pb = super::bar(total.ceil() as u64, a.json);
    let pb2 = pb.clone();
    let done = std::sync::Mutex::new(0.0f64);
    let progress = move |c: f64| {
        let mut d = done.lock().expect("lock");
        *d += c;
        pb2.set_position(d.round() as u64);
    };
    rayon::ThreadPoolBuilder::new()
        .num_threads(a.threads.unwrap_or(0))
        .build_global()
        .context("starting the worker threads")?;
    let start = Instant::now();
    // Each rollout runs on one thread; the pairs run side by side.
    let outcome = calibration::run(
        &a.out.join("calibration"),
        a.seeds,
        budget,
        Some(1),
        &progress,
    )?;
    pb.finish_and_clear();
    let command = format!(
        "powderlab study calibration --seeds {} --budget {}",
        a.seeds, a.budget
    );
    powderlab::util::create_output_dir(&a.results, "--results")?;
    let machine = powderlab::study::optimizers::machine();
    let mut md = calibration::report(&outcome, &command, &machine, budget, &a.results)?;
    md.push_str(&calibration::layers::report(
        &outcome.layers,
        budget,
        &a.results,
    )?);
    powderlab::util::write_atomic(&a.results.join("calibration.md"), md.as_bytes())?;
    print_page(
        &a,
        &md,
        start,
        "calibration.md, calibration.svg and calibration_layers.svg",
        json!({ "runs": outcome.runs, "layers": outcome.layers.runs }),
    );
    Ok(())
}

/// The skill problem of `--scene` (else `default`), its indicator's unit, and the worker pool
/// of `--threads` (default all cores) started.
fn skill_problem(
    a: &Args,
    default: &str,
) -> Result<(PathBuf, powderlab::optim::problem::Problem, &'static str)> {
    let scene = a.scene.clone().unwrap_or_else(|| PathBuf::from(default));
    let sc = powderlab::scene::Scene::load(&scene)?;
    let problem = powderlab::optim::problem::Problem::new(sc, 1 << 30)?;
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
fn print_page(a: &Args, md: &str, start: Instant, wrote: &str, extra: serde_json::Value) {
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

/// `study reliability`: `simulate` on mutated scenes under a memory cap and a timeout; writes
/// docs/results/reliability.md. Resumes from OUT/reliability/cases.jsonl.
fn reliability_cmd(a: Args) -> Result<()> {
    use powderlab::study::reliability;
    let cfg = reliability::Config {
        cases: a.cases,
        cap_bytes: (a.cap_gb * (1u64 << 30) as f64) as u64,
        timeout_s: a.timeout_s,
        jobs: a.jobs,
    };
    if !(a.cap_gb > 0.0 && a.timeout_s > 0.0 && a.cases > 0 && a.jobs > 0) {
        bail!("--cases, --cap-gb, --timeout-s and --jobs must be positive");
    }
    let exe = std::env::current_exe().context("cannot find this executable")?;
    let dir = a.out.join("reliability");
    let pb = super::bar(cfg.cases as u64, a.json);
    let start = Instant::now();
    let records = reliability::run(&exe, std::path::Path::new("."), &dir, &cfg, &|k, n| {
        pb.set_length(n as u64);
        pb.set_position(k as u64);
    })?;
    pb.finish_and_clear();
    let command = format!(
        "powderlab study reliability --cases {} --cap-gb {} --timeout-s {} --jobs {}",
        cfg.cases, a.cap_gb, a.timeout_s, cfg.jobs
    );
    let md = reliability::report(
        &records,
        &cfg,
        &command,
        &powderlab::study::optimizers::machine(),
    );
    let page = a.results.join("reliability.md");
    std::fs::create_dir_all(&a.results)
        .with_context(|| format!("cannot create {}", a.results.display()))?;
    powderlab::util::write_atomic(&page, md.as_bytes())
        .with_context(|| format!("writing {}", page.display()))?;
    let problems = records.iter().filter(|r| r.problem.is_some()).count();
    eprintln!(
        "{} cases in {:.0} s, {problems} breaking the acceptance; wrote {}",
        records.len(),
        start.elapsed().as_secs_f64(),
        page.display()
    );
    Ok(())
}
