//! The central difference of a skill scene's loss along `u = (1, …, 1)/√5` in Θ, for step sizes
//! ε from 1e-10 to 1e-3, against the adjoint's `∂L/∂Θ·u`: where they agree, and where a
//! contact switch inside ±ε (a jump of the loss) takes over the difference.
//!
//! ```sh
//! cargo run --release --example fd_eps_sweep -- SCENE [DX_M|-] [THETA] [grad]
//! ```
//!
//! `DX_M` re-grids the scene as `powderlab study error-vs-time` does (every length in metres
//! kept, substeps scaled as 1/dx); `-` keeps the scene's grid. `THETA` (five comma-separated
//! values) replaces the scene's Θ, and `grad` sweeps along the adjoint gradient's own direction
//! `u = ∂L/∂Θ / ‖∂L/∂Θ‖` instead: where a rollout returns an unusually large gradient, this says
//! whether the loss really is that steep there.

use powderlab::lab::optim::problem::Problem;
use powderlab::lab::study::error_vs_time::{along, parse_theta, regrid};
use powderlab::scene::Scene;
use rayon::prelude::*;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let Some(path) = args.get(1) else {
        anyhow::bail!("usage: fd_eps_sweep SCENE [DX_M|-] [THETA] [grad]");
    };
    // Checked before the rollouts, which take most of a minute on the default scene.
    let along_gradient = match args.get(4).map(String::as_str) {
        None => false,
        Some("grad") => true,
        Some(other) => anyhow::bail!("the fourth argument is `grad` or nothing, got {other:?}"),
    };
    let scene = regrid(Scene::load(path)?, args.get(2).map(String::as_str))?;
    let p = Problem::new(scene, 2048 << 20)?;
    let t0 = match args.get(3) {
        None => p.scene_theta(),
        Some(t) => parse_theta(t)?,
    };
    let o = p.evaluate(t0, true, false)?;
    let g = o.grad.expect("asked for the gradient");
    let norm = g.iter().map(|g| g * g).sum::<f64>().sqrt();
    let u: [f64; 5] = if along_gradient {
        anyhow::ensure!(
            norm > 0.0,
            "the gradient at {t0:?} is zero: no direction to sweep"
        );
        std::array::from_fn(|i| g[i] / norm)
    } else {
        [1.0 / 5f64.sqrt(); 5]
    };
    println!("Θ = {t0:?}, ∂L/∂Θ = {g:?} (norm {norm:.6e}), u = {u:?}");
    let adj: f64 = g.iter().zip(&u).map(|(g, u)| g * u).sum();
    println!("L = {:.12}, adjoint ∂L/∂Θ·u = {adj:.6e}", o.loss);
    println!(
        "{:>8} {:>14} {:>14} {:>10}",
        "eps", "L(+)-L(-)", "central diff", "rel err"
    );
    let eps: Vec<f64> = (0..8).map(|k| 10f64.powi(-10 + k)).collect();
    let rows: Vec<(f64, f64, f64)> = eps
        .par_iter()
        .map(|&e| {
            let at = |s: f64| p.evaluate(along(t0, &u, s), false, true).map(|o| o.loss);
            let (lp, lm) = (at(e).unwrap(), at(-e).unwrap());
            (e, lp - lm, (lp - lm) / (2.0 * e))
        })
        .collect();
    for (e, d, fd) in rows {
        let rel = (fd - adj).abs() / fd.abs().max(adj.abs());
        println!("{e:>8.0e} {d:>14.6e} {fd:>14.6e} {rel:>10.2e}");
    }
    Ok(())
}
