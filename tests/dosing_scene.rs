//! `scenes/powder_transport_dosing.ron` is the default transport scene with the dosing loss and
//! nothing else changed, and its loss doses the task's target value.

mod common;

use common::load;
use powderlab::adjoint::loss::Loss;
use powderlab::scene::{LossSpec, TargetValue};

#[test]
fn the_dosing_scene_is_the_default_scene_with_the_dosing_loss() {
    let base = load("powder_transport.ron");
    let mut dosing = load("powder_transport_dosing.ron");
    let Some(LossSpec::Dosing { grams, width: None }) = dosing.loss else {
        panic!(
            "expected Dosing(grams: .., width: None), got {:?}",
            dosing.loss
        );
    };
    let task = dosing.task.as_ref().expect("a task");
    assert_eq!(task.target_value, TargetValue::Grams(grams));
    match powderlab::adjoint::loss::scene_loss(&dosing) {
        Loss::Dosing(d) => assert_eq!(d.target_mass, grams * 1e-3),
        _ => panic!("expected the dosing loss"),
    }
    assert_eq!(base.loss, None);
    // Everything but the loss (and the file it came from) is the default scene's.
    dosing.loss = None;
    dosing.path = base.path.clone();
    dosing.source = base.source.clone();
    assert_eq!(dosing, base);
}

#[test]
fn the_precise_dosing_scene_asks_for_two_grams_with_the_dosing_loss_and_nothing_else() {
    let base = load("powder_transport.ron");
    let mut precise = load("precise_dosing.ron");
    assert_eq!(
        precise.loss,
        Some(LossSpec::Dosing {
            grams: 2.0,
            width: None
        })
    );
    let task = precise.task.as_mut().expect("a task");
    assert_eq!(task.target_value, TargetValue::Grams(2.0));
    task.target_value = TargetValue::Grams(5.0);
    precise.loss = None;
    precise.path = base.path.clone();
    precise.source = base.source.clone();
    assert_eq!(precise, base);
}
