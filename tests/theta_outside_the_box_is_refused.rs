//! A skill's ranges map Θ ∈ [−1, 1]⁵ to physical values; a rollout at a Θ outside the box is
//! refused, naming the component, instead of extrapolating the ranges silently.

#![cfg(feature = "lab")]

use powderlab::lab::optim::problem::Problem;
use powderlab::scene::Scene;
use powderlab::skills::Theta;

#[test]
fn a_rollout_outside_the_box_is_refused_and_its_edge_runs() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/scenes/tiny_transport.ron"
    );
    let problem = Problem::new(Scene::load(path).unwrap(), 1 << 30).unwrap();
    let e = problem
        .simulation(Theta([0.0, 0.0, 1.2, 0.0, 0.0]), true)
        .err()
        .expect("refused")
        .to_string();
    assert!(e.contains("theta[2]") && e.contains("1.2"), "{e}");
    assert!(problem
        .simulation(Theta([0.0, 0.0, f64::NAN, 0.0, 0.0]), true)
        .is_err());
    assert!(problem
        .simulation(Theta([1.0, -1.0, 1.0, -1.0, 1.0]), true)
        .is_ok());
}
