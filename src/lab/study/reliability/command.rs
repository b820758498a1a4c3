//! `powderlab study reliability`: the settings and the page of [`super::run`].

use super::{report, run, Config, Record};
use crate::lab::study::args::{Common, Page};
use crate::lab::study::{machine, write_page, Ctx, Report, Study};
use anyhow::{bail, Context, Result};

/// Mutated scenes through `simulate`: every exit classified (reliability.md).
pub struct ReliabilityStudy;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub common: Common,
    #[command(flatten)]
    pub page: Page,
    /// Mutated scenes to run through `simulate`.
    #[arg(long, default_value_t = 10_000)]
    pub cases: usize,
    /// Address-space cap per process, in GB.
    #[arg(long, default_value_t = 8.0)]
    pub cap_gb: f64,
    /// Wall-clock limit per process, in seconds.
    #[arg(long, default_value_t = 20.0)]
    pub timeout_s: f64,
    /// Processes side by side.
    #[arg(long, default_value_t = 2)]
    pub jobs: usize,
}
crate::study_settings!(Args);

impl Args {
    fn config(&self) -> Config {
        Config {
            cases: self.cases,
            cap_bytes: (self.cap_gb * (1u64 << 30) as f64) as u64,
            timeout_s: self.timeout_s,
            jobs: self.jobs,
        }
    }
}

impl Study for ReliabilityStudy {
    const NAME: &'static str = "reliability";
    const ABOUT: &'static str =
        "Mutated scenes through `simulate`: every exit classified (reliability.md)";
    type Args = Args;
    type Outcome = Vec<Record>;

    /// `simulate` on mutated scenes under a memory cap and a timeout, resuming from
    /// OUT/reliability/cases.jsonl.
    fn run(a: &Args, ctx: Ctx) -> Result<Vec<Record>> {
        if !(a.cap_gb > 0.0 && a.timeout_s > 0.0 && a.cases > 0 && a.jobs > 0) {
            bail!("--cases, --cap-gb, --timeout-s and --jobs must be positive");
        }
        let cfg = a.config();
        let exe = std::env::current_exe().context("cannot find this executable")?;
        let dir = a.common.out.join("reliability");
        let pb = ctx.bar(cfg.cases as u64);
        let records = run(&exe, std::path::Path::new("."), &dir, &cfg, &|k, n| {
            pb.set_length(n as u64);
            pb.set_position(k as u64);
        })?;
        pb.finish_and_clear();
        Ok(records)
    }

    fn page(a: &Args, records: Vec<Record>, _: Ctx) -> Result<Report> {
        let cfg = a.config();
        let command = format!(
            "powderlab study reliability --cases {} --cap-gb {} --timeout-s {} --jobs {}",
            cfg.cases, a.cap_gb, a.timeout_s, cfg.jobs
        );
        let md = report(&records, &cfg, &command, &machine());
        write_page(&a.page.results, "reliability.md", &md)?;
        let problems = records.iter().filter(|r| r.problem.is_some()).count();
        Ok(Report {
            text: format!(
                "{} cases, {problems} breaking the acceptance\n",
                records.len()
            ),
            wrote: "reliability.md".into(),
            dir: a.page.results.clone(),
            json: serde_json::json!({ "cases": records.len(), "problems": problems }),
            failed: false,
        })
    }
}
