//! The run-out of one column collapse, planar or axisymmetric, with Drucker–Prager or μ(I), at
//! several resolutions: does the flow law decide whether the run-out converges?
//!
//! `cargo run --release --example collapse_convergence -- GEOMETRY RHEOLOGY [A=1]
//! [CELLS=10,20,40] [GRAIN_MM=0.5] [FLOOR_MU=0.577]`
//!
//! GEOMETRY is `planar` (the validation's slab, cells across L₀) or `axisym` (the quarter
//! cylinder, cells across R₀); RHEOLOGY is `dp` (Klár's cone at 22°, the validation's) or `mui`
//! (μ(I) with the same static friction, `Rheology::mu_i_matching`, grains of GRAIN_MM). Prints
//! one line per resolution: the run-out, the front's arrest time, the particles, the substeps
//! and the wall time, and each run-out's change from the previous resolution.

use powderlab::lab::validate::axisym::{run_axisym, Axisym};
use powderlab::lab::validate::{run_collapse, Collapse, Rheology};

fn usage() -> String {
    "usage: collapse_convergence planar|axisym dp|mui [A=1] [CELLS=10,20,40] [GRAIN_MM=0.5] \
     [FLOOR_MU=0.577]"
        .into()
}

/// Argument `k` (named `name` in errors), or `default` when it is absent.
fn arg<T: std::str::FromStr>(k: usize, name: &str, default: T) -> anyhow::Result<T> {
    match std::env::args().nth(k) {
        None => Ok(default),
        Some(s) => s
            .parse()
            .map_err(|_| anyhow::anyhow!("{name} = {s:?} does not parse; {}", usage())),
    }
}

fn main() -> anyhow::Result<()> {
    let geometry: String = arg(1, "GEOMETRY", String::new())?;
    let rheology: String = arg(2, "RHEOLOGY", String::new())?;
    let a: f64 = arg(3, "A", 1.0)?;
    let cells: String = arg(4, "CELLS", "10,20,40".to_string())?;
    let grain_mm: f64 = arg(5, "GRAIN_MM", 0.5)?;
    let floor_mu: f64 = arg(6, "FLOOR_MU", 0.577)?;
    let cells: Vec<usize> = cells
        .split(',')
        .map(|c| c.parse())
        .collect::<Result<_, _>>()
        .map_err(|_| {
            anyhow::anyhow!(
                "CELLS = {cells:?}: a comma-separated list of whole numbers; {}",
                usage()
            )
        })?;
    let planar = Collapse::new(a, 1);
    let rheology = match rheology.as_str() {
        "dp" => Rheology::DruckerPrager,
        "mui" => Rheology::mu_i_matching(planar.friction_deg, grain_mm * 1e-3),
        other => anyhow::bail!("RHEOLOGY = {other:?}: dp or mui; {}", usage()),
    };
    println!("{geometry} a = {a}, {rheology:?}, floor friction {floor_mu}");
    let mut last: Option<f64> = None;
    for n in cells {
        let (runout, arrest, particles, substeps, wall) = match geometry.as_str() {
            "planar" => {
                let mut c = Collapse::new(a, n);
                c.rheology = rheology;
                c.floor_friction = floor_mu;
                let r = run_collapse(&c, None, |_| {})?;
                (
                    r.runout_ratio,
                    r.front_arrest_tc,
                    r.particles,
                    r.substeps,
                    r.wall_s,
                )
            }
            "axisym" => {
                let mut c = Axisym::new(a, n);
                c.rheology = rheology;
                c.floor_friction = floor_mu;
                let r = run_axisym(&c, None, |_| {})?;
                (
                    r.runout_ratio,
                    r.front_arrest_tc,
                    r.particles,
                    r.substeps,
                    r.wall_s,
                )
            }
            other => anyhow::bail!("GEOMETRY = {other:?}: planar or axisym; {}", usage()),
        };
        let change = last.map_or(String::new(), |l| {
            format!(", {:+.1} % from the previous", 100.0 * (runout - l) / l)
        });
        println!(
            "cells {n:>3}: run-out {runout:.3}{change}; front arrest {} T_c; {particles} particles, {substeps} substeps, {wall:.1} s",
            arrest.map_or("-".into(), |t| format!("{t:.2}"))
        );
        last = Some(runout);
    }
    Ok(())
}
