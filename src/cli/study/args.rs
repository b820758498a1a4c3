//! Each study's own arguments: the `study` command's table of subcommands ([`Study`]), one
//! struct per study, with the two groups every study shares ([`Common`], and [`Page`] for
//! those that write a results page).

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
    #[arg(long, value_parser = crate::cli::threads_arg)]
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

/// The studies, one subcommand each: the one table `powderlab study` dispatches through
/// (`study::run`).
#[derive(clap::Subcommand)]
pub enum Study {
    /// Error against run time: the grid resolution, the particles per cell and the substeps
    /// swept on the column collapse and the transport task (error_vs_time.{csv,md,svg}).
    ErrorVsTime(ErrorVsTime),
    /// Time per substep against the particle count and the grid (growth.{json,csv,svg}).
    Growth(Growth),
    /// The loss landscape of Θ by quasi-random rollouts.
    Landscape(Landscape),
    /// The optimisers at equal compute on the skill tasks (optimisation.{md,svg,csv}).
    Optimizers(Optimizers),
    /// The adjoint's gradient against secants and the smoothed gradient (directions.md).
    Directions(Directions),
    /// Residual controls on top of the skill (refinement.md).
    Refine(Refine),
    /// Calibration methods on synthetic observations (calibration.md).
    Calibration(Calibration),
    /// Learning from demonstrations (demonstration.md).
    Demonstration(Demonstration),
    /// Multi-scoop dosing and push/pull plans (planning.md).
    Planning(Planning),
    /// The distilled policy against per-scene optimisation (policy.md).
    Policy(Policy),
    /// Pouring closed on a load cell (pour.md).
    Pour(Pour),
    /// Milligram doses onto a balance on held-out powders (weighing.md).
    Weighing(Weighing),
    /// Mutated scenes through `simulate`: every exit classified (reliability.md).
    Reliability(Reliability),
}

#[derive(Args)]
pub struct ErrorVsTime {
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

#[derive(Args)]
pub struct Growth {
    #[command(flatten)]
    pub common: Common,
    #[command(flatten)]
    pub run: Run,
    /// Run one configuration (JSON) and print its result (in a process of its own).
    #[arg(long, hide = true)]
    pub config: Option<String>,
}

#[derive(Args)]
pub struct Landscape {
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

#[derive(Args)]
pub struct Optimizers {
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
    #[arg(long, value_parser = crate::cli::threads_arg)]
    pub threads: Option<usize>,
}

#[derive(Args)]
pub struct Directions {
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

#[derive(Args)]
pub struct Refine {
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
    #[arg(long, value_parser = crate::cli::threads_arg)]
    pub threads: Option<usize>,
}

#[derive(Args)]
pub struct Calibration {
    #[command(flatten)]
    pub common: Common,
    #[command(flatten)]
    pub paired: Paired,
    #[command(flatten)]
    pub page: Page,
    #[arg(long, value_parser = crate::cli::threads_arg)]
    pub threads: Option<usize>,
}

#[derive(Args)]
pub struct Demonstration {
    #[command(flatten)]
    pub common: Common,
    #[command(flatten)]
    pub page: Page,
}

#[derive(Args)]
pub struct Planning {
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

#[derive(Args)]
pub struct Policy {
    #[command(flatten)]
    pub common: Common,
    #[command(flatten)]
    pub page: Page,
    /// The policy's scene (default scenes/policy_dosing.ron).
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// The first held-out draw: draws 0–19 chose the policy's design (the design draws); 20
    /// and above have judged nothing yet (a verdict stream).
    #[arg(long, default_value_t = 0)]
    pub first_draw: usize,
}

#[derive(Args)]
pub struct Pour {
    #[command(flatten)]
    pub common: Common,
    #[command(flatten)]
    pub page: Page,
    /// The first held-out draw (as `study policy --first-draw`, whose policy it compares with).
    #[arg(long, default_value_t = 0)]
    pub first_draw: usize,
}

#[derive(Args)]
pub struct Reliability {
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

#[derive(Args)]
pub struct Weighing {
    #[command(flatten)]
    pub common: Common,
    #[command(flatten)]
    pub page: Page,
    /// The weighing scene (default scenes/vial_weighing.ron).
    #[arg(long, default_value = "scenes/vial_weighing.ron")]
    pub scene: PathBuf,
    /// Held-out draws to dose.
    #[arg(long, default_value_t = 20)]
    pub draws: usize,
    /// The first held-out draw.
    #[arg(long, default_value_t = 0)]
    pub first_draw: usize,
    /// Worker threads per dose (default: the scene's setting; 0 = all cores).
    #[arg(long, value_parser = crate::cli::threads_arg)]
    pub threads: Option<usize>,
    /// Run no dose: rewrite the page from the doses already kept.
    #[arg(long)]
    pub page_only: bool,
}
