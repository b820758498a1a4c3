//! Trajectory refinement's gradient: `∂L/∂w` of the residual on the spoon's transport and pour
//! (`optim::refine`) from the backward pass agrees with a central difference along a random
//! direction of `w`, over a whole skill rollout of the spoon-scoop test scene.

#![cfg(feature = "lab")]

use powderlab::lab::optim::problem::Problem;
use powderlab::skills::Theta;
use powderlab::util::SplitMix64;

mod common;

/// Central-difference step along a unit direction of w. The directional derivative is small
/// (about 1.4e-5 against a loss of 5.7: few grains ride in the spoon), so the rollout's
/// round-off rules small steps: with the transfers contracted one axis at a time, the measured
/// relative gaps to the adjoint are 1.3e-2 at 1e-6, 2.3e-3 at 1e-5, 1.3e-4 at 1e-4 and
/// 4.5e-6 at 3e-4 (truncation is still below round-off at 1e-3: 3.3e-4).
const EPS: f64 = 1e-4;

#[test]
fn residual_gradient_matches_a_central_difference() {
    // The spoon-scoop scene asked to deliver into its own cup: a task for the problem, and a
    // whole skill of a few hundred particles.
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/scenes/spoon_scoop.ron"
    ))
    .unwrap();
    let text = text.trim_end().trim_end_matches(')').to_string()
        + "    task: Some((target: \"cup\", target_value: Grams(1.0))),\n)";
    let scene = common::parse(&text).unwrap();
    let p = Problem::new(scene, 1 << 30).unwrap();
    // The deepest scoop at the steepest angle and the lowest lift: the spoon carries grains
    // through the transport, so the residual moves them.
    let theta = Theta([1.0, -1.0, -1.0, 0.0, 0.0]);
    let r = p.residual(theta, 3);
    assert_eq!(r.dim(), 18);
    assert!(r.len > 5, "a transport and a pour: {r:?}");
    let mut rng = SplitMix64(11);
    let w: Vec<f64> = (0..r.dim()).map(|_| rng.uniform_in(-0.3, 0.3)).collect();
    let dir: Vec<f64> = {
        let d: Vec<f64> = (0..r.dim()).map(|_| rng.normal()).collect();
        let n = d.iter().map(|x| x * x).sum::<f64>().sqrt();
        d.into_iter().map(|x| x / n).collect()
    };
    let (o, g) = p.evaluate_residual(theta, &r, &w, true, false).unwrap();
    let g = g.unwrap();
    let at = |s: f64| {
        let ws: Vec<f64> = w.iter().zip(&dir).map(|(a, b)| a + s * b).collect();
        p.evaluate_residual(theta, &r, &ws, false, false)
            .unwrap()
            .0
            .loss
    };
    // The forward of the gradient rollout is the plain forward.
    assert_eq!(at(0.0), o.loss);
    let ad: f64 = g.iter().zip(&dir).map(|(a, b)| a * b).sum();
    assert!(ad.abs() > 0.0, "no gradient reaches the residual");
    common::check_fd(at, EPS, ad, "dL/dw·u");
}
