//! The stability guard derives the substeps from the fastest tool point, which depends on the
//! skill parameters Θ. In `powder_transport` every Θ of the box must keep the scene's substeps:
//! a Θ that raised them would change the dynamics discontinuously between two rollouts of the
//! optimisation (a jump in the loss that no gradient sees).

#![cfg(feature = "lab")]

use powderlab::lab::optim::problem::Problem;
use powderlab::skills::Theta;
use powderlab::util::SplitMix64;

mod common;

/// Random skills checked besides the corners of the box.
const SAMPLES: usize = 64;

#[test]
fn every_skill_keeps_the_scene_substeps() {
    let scene = common::load("powder_transport.ron");
    let problem = Problem::new(scene.clone(), 1 << 30).unwrap();
    let mut rng = SplitMix64(5);
    let corners = (0..32).map(|m: u32| {
        Theta(std::array::from_fn(|k| {
            if m >> k & 1 == 1 {
                1.0
            } else {
                -1.0
            }
        }))
    });
    let random = (0..SAMPLES).map(|_| Theta(std::array::from_fn(|_| rng.uniform_in(-1.0, 1.0))));
    for theta in corners.chain(random) {
        let sim = problem.simulation(theta, true).unwrap();
        assert_eq!(
            sim.params().substeps,
            scene.simulation.substeps,
            "Θ = {theta:?}: the guard raised the substeps ({:?})",
            sim.stability
        );
    }
}
