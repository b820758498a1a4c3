//! `powderlab study error-vs-time`: each configuration in a child process.

use super::{Case, ConfigResult, Outputs};
use crate::lab::study::args::{Common, Run};
use crate::lab::study::{run_in_child, Ctx, Report, Study};
use anyhow::{Context, Result};
use serde_json::json;
use std::path::PathBuf;

/// Error against run time: the grid resolution, the particles per cell and the substeps
/// swept on the column collapse and the transport task (error_vs_time.{csv,md,svg}).
pub struct ErrorVsTime;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub common: Common,
    #[command(flatten)]
    pub run: Run,
    /// The transport task's scene (default scenes/powder_transport.ron).
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// Keep the configurations already finished in OUT/results.json.
    #[arg(long)]
    pub resume: bool,
    /// Run one configuration (JSON) and print its result: the study runs each configuration
    /// in a process of its own, so that its peak memory is its own.
    #[arg(long, hide = true)]
    pub config: Option<String>,
}
crate::study_settings!(Args);

impl Study for ErrorVsTime {
    const NAME: &'static str = "error-vs-time";
    const ABOUT: &'static str = "Error against run time: the grid resolution, the particles per \
        cell and the substeps swept on the column collapse and the transport task \
        (error_vs_time.{csv,md,svg})";
    type Args = Args;
    type Outcome = (Vec<ConfigResult>, Vec<super::Row>);

    fn child(a: &Args) -> Option<Result<()>> {
        let c = a.config.as_ref()?;
        Some((|| {
            let cfg: super::Config = serde_json::from_str(c).context("--config")?;
            let r = super::run_config(&cfg)?;
            println!("{}", serde_json::to_string(&r)?);
            Ok(())
        })())
    }

    fn run(a: &Args, ctx: Ctx) -> Result<Self::Outcome> {
        let scene = a
            .scene
            .clone()
            .unwrap_or_else(|| PathBuf::from("scenes/powder_transport.ron"));
        let plan = super::plan(a.run.quick, &scene, a.run.threads)?;
        // Fail fast on a scene the transport configurations cannot use.
        if let Some(cfg) = plan.iter().find(|c| c.case == Case::PowderTransport) {
            crate::lab::optim::problem::Problem::new(
                super::transport_scene(cfg)?,
                super::TAPE_BUDGET,
            )?;
        }
        let exe = std::env::current_exe().context("cannot find this executable")?;
        let pb = ctx.bar(plan.len() as u64);
        let r = super::run_study(
            &plan,
            &a.common.out,
            a.resume,
            |cfg| {
                run_in_child(&exe, Self::NAME, cfg)
                    .unwrap_or_else(|e| super::failed(cfg, format!("{e:#}")))
            },
            |i, cfg| {
                pb.set_position(i as u64);
                pb.set_message(cfg.label());
            },
        )?;
        pb.finish_and_clear();
        Ok(r)
    }

    fn page(a: &Args, (results, rows): Self::Outcome, ctx: Ctx) -> Result<Report> {
        let failed: Vec<_> = results
            .iter()
            .filter_map(|r| {
                r.failed
                    .as_ref()
                    .map(|f| json!({ "config": r.config.label(), "error": f }))
            })
            .collect();
        if !ctx.json {
            for f in &failed {
                eprintln!("FAILED {}: {}", f["config"], f["error"]);
            }
        }
        let outputs = Outputs::in_dir(&a.common.out);
        Ok(Report {
            text: super::markdown(&rows),
            wrote: format!(
                "{} configurations: {}, {}, {} and {}",
                results.len(),
                outputs.csv.display(),
                outputs.svg.display(),
                outputs.markdown.display(),
                outputs.results.display()
            ),
            dir: a.common.out.clone(),
            json: json!({
                "rows": rows,
                "failed": failed,
                "csv": outputs.csv,
                "svg": outputs.svg,
                "results": outputs.results,
            }),
            failed: !failed.is_empty(),
        })
    }
}
