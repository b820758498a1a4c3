//! The optimisation studies of `powderlab study`: the loss landscape, the optimiser benchmark,
//! the gradient directions and trajectory refinement.

use super::{args, print_page, skill_problem};
use anyhow::{bail, Context, Result};
use powderlab::lab::study;
use powderlab::skills::Theta;
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

/// `powderlab study landscape`: Sobol rollouts of a skill scene, best-of-k, main effects.
pub(super) fn landscape_cmd(a: args::Landscape) -> Result<()> {
    use powderlab::lab::study::landscape;
    let scene = a
        .scene
        .clone()
        .unwrap_or_else(|| PathBuf::from("scenes/powder_transport.ron"));
    let n = a.samples.unwrap_or(if a.run.quick { 16 } else { 256 });
    if n < 2 {
        bail!("study landscape: --samples {n}: expected at least 2");
    }
    let sc = powderlab::scene::Scene::load(&scene)?;
    let problem = powderlab::lab::optim::problem::Problem::new(sc, 1 << 30)?;
    let unit = match problem.target {
        powderlab::scene::TargetValue::Particles(_) => "particles",
        powderlab::scene::TargetValue::Grams(_) => "g",
    };
    let threads = a.run.threads.unwrap_or(problem.scene().simulation.threads);
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build_global()
        .context("starting the worker threads")?;
    super::super::announce_work(&scene, n as f64)?;
    let thetas = landscape::sobol_thetas(n, 0);
    let pb = super::super::bar(n as u64, a.common.json);
    pb.set_position(landscape::load(&a.common.out)?.len().min(n) as u64);
    let start = Instant::now();
    let points = landscape::run(&problem, &thetas, &a.common.out, &|| pb.inc(1))?;
    pb.finish_and_clear();
    let md = landscape::write_report(&points, unit, &a.common.out)?;
    if a.common.json {
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
            a.common.out.display()
        );
    }
    Ok(())
}

/// `powderlab study optimizers`: every method on paired seeds at equal compute.
pub(super) fn optimizers_cmd(a: args::Optimizers) -> Result<()> {
    use powderlab::lab::optim::Method;
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
    if a.name.is_empty() || a.name.contains(['/', '\\', '.']) {
        bail!(
            "--page {:?}: expected a file name without a folder or extension, such as optimisation",
            a.name
        );
    }
    let mut command = format!(
        "powderlab study optimizers --tasks {} --seeds {} --budget {} --method {}",
        tasks
            .iter()
            .map(|t| t.display().to_string())
            .collect::<Vec<_>>()
            .join(","),
        a.paired.seeds,
        a.paired.budget,
        methods
            .iter()
            .map(|m| m.name())
            .collect::<Vec<_>>()
            .join(",")
    );
    if a.name != "optimisation" {
        command.push_str(&format!(" --page {}", a.name));
    }
    if a.first_seed != 0 {
        command.push_str(&format!(" --first-seed {}", a.first_seed));
    }
    for t in &tasks {
        super::super::announce_work(t, (a.paired.seeds * a.paired.budget * methods.len()) as f64)?;
    }
    let start = Instant::now();
    let md = study::optimizers::run(&study::optimizers::StudyOptions {
        tasks,
        seeds: a.paired.seeds,
        first_seed: a.first_seed,
        budget: a.paired.budget,
        methods,
        // One folder per stream: a run's settings (its first seed among them) fix its journal.
        out: a
            .common
            .out
            .join(powderlab::lab::streams::folder("optimizers", a.first_seed)),
        results: a.page.results.clone(),
        page: a.name.clone(),
        command,
        quiet: a.common.json,
    })?;
    print_page(
        a.common.json,
        &a.page.results,
        &md,
        start,
        &format!("{p}.md, {p}.svg and {p}.csv", p = a.name),
        json!({}),
    );
    Ok(())
}

/// `powderlab study directions`: each loss's gradient against the dose error's secants.
pub(super) fn directions_cmd(a: args::Directions) -> Result<()> {
    use powderlab::lab::study::directions;
    let (scene, problem, unit) =
        skill_problem(&a.scene, a.run.threads, "scenes/powder_transport.ron")?;
    let landscape = a.page.results.join("landscape.csv");
    let mut points = directions::default_points(Some(&landscape));
    let steps: Vec<f64> = if a.run.quick {
        points.truncate(2);
        vec![0.1]
    } else {
        vec![0.1, 0.05]
    };
    let (labels, thetas): (Vec<String>, Vec<Theta>) = points.into_iter().unzip();
    // Three gradient rollouts, one at Θ and two per parameter and step.
    let n = thetas.len() * (4 + 10 * steps.len());
    let pb = super::super::bar(n as u64, a.common.json);
    let dir = a.common.out.join("directions");
    let start = Instant::now();
    let done = directions::run(&problem, &thetas, &steps, &dir, &|| pb.inc(1))?;
    pb.finish_and_clear();
    let rows = directions::rows(&labels, &thetas, &steps, &done)?;
    let command = format!(
        "powderlab study directions --scene {}{}",
        scene.display(),
        if a.run.quick { " --quick" } else { "" }
    );
    let md = directions::report(&rows, &steps, &command, unit);
    directions::write(&rows, &md, &a.page.results)?;
    print_page(
        a.common.json,
        &a.page.results,
        &md,
        start,
        "directions.md and directions.csv",
        json!({}),
    );
    Ok(())
}

/// `powderlab study refine`: trajectory refinement by dimension, the adjoint against CMA-ES
/// and random search at equal compute.
pub(super) fn refine_cmd(a: args::Refine) -> Result<()> {
    use powderlab::lab::study::refine;
    if a.knots.is_empty() || a.knots.contains(&0) || a.paired.seeds == 0 || a.paired.budget == 0 {
        bail!("study refine: --knots, --seeds and --budget must be at least 1");
    }
    let (scene, problem, unit) = skill_problem(&a.scene, a.threads, "scenes/precise_dosing.ron")?;
    // At most: trust's rollouts depend on its accepted steps, and never pass the budget.
    let per_seed = 5 * a.paired.budget + refine::gradient_rollouts(a.paired.budget);
    super::super::announce_work(
        &scene,
        (a.knots.len() * a.paired.seeds * 6 * a.paired.budget) as f64,
    )?;
    let pb = super::super::bar(
        (a.knots.len() * a.paired.seeds * per_seed) as u64,
        a.common.json,
    );
    let pb2 = pb.clone();
    let store = refine::Store::open(&a.common.out.join("refine"), Box::new(move || pb2.inc(1)))?;
    let start = Instant::now();
    if a.over.is_some_and(|g| !(g.is_finite() && g >= 0.0)) {
        bail!("study refine: --over must be a finite amount of at least 0 (the target's unit)");
    }
    let (starts, screen) = refine::starts(&store, &problem, a.over, a.paired.seeds)?;
    // The screening's rollouts ran first (their number is known only now): the methods' follow.
    pb.set_length(pb.position() + (a.knots.len() * a.paired.seeds * per_seed) as u64);
    let cells = refine::run(&problem, &a.knots, &starts, a.paired.budget, &store)?;
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
        a.paired.seeds,
        a.paired.budget
    );
    let md = refine::report(&cells, &command, unit, a.paired.budget, screen);
    powderlab::util::create_output_dir(&a.page.results, "--results")?;
    powderlab::util::write_atomic(&a.page.results.join("refinement.md"), md.as_bytes())?;
    print_page(
        a.common.json,
        &a.page.results,
        &md,
        start,
        "refinement.md",
        json!({ "cells": cells, "screen": screen }),
    );
    Ok(())
}
