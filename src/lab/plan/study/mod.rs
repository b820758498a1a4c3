//! The planning study (`planning.md`): multi-scoop dosing and the push/pull classes, A*
//! against greedy and scripted plans.

pub mod planning;
pub mod push;
pub mod push_directions;

use crate::lab::plan::dosing::Method;
use crate::lab::study::args::{Common, Page};
use crate::lab::study::{machine, write_page, Ctx, Report, Study};
use crate::scene::plan::PlanSpec;
use anyhow::{bail, Result};
use std::path::PathBuf;

/// Multi-scoop dosing and push/pull plans (planning.md).
pub struct Planning;

/// The push direction test runs at the first this many kept layouts of each class.
pub const DIRECTION_LAYOUTS: usize = 5;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub common: Common,
    #[command(flatten)]
    pub page: Page,
    /// The plan scenes (comma separated; default scenes/multi_scoop_dosing.ron and
    /// scenes/plate_push.ron).
    #[arg(long, value_delimiter = ',')]
    pub tasks: Vec<PathBuf>,
    /// Instances per task.
    #[arg(long, default_value_t = 10)]
    pub seeds: usize,
    /// Push layouts: `kept` (the design stream the settings were chosen on), `fresh` (the
    /// verdict stream) or `both`.
    #[arg(long, default_value = "both")]
    pub layouts: String,
    /// Worker threads of every simulation (default: the scenes' setting). Results do not
    /// depend on it; small scenes run faster as two studies of one thread each.
    #[arg(long, value_parser = crate::scene::threads_arg)]
    pub threads: Option<usize>,
    /// The planners (comma separated, or all).
    #[arg(long, value_delimiter = ',', default_value = "all")]
    pub method: Vec<String>,
}
crate::study_settings!(Args);

impl Study for Planning {
    const NAME: &'static str = "planning";
    const ABOUT: &'static str = "Multi-scoop dosing and push/pull plans (planning.md)";
    type Args = Args;
    type Outcome = (
        Vec<planning::Row>,
        Vec<push::PushRow>,
        Vec<push_directions::Point>,
    );

    /// Multi-scoop dosing and the four push/pull classes over randomised instances, A* against
    /// greedy and scripted (`--seeds` instances of each, 10 by default).
    fn run(a: &Args, ctx: Ctx) -> Result<Self::Outcome> {
        // The two tasks' scenes, or those `--tasks` names (a push plan or a dosing plan each).
        let tasks = if a.tasks.is_empty() {
            vec![
                PathBuf::from("scenes/multi_scoop_dosing.ron"),
                PathBuf::from("scenes/plate_push.ron"),
            ]
        } else {
            a.tasks.clone()
        };
        let (mut dosing, mut pushing) = (None, None);
        for t in &tasks {
            let mut s = crate::scene::Scene::load(t)?;
            if let Some(n) = a.threads {
                s.simulation.threads = n;
            }
            match &s.plan {
                Some(PlanSpec::Dosing(_)) => dosing = Some(s),
                Some(PlanSpec::Push(_)) => pushing = Some(s),
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
        let (kept, fresh) = match a.layouts.as_str() {
            "kept" => (true, false),
            "fresh" => (false, true),
            "both" => (true, true),
            o => bail!("--layouts {o}: expected kept, fresh or both"),
        };
        let mut pushes: Vec<(bool, push::PushInstance)> = Vec::new();
        if pushing.is_some() {
            for (on, seed, is_fresh) in [
                (kept, push::KEPT_SEED, false),
                (fresh, push::FRESH_SEED, true),
            ] {
                if on {
                    let all = push::push_instances(a.seeds, seed);
                    pushes.extend(all.into_iter().map(|i| (is_fresh, i)));
                }
            }
        }
        let push_planners = push::planners(&methods);
        let pb =
            ctx.bar((instances.len() * methods.len() + pushes.len() * push_planners.len()) as u64);
        let rows = match &dosing {
            Some(scene) => planning::run(
                scene,
                &a.common.out.join("planning"),
                &instances,
                &methods,
                &|k, m| {
                    pb.inc(1);
                    pb.set_message(format!("dosing instance {k}: {}", m.name()));
                },
            )?,
            None => Vec::new(),
        };
        let push_rows = match &pushing {
            Some(scene) => push::run_push(
                scene,
                &a.common.out.join("planning/push"),
                &pushes,
                &push_planners,
                &|k, m| {
                    pb.inc(1);
                    pb.set_message(format!("push instance {k}: {}", m.name()));
                },
            )?,
            None => Vec::new(),
        };
        // The direction test on the first five kept layouts of each class.
        let points = match &pushing {
            Some(scene) if kept => {
                let at: Vec<push::PushInstance> = push::push_instances(a.seeds, push::KEPT_SEED)
                    .into_iter()
                    .filter(|i| i.index < DIRECTION_LAYOUTS)
                    .collect();
                push_directions::run(
                    scene,
                    &a.common.out.join("planning/push/directions"),
                    &at,
                    &|k| {
                        pb.set_message(format!("push direction test {k}/{}", at.len()));
                    },
                )?
            }
            _ => Vec::new(),
        };
        pb.finish_and_clear();
        Ok((rows, push_rows, points))
    }

    fn page(a: &Args, (rows, push_rows, points): Self::Outcome, _: Ctx) -> Result<Report> {
        let command = format!(
            "powderlab study planning --seeds {} --out {}",
            a.seeds,
            a.common.out.display()
        );
        let push_machine = a.threads.map_or_else(machine, |n| {
            format!(
                "{}, {n} worker thread(s) per simulation",
                crate::lab::study::cpu_name()
            )
        });
        let push_md =
            push::push_report(&push_rows, &push_machine) + &push_directions::report(&points);
        // Without the dosing task, the page keeps its dosing section and replaces the rest.
        let md = if rows.is_empty() {
            let old =
                std::fs::read_to_string(a.page.results.join("planning.md")).unwrap_or_default();
            let head = old
                .split(push::SECTION)
                .next()
                .unwrap_or_default()
                .trim_end();
            format!("{head}\n{push_md}")
        } else {
            planning::report(&rows, &command, &machine()) + &push_md
        };
        write_page(&a.page.results, "planning.md", &md)?;
        Ok(Report {
            text: md,
            wrote: "planning.md".into(),
            dir: a.page.results.clone(),
            json: serde_json::json!({ "instances": rows.len(), "push_instances": push_rows.len() }),
            failed: false,
        })
    }
}
