//! The gravimetric pour (`powderlab::lab::policy::pour`): what it adds to the cup is what its load
//! cell read, a dose of nothing pours nothing, and settings it cannot run are refused.
#![cfg(feature = "lab")]

use powderlab::lab::optim::problem::Problem;
use powderlab::lab::policy::dataset::{problem_of, spec_of};
use powderlab::lab::policy::knob;
use powderlab::lab::policy::pour::{rollout, Gravimetric};
use powderlab::scene::Scene;

mod common;

/// One grain of `policy_dosing.ron`'s powder at its default density: 1500 kg/m³ × (5 mm)³ / 8
/// particles per cell, in grams.
const GRAIN_G: f64 = 1500.0 * 0.005 * 0.005 * 0.005 / 8.0 * 1e3;

/// What the pour adds to the cup is what the load cell read within two grains: a grain that
/// leaves over the lip's far side may miss the cup, and the load cell's reach is a cell wider
/// than the bowl, so a grain stuck on the spoon's outside counts as held.
const POUR_GRAINS: f64 = 2.0;

/// Without a pour, the cup gets only the grains the heap sheds during the carry: a few, far
/// below the load (a twentieth of it), where any tilt that poured would move most of it.
const SHED_FRACTION: f64 = 0.05;

/// `policy_dosing.ron` as written (its base draw), and the family's Θ at scoop depth `s`.
fn problem_at(s: f64) -> (Problem, powderlab::skills::Theta) {
    let base = Scene::load(common::scene_path("policy_dosing.ron")).unwrap();
    let d = spec_of(&base).unwrap().base(&base);
    let (problem, _) = problem_of(&base, &d).unwrap();
    let theta = knob::family(&problem, &d, s);
    (problem, theta)
}

#[test]
fn the_pour_adds_what_the_load_cell_read_and_a_zero_dose_pours_nothing() {
    let (problem, theta) = problem_at(1.0);
    let g = Gravimetric::default();
    // A dose no spoon holds: the spoon tilts to its limit and turns back.
    let (full, tf) = rollout(&problem, theta, 100.0, &g).unwrap();
    // A dose of nothing: it turns back before it tilts.
    let (zero, tz) = rollout(&problem, theta, 0.0, &g).unwrap();
    assert!(
        tf.stopped_at.is_none(),
        "turned back at {:?}",
        tf.stopped_at
    );
    assert_eq!(tz.stopped_at, Some(0), "the spoon should turn back at once");
    assert_eq!(tf.held_g, tz.held_g, "the same scoop and carry");
    assert!(tf.held_g > 1.0, "the deepest scoop held {} g", tf.held_g);
    let added = full.transported - zero.transported;
    assert!(
        (added - tf.held_g).abs() <= POUR_GRAINS * GRAIN_G,
        "held {} g, the pour added {} g",
        tf.held_g,
        added
    );
    assert!(
        zero.transported < SHED_FRACTION * tf.held_g,
        "{} g reached the cup without a pour",
        zero.transported
    );
    // The tilt rose to the limit and came back upright.
    let top = tf.steps.iter().map(|s| s.0).fold(0.0, f64::max);
    assert!(top <= g.max_deg + 1e-9 && top > 90.0, "{top}");
    assert!(tf.steps.last().unwrap().0.abs() < 1e-9, "ended tilted");
    assert!(tz.steps.iter().all(|s| s.0 == 0.0), "a zero dose tilted");
}

#[test]
fn settings_the_loop_cannot_run_are_refused() {
    let (problem, theta) = problem_at(0.0);
    for g in [
        Gravimetric {
            speed_deg: 0.0,
            ..Default::default()
        },
        Gravimetric {
            lead_steps: -1.0,
            ..Default::default()
        },
        Gravimetric {
            max_deg: 200.0,
            ..Default::default()
        },
        Gravimetric {
            turn_back_deg: Some(0.0),
            ..Default::default()
        },
        Gravimetric {
            tap_mm: Some(-0.5),
            ..Default::default()
        },
    ] {
        let e = rollout(&problem, theta, 1.0, &g).unwrap_err().to_string();
        assert!(
            e.starts_with("gravimetric pour:") && e.contains("must be"),
            "{e}"
        );
    }
}
