//! The studies of skill optimisation: the optimisers at equal compute (`optimisation.md`), the
//! loss landscape, the adjoint's directions against secants (`directions.md`) and trajectory
//! refinement (`refinement.md`).

pub mod directions;
pub(crate) mod landscape;
pub(crate) mod optimizers;
pub(crate) mod refine;

use crate::lab::optim::problem::Problem;
use crate::lab::study::args::{Common, Page, Paired, Run};
use crate::lab::study::{start_workers, write_page, Ctx, Report, Study};
use crate::sim::announce_work;
use crate::skills::Theta;
use anyhow::{bail, Result};
use serde_json::json;
use std::path::PathBuf;

/// The skill problem of `--scene` (else `default`), its indicator's unit, and the worker pool
/// started with `threads` (else the scene's own thread count, or all cores where `all_cores`).
fn skill_problem(
    scene: &Option<PathBuf>,
    threads: Option<usize>,
    all_cores: bool,
    default: &str,
) -> Result<(PathBuf, Problem, &'static str)> {
    let scene = scene.clone().unwrap_or_else(|| PathBuf::from(default));
    let problem = Problem::new(crate::scene::Scene::load(&scene)?, 1 << 30)?;
    let unit = match problem.target {
        crate::scene::TargetValue::Particles(_) => "particles",
        crate::scene::TargetValue::Grams(_) => "g",
    };
    let own = if all_cores {
        0
    } else {
        problem.scene().simulation.threads
    };
    start_workers(threads.unwrap_or(own))?;
    Ok((scene, problem, unit))
}

/// The loss landscape of Θ by quasi-random rollouts.
pub struct Landscape;

#[derive(clap::Args)]
pub struct LandscapeArgs {
    #[command(flatten)]
    pub common: Common,
    #[command(flatten)]
    pub run: Run,
    /// The skill scene (default scenes/powder_transport.ron).
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// Quasi-random rollouts to run (default 256; 16 with --quick).
    #[arg(long)]
    pub samples: Option<usize>,
}

impl Study for Landscape {
    const NAME: &'static str = "landscape";
    const ABOUT: &'static str = "The loss landscape of Θ by quasi-random rollouts";
    type Args = LandscapeArgs;
    type Outcome = (Vec<landscape::Point>, &'static str);

    fn run(a: &LandscapeArgs, ctx: Ctx) -> Result<Self::Outcome> {
        let n = a.samples.unwrap_or(if a.run.quick { 16 } else { 256 });
        if n < 2 {
            bail!("study landscape: --samples {n}: expected at least 2");
        }
        // The scene's own thread count unless --threads says otherwise.
        let (scene, problem, unit) = skill_problem(
            &a.scene,
            a.run.threads,
            false,
            "scenes/powder_transport.ron",
        )?;
        announce_work(&scene, n as f64)?;
        let thetas = landscape::sobol_thetas(n, 0);
        let pb = ctx.bar(n as u64);
        pb.set_position(landscape::load(&a.common.out)?.len().min(n) as u64);
        let points = landscape::run(&problem, &thetas, &a.common.out, &|| pb.inc(1))?;
        pb.finish_and_clear();
        Ok((points, unit))
    }

    fn page(a: &LandscapeArgs, (points, unit): Self::Outcome, _: Ctx) -> Result<Report> {
        Ok(Report {
            text: landscape::write_report(&points, unit, &a.common.out)?,
            wrote: format!("{} rollouts: landscape.csv and landscape.md", points.len()),
            dir: a.common.out.clone(),
            json: json!({ "rollouts": points.len() }),
            failed: false,
        })
    }
}

/// The optimisers at equal compute on the skill tasks (optimisation.{md,svg,csv}).
pub struct Optimizers;

#[derive(clap::Args)]
pub struct OptimizersArgs {
    #[command(flatten)]
    pub common: Common,
    #[command(flatten)]
    pub paired: Paired,
    #[command(flatten)]
    pub page: Page,
    /// The skill scenes to benchmark (comma separated; default the transport task and the
    /// precise-dosing task).
    #[arg(long, value_delimiter = ',')]
    pub tasks: Vec<PathBuf>,
    /// The methods (comma separated, or all).
    #[arg(long, value_delimiter = ',', default_value = "all")]
    pub method: Vec<String>,
    /// The page's name: NAME.md, NAME.svg and NAME.csv in --results.
    #[arg(long = "page", default_value = "optimisation")]
    pub name: String,
    /// The first seed of the stream: seeds 0–9 chose the optimisers' settings (the design
    /// stream); 10 and above have judged nothing yet (a verdict stream).
    #[arg(long, default_value_t = 0)]
    pub first_seed: usize,
    #[arg(long, value_parser = crate::scene::threads_arg)]
    pub threads: Option<usize>,
}

impl Study for Optimizers {
    const NAME: &'static str = "optimizers";
    const ABOUT: &'static str =
        "The optimisers at equal compute on the skill tasks (optimisation.{md,svg,csv})";
    type Args = OptimizersArgs;
    /// The page, which the benchmark writes after every seed.
    type Outcome = String;

