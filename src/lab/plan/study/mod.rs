//! The planning study (`planning.md`): multi-scoop dosing and the push/pull classes, A*
//! against greedy and scripted plans.

pub mod planning;
pub mod push;

use crate::lab::plan::dosing::Method;
use crate::lab::study::args::{Common, Page};
use crate::lab::study::{machine, write_page, Ctx, Report, Study};
use crate::scene::plan::PlanSpec;
use anyhow::{bail, Result};
use std::path::PathBuf;

/// Multi-scoop dosing and push/pull plans (planning.md).
pub struct Planning;

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
    /// The planners (comma separated, or all).
    #[arg(long, value_delimiter = ',', default_value = "all")]
    pub method: Vec<String>,
}
crate::study_settings!(Args);

impl Study for Planning {
    const NAME: &'static str = "planning";
    const ABOUT: &'static str = "Multi-scoop dosing and push/pull plans (planning.md)";
    type Args = Args;
    type Outcome = (Vec<planning::Row>, Vec<push::PushRow>);

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
            let s = crate::scene::Scene::load(t)?;
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
        let pushes = pushing
            .as_ref()
            .map_or(Vec::new(), |_| push::push_instances(a.seeds, 2027));
        let pb = ctx.bar(((instances.len() + pushes.len()) * methods.len()) as u64);
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
                &methods,
                &|k, m| {
                    pb.inc(1);
                    pb.set_message(format!("push instance {k}: {}", m.name()));
                },
            )?,
            None => Vec::new(),
        };
        pb.finish_and_clear();
        Ok((rows, push_rows))
    }

    fn page(a: &Args, (rows, push_rows): Self::Outcome, _: Ctx) -> Result<Report> {
        let command = format!(
            "powderlab study planning --seeds {} --out {}",
            a.seeds,
            a.common.out.display()
        );
        let md = planning::report(&rows, &command, &machine()) + &push::push_report(&push_rows);
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
