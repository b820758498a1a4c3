//! The push loss's gradient with respect to a stroke's five parameters Φ, through the spatula's
//! start pose and controls and the whole simulation, against central differences of the
//! simulated push loss (issue: pushing and pulling at seed B's level).

mod common;

use powderlab::lab::plan::push::{Push, PushNode};
use powderlab::lab::plan::stroke::Stroke;
use std::time::Instant;

/// The push loss after stroke Φ from `n`, simulated forward.
fn push_loss(push: &Push, n: &PushNode, phi: [f64; 5]) -> f64 {
    let mut sim = push.stroke_simulation(n, &Stroke::from_phi(&phi)).unwrap();
    let steps = sim.horizon;
    sim.run(steps, |_| {}).unwrap();
    let xs: Vec<_> = sim.body_states().into_iter().map(|b| b.x).collect();
    push.push_loss().eval(&xs).0
}

/// A stroke off the scripted one in every parameter, with a length of exactly 80 steps at the
/// plan's speed (0.08 m at 1 mm a step), so a length step does not change the step count.
const PHI: [f64; 5] = [-0.3, 0.2, 0.15, -0.6, 0.2];

/// The central differences' step in Φ. The push loss is rough on the scale of a stroke
/// optimiser's steps: for `behind`, differences at 1e-2, 1e-3 and 1e-4 in Φ gave 3.9e-4,
/// −3.6e-4 and 7.7e-4 (the blade's contact with single grains switching), and they settle on
/// the adjoint's −1.5588e-3 from 1e-5 down (−1.546e-3 at 1e-5, −1.509e-3 at 1e-6, −1.5588e-3
/// at 1e-7); `lateral`'s still differed from the adjoint by 4e-5 of itself at 1e-6 and by 1e-5
/// at 1e-7. The check is of the derivative, so it takes the step the project's other gradient
/// checks take, inside the smooth piece.
const FD_STEP: f64 = 1e-7;

#[test]
fn the_stroke_gradient_matches_central_differences() {
    let scene = common::load("plate_push.ron");
    let mut push = Push::new(scene, 1, None).unwrap();
    let n = push.start().unwrap();
    let t0 = Instant::now();
    let base = push_loss(&push, &n, PHI);
    let forward_s = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let g = push.rollout_grad(&n, PHI).unwrap();
    let gradient_s = t1.elapsed().as_secs_f64();
    println!(
        "push loss {base:.6e} m; forward {forward_s:.3} s, with the backward pass {gradient_s:.3} \
         s ({:.2}× a forward's cost for the backward pass)",
        gradient_s / forward_s - 1.0
    );
    assert!(
        (g.push_loss - base).abs() <= 1e-12 * base,
        "{} against {base}",
        g.push_loss
    );
    assert!(g.grad.iter().any(|v| *v != 0.0), "{:?}", g.grad);
    let names = ["behind", "lateral", "yaw", "height", "length"];
    for k in 0..5 {
        common::check_fd(
            |h| {
                let mut phi = PHI;
                phi[k] += h;
                push_loss(&push, &n, phi)
            },
            FD_STEP,
            g.grad[k],
            &format!("∂L/∂Φ {}", names[k]),
        );
    }
}
