//! The demonstration study (`demonstration.md`): synthetic demonstrations filmed and fitted
//! back, and an expert's demonstration as an optimiser's warm start.

pub mod demonstration;
pub mod warm_start;

use crate::lab::study::args::{Common, Page};
use crate::lab::study::{machine, write_page, Ctx, Report, Study};
use anyhow::Result;

/// Learning from demonstrations (demonstration.md).
pub struct Demonstration;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub common: Common,
    #[command(flatten)]
    pub page: Page,
}
crate::study_settings!(Args);

/// The study's skill scene.
const SCENE: &str = "scenes/powder_transport.ron";

/// The cameras' film: 160 × 120 pixels, every 4th step, 2 % noise.
const SETUP: demonstration::Setup = demonstration::Setup {
    size: (160, 120),
    every: 4,
    noise: 0.02,
};

impl Study for Demonstration {
    const NAME: &'static str = "demonstration";
    const ABOUT: &'static str = "Learning from demonstrations (demonstration.md)";
    type Args = Args;
    type Outcome = (Vec<demonstration::Row>, warm_start::WarmStart);

    /// Five synthetic demonstrations filmed and fitted back, and an expert's demonstration as
    /// the warm start of an optimisation.
    fn run(a: &Args, ctx: Ctx) -> Result<Self::Outcome> {
        let scene = crate::scene::Scene::load(SCENE)?;
        let pb = ctx.bar(demonstration::THETAS.len() as u64);
        let pb2 = pb.clone();
        let rows = demonstration::run(
            &scene,
            &a.common.out.join("demonstration"),
            &SETUP,
            &move |k| pb2.set_position(k as u64),
        )?;
        pb.finish_and_clear();
        if !ctx.json {
            eprintln!(
                "the warm start: an expert's demonstration, then CMA-ES from it and from random starts"
            );
        }
        let warm = warm_start::run(
            &scene,
            &a.common.out.join("demonstration/warm_start"),
            &SETUP,
        )?;
        Ok((rows, warm))
    }

    fn page(a: &Args, (rows, warm): Self::Outcome, _: Ctx) -> Result<Report> {
        let md = demonstration::report(
            &rows,
            SCENE,
            &SETUP,
            "powderlab study demonstration",
            &machine(),
        ) + &warm_start::report(&warm);
        write_page(&a.page.results, "demonstration.md", &md)?;
        Ok(Report {
            text: md,
            wrote: "demonstration.md".into(),
            dir: a.page.results.clone(),
            json: serde_json::json!({ "rows": rows.len() }),
            failed: false,
        })
    }
}
