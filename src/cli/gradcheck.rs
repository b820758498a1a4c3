//! `powderlab gradcheck`: the adjoint's gradients against central differences in f64, per
//! parameter.

use anyhow::{bail, Result};
use powderlab::sim::{SimOptions, Simulation};
use serde_json::json;
use std::path::PathBuf;

/// Compare adjoint gradients with central differences (f64), per parameter.
#[derive(clap::Args)]
pub struct Args {
    scene: PathBuf,
    /// Parameter groups: v0, x0, material, friction, gravity, tool, skill (comma separated).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "v0,x0,material,friction,gravity"
    )]
    params: Vec<String>,
    /// Global steps (default: the scene's horizon).
    #[arg(long)]
    steps: Option<usize>,
    #[arg(long, value_parser = super::threads_arg)]
    threads: Option<usize>,
    /// Memory budget of the tape in MB.
    #[arg(long, default_value_t = 1024)]
    budget_mb: usize,
    /// Largest relative error that passes.
    #[arg(long, default_value_t = 1e-3)]
    tol: f64,
    /// Multiply every central-difference step by this factor (a sweep over it tells a wrong
    /// adjoint from a contact switch inside the step).
    #[arg(long, default_value_t = 1.0)]
    eps_scale: f64,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

/// Runs the command.
pub fn run(a: Args) -> Result<()> {
    let Args {
        scene,
        params,
        steps,
        threads,
        budget_mb,
        tol,
        eps_scale,
        json: json_out,
    } = a;
    if !(tol.is_finite() && tol > 0.0) {
        bail!("--tol {tol}: expected a positive relative error, such as 1e-3");
    }
    let sc = powderlab::scene::Scene::load(&scene)?;
    let steps = match steps {
        Some(s) => s,
        None => Simulation::new(&sc, &SimOptions::threads(threads))?.horizon,
    };
    if !json_out {
        eprintln!(
            "{}: gradients over {steps} steps, loss Σ‖x_p(T) − t‖ ...",
            scene.display()
        );
    }
    let r = powderlab::lab::gradcheck::run_scaled(
        &sc,
        steps,
        &params,
        threads,
        budget_mb << 20,
        eps_scale,
    )?;
    let passed = r.max_rel_error <= tol;
    if json_out {
        let mut v = serde_json::to_value(&r)?;
        v["passed"] = json!(passed);
        v["tolerance"] = json!(tol);
        println!("{v}");
    } else {
        println!("loss {:.9e} at target ({:.4}, {:.4}, {:.4}) m; checkpoint every {} steps; tape {:.1} MB", r.loss, r.target_m[0], r.target_m[1], r.target_m[2], r.checkpoint_every, r.tape_bytes as f64 / 1e6);
        println!(
            "forward {:.2} s, forward + backward {:.2} s (ratio {:.2})",
            r.forward_s,
            r.forward_backward_s,
            r.forward_backward_s / r.forward_s
        );
        println!(
            "{:<40} {:>18} {:>18} {:>10} {:>8}",
            "parameter", "adjoint", "finite difference", "rel error", "eps"
        );
        for row in &r.rows {
            let note = if row.noise_limited {
                format!(
                    "zero gradient: both below the round-off floor {:.1e}",
                    row.noise_floor
                )
            } else if let Some((side, e)) = row.nearest_side() {
                let [minus, plus] = row.one_sided;
                let follows = if e <= tol {
                    format!("the adjoint follows {side} (to {e:.1e})")
                } else {
                    format!("the adjoint follows neither side nor their mean (nearest: {side}, {e:.1e} off), so it is not a one-sided derivative here")
                };
                format!(
                    "kink at this point: one-sided differences {minus:.6e} (−) and {plus:.6e} (+); {follows}"
                )
            } else {
                String::new()
            };
            println!(
                "{:<40} {:>18.10e} {:>18.10e} {:>10.2e} {:>8.0e}  {note}",
                row.parameter, row.adjoint, row.finite_difference, row.rel_error, row.eps
            );
        }
        println!(
            "max relative error (non-zero gradients; at a kink, against the nearest side or their mean) {:.2e}: {}",
            r.max_rel_error,
            if passed { "PASS" } else { "FAIL" }
        );
    }
    if !passed {
        std::process::exit(1);
    }
    Ok(())
}
