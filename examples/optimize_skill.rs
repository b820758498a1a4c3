//! Skill optimisation driven from code: the paper's RMSprop on the transport task's five skill
//! parameters Θ, one rollout (forward and backward) per epoch.
//!
//! ```sh
//! cargo run --release --example optimize_skill -- [EPOCHS=5]
//! ```
//!
//! `powderlab optimize` does the same with seeds, the baselines, resuming and the plots.

use powderlab::lab::optim::problem::Problem;
use powderlab::lab::optim::rmsprop::{RmsProp, RmsState};
use powderlab::scene::Scene;

fn main() -> anyhow::Result<()> {
    let epochs: usize = std::env::args().nth(1).map_or(Ok(5), |s| s.parse())?;
    let scene = Scene::load("scenes/powder_transport.ron")?;
    // The problem owns Θ: it maps Θ to the spoon's controls, builds the scene once, and maps the
    // backward pass's control gradients back to ∂L/∂Θ.
    let problem = Problem::new(scene, 1 << 30)?;
    let rmsprop = RmsProp::default();
    let mut state = RmsState {
        theta: problem.scene_theta(),
        mean_square: [0.0; 5],
    };
    let mut best = (f64::INFINITY, state.theta, f64::NAN);
    for epoch in 1..=epochs {
        // One rollout at Θ with the gradient; `false`: the simulation gets its own threads.
        let out = problem.evaluate(state.theta, true, false)?;
        let grad = out.grad.expect("asked for the gradient");
        println!(
            "epoch {epoch}: loss {:.3}, indicator {:+.3} g (target minus delivered), Θ {:.3?}, |∂L/∂Θ| {:.3}",
            out.loss,
            out.indicator,
            state.theta,
            grad.iter().map(|g| g * g).sum::<f64>().sqrt()
        );
        if out.loss < best.0 {
            best = (out.loss, state.theta, out.indicator);
        }
        // The curriculum moves only θ_d, θ_s and θ_l until `switch_epoch`.
        rmsprop.step(&mut state, grad, epoch);
    }
    println!(
        "best: loss {:.3} at Θ {:.3?} (indicator {:+.3} g)",
        best.0, best.1, best.2
    );
    Ok(())
}
