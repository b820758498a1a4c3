//! The `powderlab` command line: parses the arguments and dispatches to [`cli`], one file per
//! command.

mod cli;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "powderlab",
    version,
    about = "Differentiable MPM simulation of powders"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a scene forward, optionally recording it to a Rerun .rrd file.
    Simulate(cli::simulate::Args),
    /// Measure throughput (particle-substeps per second), wall time, peak memory and stages.
    Bench(cli::bench::Args),
    /// Compare adjoint gradients with central differences (f64), per parameter.
    #[cfg(feature = "lab")]
    Gradcheck(cli::gradcheck::Args),
    /// Fit friction angle, stiffness or contact friction to observed height maps or point
    /// clouds through the adjoint; writes fitted.ron, report.md, loss.svg, calibration.rrd.
    #[cfg(feature = "lab")]
    Calibrate(cli::calibrate::Args),
    /// Write what a camera would see of a scene at a step: a height map (.csv) or a point
    /// cloud (.ply), with optional noise (synthetic observations for `calibrate`).
    #[cfg(feature = "lab")]
    Observe(cli::calibrate::ObserveArgs),
    /// Learn the skill from a demonstration: `make` films a synthetic one, `fit` tracks the
    /// spoon and fits Θ to its path.
    #[cfg(feature = "lab")]
    Demo(cli::demo::Args),
    /// Render PNG frames of a run from one or more cameras (powder as shaded splats, tools and
    /// cups ray-marched from their SDFs).
    #[cfg(feature = "lab")]
    Render(cli::render::Args),
    /// Optimise the skill parameters of the scene's tool (gradient descent, and the baselines
    /// on the same rollout budget); writes metrics.csv, summary.json, indicator.svg, best.rrd.
    #[cfg(feature = "lab")]
    Optimize(cli::optimize::Args),
    /// Plan a dose larger than one spoonful: A* over optimised scoops (seed B's Algorithm 1),
    /// or the greedy and scripted baselines; writes plan-METHOD.json and plan-METHOD.rrd.
    #[cfg(feature = "lab")]
    Plan(cli::plan::Args),
    /// A skill policy over randomised scenes: `dataset`, `train`, `finetune`, `eval`, `apply`.
    #[cfg(feature = "lab")]
    Policy(cli::policy::Args),
    /// Measure the angle of repose of a scene's powder by its heap test (a tube of powder
    /// lifted off a rough floor), over several packings.
    #[cfg(feature = "lab")]
    Repose(cli::repose::Args),
    /// Check against exact solutions and published experiments (the quick set without a case).
    #[cfg(feature = "lab")]
    Validate(cli::validate::Args),
    /// Weigh out a dose: scoop from the vial, tilt and tap the spatula over the boat until the
    /// balance reads the target; prints target, delivered mass, error and scoops.
    #[cfg(feature = "lab")]
    Weigh(cli::weigh::Args),
    /// The studies behind docs/results/, one subcommand each (`powderlab study --help` lists
    /// them).
    #[cfg(feature = "lab")]
    Study(cli::study::Args),
}

fn main() {
    let r = match Cli::parse().command {
        Command::Simulate(a) => cli::simulate::run(a),
        Command::Bench(a) => cli::bench::run(a),
        #[cfg(feature = "lab")]
        Command::Gradcheck(a) => cli::gradcheck::run(a),
        #[cfg(feature = "lab")]
        Command::Calibrate(a) => cli::calibrate::run(a),
        #[cfg(feature = "lab")]
        Command::Observe(a) => cli::calibrate::observe(a),
        #[cfg(feature = "lab")]
        Command::Demo(a) => cli::demo::run(a),
        #[cfg(feature = "lab")]
        Command::Render(a) => cli::render::run(a),
        #[cfg(feature = "lab")]
        Command::Optimize(a) => cli::optimize::run(a),
        #[cfg(feature = "lab")]
        Command::Plan(a) => cli::plan::run(a),
        #[cfg(feature = "lab")]
        Command::Policy(a) => cli::policy::run(a),
        #[cfg(feature = "lab")]
        Command::Repose(a) => cli::repose::run(a),
        #[cfg(feature = "lab")]
        Command::Validate(a) => cli::validate::run(a),
        #[cfg(feature = "lab")]
        Command::Study(a) => cli::study::run(a),
        #[cfg(feature = "lab")]
        Command::Weigh(a) => cli::weigh::run(a),
    };
    if let Err(e) = r {
        eprintln!("error: {e:#}");
        std::process::exit(2);
    }
}
