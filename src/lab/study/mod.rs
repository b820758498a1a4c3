//! The studies behind `docs/results/`: one trait ([`Study`]) and one table
//! ([`table::STUDIES`]) that `powderlab study` dispatches through.
//!
//! Each study lives beside what it measures: the optimisers', landscape, directions and
//! refinement studies in [`crate::lab::optim::study`], calibration in
//! [`crate::lab::calibrate::study`], demonstrations in [`crate::lab::demo::study`], planning in
//! [`crate::lab::plan::study`], the policy and the pour in [`crate::lab::policy::study`], and
//! weighing in [`crate::lab::weigh::study`]. The studies of the simulator itself are here:
//! error against run time ([`error_vs_time`]), time per substep against the problem size
//! ([`growth`]) and the reliability of scene loading ([`reliability`]).
//!
//! A study's arguments are its settings; its run resumes from the journals it keeps under
//! `--out`, so a study stopped part-way goes on where it stopped, and a finished one rewrites
//! its page from what it kept without running anything again.

pub(crate) mod args;
pub mod error_vs_time;
pub mod growth;
pub mod reliability;
pub mod table;

use anyhow::{bail, Context, Result};

use std::path::{Path, PathBuf};

/// What a study's run needs from the command: whether it prints one JSON object (and so no
/// progress bar).
#[derive(Clone, Copy, Debug)]
pub struct Ctx {
    pub json: bool,
}

impl Ctx {
    /// A progress bar of `len` units, hidden under `--json`.
    pub fn bar(&self, len: u64) -> indicatif::ProgressBar {
        crate::util::progress_bar(len, self.json)
    }
}

/// What a study hands back once its page is written: the text it prints, where it wrote what,
/// and the fields its `--json` object adds.
pub struct Report {
    /// Printed to stdout (the page, or the study's table); `markdown` in the JSON object.
    pub text: String,
    /// What was written, for the closing line on stderr ("wrote X to DIR").
    pub wrote: String,
    pub dir: PathBuf,
    /// The JSON object's fields besides `wall_s` and `markdown`.
    pub json: serde_json::Value,
    /// Some of the work failed: the command exits with code 1 after printing.
    pub failed: bool,
}

/// One study: its settings (its own command-line arguments), its run, which resumes from
/// what its journals keep, and its page, written from the run's outcome.
pub trait Study {
    /// The subcommand: `powderlab study NAME`.
    const NAME: &'static str;
    /// The subcommand's line in `powderlab study --help`.
    const ABOUT: &'static str;
    /// The study's settings.
    type Args: clap::Args + clap::FromArgMatches + args::HasCommon;
    /// What the run measured, for the page.
    type Outcome;

    /// A study whose configurations each run in a process of their own (this executable with
    /// `--config`) answers that child's call here: `Some` when the arguments ask for one
    /// configuration, which it runs and prints.
    fn child(_args: &Self::Args) -> Option<Result<()>> {
        None
    }

    /// Runs the study, resuming from its journals under the arguments' output folder.
    fn run(args: &Self::Args, ctx: Ctx) -> Result<Self::Outcome>;

    /// Writes the page (and its figures and tables) from the outcome.
    fn page(args: &Self::Args, outcome: Self::Outcome, ctx: Ctx) -> Result<Report>;
}

/// Runs one configuration of study `study` in a child process (this executable with
/// `--config`), so that its peak memory is its own, and reads the result it prints as its last
/// line.
pub fn run_in_child<C: serde::Serialize, R: serde::de::DeserializeOwned>(
    exe: &Path,
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

/// Writes a study's page: the folder made, the markdown written atomically.
pub fn write_page(dir: &Path, name: &str, md: &str) -> Result<()> {
    crate::util::create_output_dir(dir, "--results")?;
    crate::util::write_atomic(&dir.join(name), md.as_bytes())
        .with_context(|| format!("writing {}", dir.join(name).display()))
}

/// The processor's name and the worker threads, for the page's header.
pub fn machine() -> String {
    format!(
        "{}, {} worker threads",
        cpu_name(),
        rayon::current_num_threads()
    )
}

/// The processor's model name.
pub fn cpu_name() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|t| {
            t.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|s| s.trim().to_string())
        })
        .unwrap_or_else(|| "unknown processor".into())
}

/// Starts the global worker pool with `threads` threads (0: all cores).
pub fn start_workers(threads: usize) -> Result<()> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build_global()
        .context("starting the worker threads")
}