    fn run(a: &OptimizersArgs, ctx: Ctx) -> Result<String> {
        use crate::lab::optim::Method;
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
        start_workers(a.threads.unwrap_or(0))?;
        if a.name.is_empty() || a.name.contains(['/', '\\', '.']) {
            bail!(
                "--page {:?}: expected a file name without a folder or extension, such as optimisation",
                a.name
            );
        }
        let join = |v: Vec<String>| v.join(",");
        let mut command = format!(
            "powderlab study optimizers --tasks {} --seeds {} --budget {} --method {}",
            join(tasks.iter().map(|t| t.display().to_string()).collect()),
            a.paired.seeds,
            a.paired.budget,
            join(methods.iter().map(|m| m.name().to_string()).collect()),
        );
        if a.name != "optimisation" {
            command.push_str(&format!(" --page {}", a.name));
        }
        if a.first_seed != 0 {
            command.push_str(&format!(" --first-seed {}", a.first_seed));
        }
        for t in &tasks {
            announce_work(t, (a.paired.seeds * a.paired.budget * methods.len()) as f64)?;
        }
        optimizers::run(&optimizers::StudyOptions {
            tasks,
            seeds: a.paired.seeds,
            first_seed: a.first_seed,
            budget: a.paired.budget,
            methods,
            // One folder per stream: a run's settings (its first seed among them) fix its
            // journal.
            out: a
                .common
                .out
                .join(crate::lab::streams::folder("optimizers", a.first_seed)),
            results: a.page.results.clone(),
            page: a.name.clone(),
            command,
            quiet: ctx.json,
        })
    }

    fn page(a: &OptimizersArgs, md: String, _: Ctx) -> Result<Report> {
        Ok(Report {
            text: md,
            wrote: format!("{p}.md, {p}.svg and {p}.csv", p = a.name),
            dir: a.page.results.clone(),
            json: json!({}),
            failed: false,
        })
    }
}

/// The adjoint's gradient against secants and the smoothed gradient (directions.md).
pub struct Directions;

#[derive(clap::Args)]
pub struct DirectionsArgs {
    #[command(flatten)]
    pub common: Common,
    #[command(flatten)]
    pub run: Run,
    #[command(flatten)]
    pub page: Page,
    /// The skill scene (default scenes/powder_transport.ron).
    #[arg(long)]
    pub scene: Option<PathBuf>,
}

impl Study for Directions {
    const NAME: &'static str = "directions";
    const ABOUT: &'static str =
        "The adjoint's gradient against secants and the smoothed gradient (directions.md)";
    type Args = DirectionsArgs;
    type Outcome = (Vec<directions::Row>, Vec<f64>, PathBuf, &'static str);

    fn run(a: &DirectionsArgs, ctx: Ctx) -> Result<Self::Outcome> {
        let (scene, problem, unit) =
            skill_problem(&a.scene, a.run.threads, true, "scenes/powder_transport.ron")?;
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
        let pb = ctx.bar((thetas.len() * (4 + 10 * steps.len())) as u64);
        let dir = a.common.out.join("directions");
        let done = directions::run(&problem, &thetas, &steps, &dir, &|| pb.inc(1))?;
        pb.finish_and_clear();
        let rows = directions::rows(&labels, &thetas, &steps, &done)?;
        Ok((rows, steps, scene, unit))
    }

    fn page(
        a: &DirectionsArgs,
        (rows, steps, scene, unit): Self::Outcome,
        _: Ctx,
    ) -> Result<Report> {
        let command = format!(
            "powderlab study directions --scene {}{}",
            scene.display(),
            if a.run.quick { " --quick" } else { "" }
        );
        let md = directions::report(&rows, &steps, &command, unit);
        directions::write(&rows, &md, &a.page.results)?;
        Ok(Report {
            text: md,
            wrote: "directions.md and directions.csv".into(),
            dir: a.page.results.clone(),
            json: json!({}),
            failed: false,
        })
    }
}

/// Residual controls on top of the skill (refinement.md).
pub struct Refine;

#[derive(clap::Args)]
pub struct RefineArgs {
    #[command(flatten)]
    pub common: Common,
    #[command(flatten)]
    pub paired: Paired,
    #[command(flatten)]
    pub page: Page,
    /// The skill scene (default scenes/precise_dosing.ron).
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// Knots per control channel of each dimension tried (6 parameters per knot).
    #[arg(long, value_delimiter = ',', default_values_t = [1usize, 5, 16])]
    pub knots: Vec<usize>,
    /// Start each seed from a Sobol point whose plain skill delivers at least this much more
    /// than the target (the target's unit), instead of Θ_init(k).
    #[arg(long)]
    pub over: Option<f64>,
    #[arg(long, value_parser = crate::scene::threads_arg)]
    pub threads: Option<usize>,
}

impl Study for Refine {
    const NAME: &'static str = "refine";
    const ABOUT: &'static str = "Residual controls on top of the skill (refinement.md)";
    type Args = RefineArgs;
    type Outcome = (
        Vec<refine::Cell>,
        Option<refine::Screen>,
        PathBuf,
        &'static str,
    );

