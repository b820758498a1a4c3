//! `powderlab::rollout` (what the Python bindings and their Ray workers call) gives the
//! optimiser's bits: the same loss, indicator and ∂L/∂Θ as `Problem::evaluate`, which reuses a
//! built world, at one thread and at two.

use powderlab::rollout::{self, Request};
use powderlab::scene::Scene;
use powderlab::skills::Theta;

#[cfg(feature = "lab")]
#[test]
fn rollout_gives_the_optimisers_loss_indicator_and_gradient() {
    use powderlab::lab::optim::problem::Problem;
    let scene = Scene::load("tests/scenes/tiny_transport.ron").unwrap();
    let theta = Theta([0.1, -0.4, 0.5, -0.2, 0.6]);
    let problem = Problem::new(scene.clone(), 1 << 30).unwrap();
    let expected = problem.evaluate(theta, true, false).unwrap();
    for threads in [1, 2] {
        let r = rollout::run(
            &scene,
            &Request {
                theta: Some(theta),
                grad: true,
                threads: Some(threads),
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(r.loss, Some(expected.loss), "{threads} threads");
        assert_eq!(r.indicator, Some(expected.indicator));
        assert_eq!(r.transported, Some(expected.transported));
        assert_eq!(r.steps, expected.steps);
        let (tool, g) = r.skill.expect("a skill tool");
        assert_eq!(tool, "spoon");
        assert_eq!(Some(g), expected.grad, "{threads} threads");
    }
}

#[test]
fn controls_replace_the_tool_and_errors_name_the_field() {
    let scene = Scene::load("tests/scenes/tiny_transport.ron").unwrap();
    let r = rollout::run(
        &scene,
        &Request {
            controls: Some((None, vec![[0.0, -0.001, 0.0, 0.0, 0.0, 0.0]; 6])),
            grad: true,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(r.steps, 6);
    assert!(r.skill.is_none(), "the tool no longer follows a skill");
    let g = r.gradients.unwrap();
    assert_eq!(g.tool_controls("spoon").unwrap().len(), 6);

    let e = rollout::run(
        &scene,
        &Request {
            controls: Some((Some("ladle".into()), vec![[0.0; 6]])),
            ..Default::default()
        },
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("no tool named 'ladle'") && e.contains("spoon"),
        "{e}"
    );
    let e = rollout::run(
        &scene,
        &Request {
            theta: Some(Theta([1.5, 0.0, 0.0, 0.0, 0.0])),
            ..Default::default()
        },
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("theta"), "{e}");
}
