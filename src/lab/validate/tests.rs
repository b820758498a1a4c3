//! The collapse's front, arrest time and slopes on hand-made data.

use super::*;

#[test]
fn deposit_front_skips_lone_particles_ahead_of_the_deposit() {
    // Bins of 1: 5 particles in [0,1), 4 in [2,3), one lone particle in [7,8).
    let mut xs = vec![0.5; 5];
    xs.extend([2.1, 2.2, 2.3, 2.9, 7.5]);
    assert_eq!(deposit_front(&xs, 1.0, 4), 3.0);
    assert_eq!(deposit_front(&xs, 1.0, 5), 1.0);
    // In whole cells, the same fronts, and 0 where no bin has enough particles.
    assert_eq!(deposit_front_cells(&xs, 1.0, 4), 3);
    assert_eq!(deposit_front_cells(&xs, 1.0, 6), 0);
}

#[test]
fn front_arrest_is_the_last_time_the_front_left_its_final_cell() {
    // Advances, reaches within one cell of 10 at t = 3, overshoots back out at t = 4
    // (|12 − 10| > 1), then stays within a cell from t = 5 on.
    let trace = [
        (1.0, 2),
        (2.0, 6),
        (3.0, 9),
        (4.0, 12),
        (5.0, 11),
        (6.0, 9),
        (7.0, 10),
    ];
    assert_eq!(front_arrest(&trace, 1), Some(5.0));
    // A front that never moved arrested at the first sample; an empty trace has no time.
    assert_eq!(front_arrest(&[(0.5, 3), (1.0, 3)], 1), Some(0.5));
    assert_eq!(front_arrest(&[], 1), None);
}

#[test]
fn equal_height_columns_share_one_height_in_cells() {
    // At the validation's 20 cells: 60, 30 and 20 across L0, every column 30 cells high.
    let cells: Vec<usize> = SMALL_A
        .iter()
        .map(|&a| equal_height_cells(a, 1.5, 20))
        .collect();
    assert_eq!(cells, [60, 30, 20]);
    for (&a, &n) in SMALL_A.iter().zip(&cells) {
        assert_eq!(a * n as f64, 30.0);
    }
    // An odd count rounds (7.5 → 8), and the tallest column keeps the count given.
    assert_eq!(equal_height_cells(1.0, 1.5, 5), 8);
    assert_eq!(equal_height_cells(1.5, 1.5, 5), 5);
}

fn result(aspect: f64, front_arrest_tc: Option<f64>, arrest_tc: Option<f64>) -> CollapseResult {
    CollapseResult::for_checks(aspect, 20, lube_runout(aspect), front_arrest_tc, arrest_tc)
}

#[test]
fn a_run_cut_off_while_ringing_still_gets_its_front_arrest_row() {
    let rs = [
        result(0.5, Some(3.3), None),
        result(1.0, Some(2.9), Some(4.5)),
        result(1.5, Some(5.0), Some(5.5)),
    ];
    let checks = collapse_checks("small-a", &rs, 1.0, 0.15, "a note");
    let arrest: Vec<&Check> = checks
        .iter()
        .filter(|c| c.quantity.starts_with("front arrest"))
        .collect();
    assert_eq!(arrest.len(), 3);
    assert!(arrest[0].passed && arrest[0].note.contains("cut off at 6 T_c"));
    assert!(arrest[1].passed && arrest[1].note.contains("at 4.50 T_c"));
    assert!(!arrest[2].passed);
    // The law's own run-outs fit a slope of exactly 1, and the note is kept.
    let slope = checks
        .iter()
        .find(|c| c.quantity == "small-a log-log slope")
        .unwrap();
    assert!(slope.passed && (slope.measured - 1.0).abs() < 1e-12);
    assert!(slope.note.ends_with("; a note"));
}