    fn run(a: &RefineArgs, ctx: Ctx) -> Result<Self::Outcome> {
        let (seeds, budget) = (a.paired.seeds, a.paired.budget);
        if a.knots.is_empty() || a.knots.contains(&0) || seeds == 0 || budget == 0 {
            bail!("study refine: --knots, --seeds and --budget must be at least 1");
        }
        if a.over.is_some_and(|g| !(g.is_finite() && g >= 0.0)) {
            bail!("study refine: --over must be a finite amount of at least 0 (the target's unit)");
        }
        let (scene, problem, unit) =
            skill_problem(&a.scene, a.threads, true, "scenes/precise_dosing.ron")?;
        // At most: trust's rollouts depend on its accepted steps, and never pass the budget.
        let per_seed = 5 * budget + refine::gradient_rollouts(budget);
        announce_work(&scene, (a.knots.len() * seeds * 6 * budget) as f64)?;
        let methods = (a.knots.len() * seeds * per_seed) as u64;
        let pb = ctx.bar(methods);
        let pb2 = pb.clone();
        let store =
            refine::Store::open(&a.common.out.join("refine"), Box::new(move || pb2.inc(1)))?;
        let (starts, screen) = refine::starts(&store, &problem, a.over, seeds)?;
        // The screening's rollouts ran first (their number is known only now): the methods'
        // follow.
        pb.set_length(pb.position() + methods);
        let cells = refine::run(&problem, &a.knots, &starts, budget, &store)?;
        pb.finish_and_clear();
        Ok((cells, screen, scene, unit))
    }

    fn page(a: &RefineArgs, (cells, screen, scene, unit): Self::Outcome, _: Ctx) -> Result<Report> {
        let over = a.over.map_or(String::new(), |g| format!(" --over {g}"));
        let knots: Vec<String> = a.knots.iter().map(|k| k.to_string()).collect();
        let command = format!(
            "powderlab study refine --scene {}{over} --knots {} --seeds {} --budget {}",
            scene.display(),
            knots.join(","),
            a.paired.seeds,
            a.paired.budget
        );
        let md = refine::report(&cells, &command, unit, a.paired.budget, screen);
        write_page(&a.page.results, "refinement.md", &md)?;
        Ok(Report {
            text: md,
            wrote: "refinement.md".into(),
            dir: a.page.results.clone(),
            json: json!({ "cells": cells, "screen": screen }),
            failed: false,
        })
    }
}

crate::study_settings!(LandscapeArgs, OptimizersArgs, DirectionsArgs, RefineArgs);
