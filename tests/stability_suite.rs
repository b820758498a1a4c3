//! The stability suite (`powderlab validate stability`): every stiff or extreme case ends stable
//! or refused with a message, never in a NaN, a panic or a spurious energy gain; a stiff scene
//! under `Strict` is refused exactly when `Auto` had to raise its substeps.

#![cfg(feature = "lab")]

use powderlab::lab::validate::stability::{cases, run_case, Outcome};

#[test]
fn every_case_is_stable_or_refused() {
    let results: Vec<_> = cases().iter().map(|c| run_case(c, Some(2))).collect();
    for r in &results {
        println!("{:<70} {:?}", r.name, r.outcome);
        assert!(r.outcome.acceptable(), "{}: {:?}", r.name, r.outcome);
    }
    let find = |name: &str| {
        &results
            .iter()
            .find(|r| r.name == name)
            .unwrap_or_else(|| panic!("no case {name}"))
            .outcome
    };
    for e in ["1e4", "1e5", "1e6", "1e7"] {
        let auto = find(&format!("E = {e} Pa, Auto"));
        let strict = find(&format!("E = {e} Pa, Strict"));
        let Outcome::Stable {
            substeps,
            requested,
            ..
        } = auto
        else {
            panic!("E = {e}, Auto: {auto:?}");
        };
        match strict {
            Outcome::Refused { message } => {
                assert!(
                    substeps > requested,
                    "E = {e}: refused but Auto kept {substeps}"
                );
                assert!(
                    message.contains(&format!("at least {substeps}")),
                    "the refusal names the substeps Auto used: {message}"
                );
            }
            Outcome::Stable { .. } => assert_eq!(substeps, requested, "E = {e}"),
            other => panic!("E = {e}, Strict: {other:?}"),
        }
    }
    assert!(matches!(find("a single particle"), Outcome::Stable { .. }));
}
