//! The table of studies: every [`Study`] by its subcommand's name. It lives apart from the trait,
//! which every study imports, so that the table's naming each study makes no import cycle.

use super::args::HasCommon;
use super::{error_vs_time, growth, reliability, Ctx, Study};
use anyhow::{bail, Result};
use clap::{ArgMatches, Args, Command, FromArgMatches};
use serde_json::json;
use std::time::Instant;

/// A row of the table: a study's subcommand and how it runs.
pub struct Entry {
    pub name: &'static str,
    /// Adds the subcommand, with its arguments, to `powderlab study`.
    pub command: fn(Command) -> Command,
    /// Parses the subcommand's arguments and runs the study.
    pub run: fn(&ArgMatches) -> Result<()>,
}

/// The entry of study `S`.
pub const fn entry<S: Study>() -> Entry {
    Entry {
        name: S::NAME,
        command: subcommand::<S>,
        run: parse_and_drive::<S>,
    }
}

fn subcommand<S: Study>(c: Command) -> Command {
    // The argument groups' doc comments would set the subcommand's text: `ABOUT` goes last.
    c.subcommand(
        S::Args::augment_args(Command::new(S::NAME))
            .about(S::ABOUT)
            .long_about(None),
    )
}

fn parse_and_drive<S: Study>(m: &ArgMatches) -> Result<()> {
    let args = S::Args::from_arg_matches(m).map_err(|e| anyhow::anyhow!("{e}"))?;
    drive::<S>(args)
}

/// Every study, in the order of `powderlab study --help`.
pub const STUDIES: &[Entry] = &[
    entry::<error_vs_time::ErrorVsTime>(),
    entry::<growth::Growth>(),
    entry::<crate::lab::optim::study::Landscape>(),
    entry::<crate::lab::optim::study::Optimizers>(),
    entry::<crate::lab::optim::study::Directions>(),
    entry::<crate::lab::optim::study::Refine>(),
    entry::<crate::lab::calibrate::study::CalibrationStudy>(),
    entry::<crate::lab::demo::study::Demonstration>(),
    entry::<crate::lab::plan::study::Planning>(),
    entry::<crate::lab::policy::study::PolicyStudy>(),
    entry::<crate::lab::policy::study::Pour>(),
    entry::<crate::lab::weigh::study::WeighingStudy>(),
    entry::<reliability::ReliabilityStudy>(),
];

/// The `study` command with one subcommand per row of [`STUDIES`].
pub fn command(study: Command) -> Command {
    STUDIES
        .iter()
        .fold(study.subcommand_required(true), |c, e| (e.command)(c))
}

/// Runs the study that `matches` (the `study` command's) names.
pub fn dispatch(matches: &ArgMatches) -> Result<()> {
    let Some((name, sub)) = matches.subcommand() else {
        bail!("study: name a study (powderlab study --help lists them)");
    };
    match STUDIES.iter().find(|e| e.name == name) {
        Some(e) => (e.run)(sub),
        None => bail!("study {name}: no such study (powderlab study --help lists them)"),
    }
}

/// Runs study `S`: a child's configuration, or the run and then the page, and prints what the
/// page's report says (one JSON object under `--json`).
fn drive<S: Study>(args: S::Args) -> Result<()> {
    if let Some(r) = S::child(&args) {
        return r;
    }
    let ctx = Ctx {
        json: args.common().json,
    };
    let start = Instant::now();
    let outcome = S::run(&args, ctx)?;
    let r = S::page(&args, outcome, ctx)?;
    let wall_s = start.elapsed().as_secs_f64();
    if ctx.json {
        let mut o = json!({ "wall_s": wall_s, "markdown": r.text });
        if let (Some(o), Some(e)) = (o.as_object_mut(), r.json.as_object()) {
            o.extend(e.clone());
        }
        println!("{o}");
    } else {
        print!("{}", r.text);
        eprintln!("{wall_s:.0} s; wrote {} to {}", r.wrote, r.dir.display());
    }
    if r.failed {
        std::process::exit(1);
    }
    Ok(())
}
