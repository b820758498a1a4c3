//! The argument groups every study's settings share: [`Common`] (the output folder and
//! `--json`), [`Page`] for those that write a page of `docs/results/`, [`Run`] (quick and
//! threads) and [`Paired`] (paired seeds at a budget).

use clap::Args;
use std::path::PathBuf;

/// Every study: where its rollouts and resumable state go, and how it reports.
#[derive(Args)]
pub struct Common {
    /// Output folder (the study's journals and working files; it resumes from them).
    #[arg(long, default_value = "study")]
    pub out: PathBuf,
    /// Print one JSON object.
    #[arg(long)]
    pub json: bool,
}

/// Every study's settings hold the [`Common`] group.
pub trait HasCommon {
    fn common(&self) -> &Common;
}

/// Implements [`HasCommon`] for settings whose `common` field is the group.
#[macro_export]
macro_rules! study_settings {
    ($($t:ty),+) => {
        $(impl $crate::lab::study::args::HasCommon for $t {
            fn common(&self) -> &$crate::lab::study::args::Common {
                &self.common
            }
        })+
    };
}

/// The studies that write a page of `docs/results/`.
#[derive(Args)]
pub struct Page {
    /// Where the page goes.
    #[arg(long, default_value = "docs/results")]
    pub results: PathBuf,
}

/// How long a study runs, and on how many threads.
#[derive(Args)]
pub struct Run {
    /// A seconds-long version of the study (tests and CI).
    #[arg(long)]
    pub quick: bool,
    #[arg(long, value_parser = crate::scene::threads_arg)]
    pub threads: Option<usize>,
}

/// The studies that compare methods on paired seeds at equal compute.
#[derive(Args)]
pub struct Paired {
    /// Paired seeds (draws) per task.
    #[arg(long, default_value_t = 10)]
    pub seeds: usize,
    /// Compute per seed and method, in forward rollouts.
    #[arg(long, default_value_t = 20)]
    pub budget: usize,
}
