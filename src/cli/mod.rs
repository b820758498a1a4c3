//! The commands of the `powderlab` binary, one file each. Each parses its own arguments
//! (`Args`) and calls the library; what a command decides beyond reading its arguments and
//! printing lives in the library module it calls.

pub mod bench;
#[cfg(feature = "lab")]
pub mod calibrate;
#[cfg(feature = "lab")]
pub mod demo;
#[cfg(feature = "lab")]
pub mod gradcheck;
#[cfg(feature = "lab")]
pub mod optimize;
#[cfg(feature = "lab")]
pub mod plan;
#[cfg(feature = "lab")]
pub mod policy;
#[cfg(feature = "lab")]
pub mod render;
#[cfg(feature = "lab")]
pub mod repose;
pub mod simulate;
#[cfg(feature = "lab")]
pub mod study;
#[cfg(feature = "lab")]
pub mod validate;
#[cfg(feature = "lab")]
pub mod weigh;

pub use powderlab::scene::threads_arg;
use powderlab::sim::Simulation;
pub use powderlab::util::progress_bar as bar;

/// Prints what the stability guard found and whether it raised the substeps.
pub fn describe_stability(sim: &Simulation) {
    let s = &sim.stability;
    let p = sim.params();
    // Nothing moves and nothing is elastic (no particles, static colliders): no limit.
    let limit = if s.dt_max.is_finite() {
        format!("{:.3e} s", s.dt_max)
    } else {
        "unlimited (nothing in the scene moves or deforms)".into()
    };
    eprintln!(
        "stability: wave speed {:.3} m/s, largest speed {:.3} m/s, stable substep {limit}",
        s.wave_speed, s.max_speed
    );
    if s.raised() {
        eprintln!(
            "stability: Auto raised substeps from {} to {} (Δt_sub = {:.3e} s)",
            s.substeps_requested, s.substeps, p.dt_sub
        );
    }
}

/// Writes a report to `report` (atomically) if asked, and prints it as one JSON object with
/// `--json`; returns whether the caller should print its text form instead.
#[cfg(feature = "lab")]
pub fn report_or_json(
    obj: &serde_json::Value,
    report: Option<&std::path::Path>,
    json_out: bool,
) -> anyhow::Result<bool> {
    if let Some(p) = report {
        powderlab::util::write_atomic(p, serde_json::to_string_pretty(obj)?.as_bytes())?;
    }
    if json_out {
        println!("{obj}");
    }
    Ok(!json_out)
}

/// The scene at `path` with each `--set NAME=VALUE` of `sets` applied, refused in one line if
/// the values make it invalid.
#[cfg(feature = "lab")]
pub fn load_with_sets(
    path: &std::path::Path,
    sets: &[String],
) -> anyhow::Result<powderlab::scene::Scene> {
    let mut scene = powderlab::scene::Scene::load(path)?;
    for (p, v) in assignments(&scene, "--set", sets)? {
        p.apply(&mut scene, v);
    }
    if let Err(e) = scene.validate() {
        anyhow::bail!("--set: the scene with these values is refused: {e}");
    }
    Ok(scene)
}

/// `NAME=VALUE` pairs against the fitted (or settable) parameters of `scene` (`--set`).
#[cfg(feature = "lab")]
pub fn assignments(
    scene: &powderlab::scene::Scene,
    flag: &str,
    pairs: &[String],
) -> anyhow::Result<Vec<(powderlab::lab::calibrate::params::FitParam, f64)>> {
    let mut out = Vec::new();
    for a in pairs {
        use anyhow::Context;
        let (name, v) = a
            .split_once('=')
            .with_context(|| format!("{flag} {a}: expected NAME=VALUE, e.g. friction_deg=35"))?;
        let v: f64 = v
            .trim()
            .parse()
            .ok()
            .filter(|x: &f64| x.is_finite())
            .with_context(|| format!("{flag} {a}: '{v}' is not a finite number"))?;
        let p = powderlab::lab::calibrate::params::parse(scene, &[name.to_string()], &[])
            .map_err(|e| anyhow::anyhow!("{}", e.replacen("--fit", flag, 1)))?
            .remove(0);
        out.push((p, v));
    }
    Ok(out)
}
