//! The quick subset of `powderlab validate` (the whole set is `powderlab validate`, minutes):
//! the fixed–free bar's period, the block on an incline below and above its friction angle,
//! the self-weight column at one particle per cell, and the scale invariance of a column
//! collapse.

#![cfg(feature = "lab")]

use powderlab::lab::validate::{bar, column, incline, scale_invariance};

#[test]
fn vibrating_bar_period_within_one_percent() {
    let r = bar::run_bar(&bar::Bar::new(16), Some(2)).unwrap();
    println!("{r:?}");
    for c in bar::bar_checks(&r) {
        println!("{c:?}");
    }
    let rel = (r.period - r.exact_period).abs() / r.exact_period;
    assert!(
        rel <= bar::BAR_PERIOD_REL_TOL,
        "period {} vs {}",
        r.period,
        r.exact_period
    );
    // APIC dissipates; it must never gain energy.
    assert!(r.energy_drift < 0.0, "energy drift {}", r.energy_drift);
}

#[test]
fn block_sticks_below_and_slides_above_its_friction_angle() {
    for ratio in [0.95, 1.05] {
        let r = incline::run_incline(&incline::Incline::new(ratio), Some(2)).unwrap();
        println!("{r:?}");
        let checks = incline::incline_checks(&r);
        assert!(checks.iter().all(|c| c.passed), "{checks:?}");
    }
}

/// At one particle per cell the base stress is exact up to a term of the order of the strain
/// (about 7e-4 of ρgH here, and ten times smaller for a ten times stiffer column).
const SELF_WEIGHT_ONE_PPC_TOL: f64 = 2e-3;

#[test]
fn self_weight_column_base_stress() {
    let r = column::run_column(&column::Column::new(8, 1), Some(2)).unwrap();
    println!("{r:?}");
    assert!(r.error <= SELF_WEIGHT_ONE_PPC_TOL, "{r:?}");
}

#[test]
fn a_column_scaled_twice_leaves_the_same_normalised_deposit() {
    let c = scale_invariance(0.5, 10, Some(2)).unwrap();
    println!("{c:?}");
    assert!(c.passed, "{c:?}");
}
