//! `powderlab simulate`: run a scene forward, record it, save its final state, and print the
//! energy budget.

use anyhow::{Context, Result};
use powderlab::metrics::frame_metrics;
use powderlab::sim::{SimOptions, Simulation};
use powderlab::util::check_output_file;
use std::path::PathBuf;
use std::time::Instant;

/// Run a scene forward, optionally recording it to a Rerun .rrd file.
#[derive(clap::Args)]
pub struct Args {
    scene: PathBuf,
    /// Global steps (default: the scene's horizon).
    #[arg(long)]
    steps: Option<usize>,
    /// Rerun recording to write.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Worker threads (default: the scene's setting; 0 = all cores).
    #[arg(long, value_parser = super::threads_arg)]
    threads: Option<usize>,
    /// Write the final particle positions and velocities as PLY.
    #[arg(long)]
    save_state: Option<PathBuf>,
    /// Run a scene whose estimated work is over the limit (1e10 particle-substeps, about an
    /// hour on the reference machine) anyway.
    #[arg(long)]
    force: bool,
    /// When the run fails mid-way, keep the recording up to the failure (as OUT.partial)
    /// instead of removing it.
    #[arg(long)]
    keep_partial: bool,
}

/// Fault injection for the tests: set to a step number, the run makes one particle's
/// velocity NaN after that step, so that a failure mid-run can be tested on a sound scene.
pub const FAULT_ENV: &str = "POWDERLAB_FAULT_NAN_AT_STEP";

/// Runs the command.
pub fn run(a: Args) -> Result<()> {
    let Args {
        scene,
        steps,
        out,
        threads,
        save_state,
        force,
        keep_partial,
    } = a;
    // Refuse an unwritable output before the run, not after it.
    if let Some(p) = &out {
        check_output_file(p, "--out")?;
    }
    if let Some(p) = &save_state {
        check_output_file(p, "--save-state")?;
    }
    let mut sim = Simulation::from_file(&scene, &SimOptions::threads(threads))?;
    super::describe_stability(&sim);
    let steps = steps.unwrap_or(sim.horizon);
    let n = sim.particle_count();
    let work = sim.work(steps);
    eprintln!("work: {}", work.describe());
    if work.over_limit() && !force {
        // The file's position of the field that drives the work, where the file holds it.
        let (field, why) = work.driver(&sim.scene, &sim.stability);
        let at = field.map_or(String::new(), |f| {
            let (line, col) = powderlab::scene::parse::locate(&sim.scene.source, &f);
            format!(":{line}:{col}")
        });
        anyhow::bail!(
            "{}{at}: {}, over the limit of {:.0e}: {why}; pass --force to run it anyway",
            scene.display(),
            work.describe(),
            powderlab::scene::WORK_LIMIT,
        );
    }
    eprintln!(
        "{}: {} particles, {} steps × {} substeps, {} threads; systems: {}",
        scene.display(),
        n,
        steps,
        sim.params().substeps,
        sim.threads(),
        sim.system_names().join(" → ")
    );
    let target = sim.scene.task.as_ref().map(|t| t.target.clone());
    #[cfg(feature = "rerun")]
    let mut recorder = match &out {
        Some(path) => {
            let mut r = powderlab::record::Recorder::for_scene(path, &mut sim.world, &sim.scene)?;
            r.frame(&mut sim.world)?;
            Some(r)
        }
        None => None,
    };
    #[cfg(not(feature = "rerun"))]
    if out.is_some() {
        anyhow::bail!("--out needs the `rerun` feature: rebuild without --no-default-features");
    }
    let pb = super::bar(steps as u64, false);
    let start = Instant::now();
    // One set of frame metrics per step serves the energy monitor, the recording and the
    // final report.
    let mut energy = powderlab::metrics::EnergyMonitor::default();
    let mut m = frame_metrics(&mut sim.world, target.as_deref());
    energy.observe(&m);
    let fault_at: Option<usize> = std::env::var(FAULT_ENV).ok().and_then(|v| v.parse().ok());
    let mut run = || -> Result<()> {
        for step in 0..steps {
            sim.step()?;
            if fault_at == Some(step) {
                if let Some(mut v) = sim
                    .world
                    .query::<&mut powderlab::components::Velocity>()
                    .iter_mut(&mut sim.world)
                    .next()
                {
                    v.0[0].x = f64::NAN;
                }
            }
            m = frame_metrics(&mut sim.world, target.as_deref());
            energy.observe(&m);
            #[cfg(feature = "rerun")]
            if let Some(r) = recorder.as_mut() {
                r.frame_with(&mut sim.world, &m)?;
            }
            pb.inc(1);
        }
        Ok(())
    };
    let outcome = run();
    pb.finish_and_clear();
    if let Err(e) = outcome {
        // No half-written output under any name unless asked for.
        #[cfg(feature = "rerun")]
        if let Some(r) = recorder {
            if keep_partial {
                let kept = r.keep_partial()?;
                return Err(e.context(format!(
                    "kept the recording up to the failure in {}",
                    kept.display()
                )));
            }
            r.discard();
        }
        #[cfg(not(feature = "rerun"))]
        let _ = keep_partial;
        return Err(e);
    }
    let wall = start.elapsed().as_secs_f64();
    #[cfg(feature = "rerun")]
    if let Some(r) = recorder {
        r.finish()?;
    }
    if let Some(path) = &save_state {
        powderlab::ply::write_ply(path, &sim.body_states())
            .with_context(|| format!("writing {}", path.display()))?;
    }
    let ps = n as f64 * sim.clock().total_substeps as f64;
    eprintln!(
        "done: {steps} steps in {wall:.2} s ({:.3} M particle-substeps/s); mean height {:.4} m{}",
        ps / wall / 1e6,
        m.mean_height,
        target.map_or(String::new(), |t| format!(
            "; {} particles in '{t}'",
            m.transported
        ))
    );
    report_energy(&energy, &sim.scene);
    if let Some(p) = &out {
        eprintln!("recording: {}", p.display());
    }
    if let Some(p) = &save_state {
        eprintln!("state: {}", p.display());
    }
    Ok(())
}

/// Prints the energy budget of a run and flags a spurious gain.
fn report_energy(e: &powderlab::metrics::EnergyMonitor, scene: &powderlab::scene::Scene) {
    let driven = scene.colliders.iter().any(|c| c.control.is_some());
    let verdict = if driven {
        "a driven tool does work on the powder, so a gain is not flagged"
    } else if e.spurious_gain() {
        "SPURIOUS ENERGY GAIN: the total rose above its lowest value by more than 10 % of the energy in play; reduce dt or raise substeps"
    } else {
        "no spurious gain"
    };
    eprintln!(
        "energy (kinetic + gravitational + elastic): {:.6e} J -> {:.6e} J; largest rise {:.3e} J at step {} ({:.3} % of the {:.3e} J in play): {verdict}",
        e.initial.unwrap_or(0.0),
        e.last,
        e.largest_gain,
        e.largest_gain_frame,
        100.0 * e.gain_fraction(),
        e.scale
    );
}
