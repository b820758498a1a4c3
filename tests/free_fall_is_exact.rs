//! Free fall: with no contact, MLS-MPM reproduces the symplectic-Euler trajectory exactly,
//! because the B-spline weights are a partition of unity with zero first moment.

#![cfg(feature = "lab")]

use powderlab::lab::validate::{free_fall, FREE_FALL_REL_TOL};

#[test]
fn free_fall_matches_the_closed_form_to_round_off() {
    let checks = free_fall(Some(2)).unwrap();
    assert_eq!(checks.len(), 2);
    for c in checks {
        assert!(
            c.measured <= FREE_FALL_REL_TOL,
            "{}: {:e} > {:e}",
            c.quantity,
            c.measured,
            FREE_FALL_REL_TOL
        );
        assert!(c.passed);
    }
}
