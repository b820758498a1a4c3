//! The study's plan, analysis (errors, Pareto front) and Θ parsing.

use super::*;
use crate::skills::Theta;

#[test]
fn pareto_front_keeps_the_undominated_points() {
    let pts = [
        (1.0, 0.5),
        (2.0, 0.6),
        (3.0, 0.1),
        (0.5, 0.9),
        (4.0, 0.1),
        (5.0, 0.01),
    ];
    assert_eq!(
        pareto_front(&pts),
        vec![true, false, true, true, false, true]
    );
}

#[test]
fn theta_takes_exactly_five_numbers() {
    assert_eq!(
        parse_theta("0.3, 0.2,0,-1,1").unwrap(),
        Theta([0.3, 0.2, 0.0, -1.0, 1.0])
    );
    assert!(parse_theta("0.3,0.2,0,-1")
        .unwrap_err()
        .to_string()
        .contains("has 4 values"));
    assert!(parse_theta("0.3,x,0,-1,1").is_err());
}

fn collapse_result(sweep: Sweep, cells: usize, cfl: f64, runout: f64, wall_s: f64) -> ConfigResult {
    let cfg = Config {
        case: Case::ColumnCollapse,
        sweep,
        dx: COLLAPSE_LENGTH / cells as f64,
        particles_per_cell: 8,
        cfl: Some(cfl),
        substeps: None,
        gradient: false,
        steps: None,
        scene: None,
        threads: None,
    };
    ConfigResult {
        config: cfg,
        particles: 100,
        substeps_per_step: 1,
        steps: 1,
        wall_s,
        peak_rss_bytes: 1,
        values: [("runout_ratio".to_string(), runout)].into(),
        gradient: None,
        failed: None,
    }
}

#[test]
fn analysis_measures_errors_against_the_finest_grid_the_sweep_and_the_law() {
    let results = vec![
        collapse_result(Sweep::Resolution, 5, 0.5, 2.0, 1.0),
        collapse_result(Sweep::Resolution, 10, 0.5, 1.6, 4.0),
        collapse_result(Sweep::Resolution, 20, 0.5, 1.5, 16.0),
        collapse_result(Sweep::Substeps, 10, 0.25, 1.8, 8.0),
        collapse_result(Sweep::Substeps, 10, 0.125, 1.65, 12.0),
        failed(
            &collapse_result(Sweep::Resolution, 40, 0.5, 0.0, 0.0).config,
            "out of memory".into(),
        ),
    ];
    let rows = analyse(&results);
    // The failed configuration is left out; the reference is the finest that succeeded.
    assert_eq!(rows.len(), 5);
    let by = |cells: usize, cfl: f64| {
        rows.iter()
            .find(|r| {
                (r.dx_m - COLLAPSE_LENGTH / cells as f64).abs() < 1e-15
                    && (r.sweep == Sweep::Resolution) == (cfl == 0.5)
                    && (cfl == 0.5 || r.label.contains(&format!("CFL {cfl}")))
            })
            .unwrap()
    };
    let r5 = by(5, 0.5);
    assert!((r5.error_vs_reference.unwrap() - 0.5 / 1.5).abs() < 1e-12);
    assert!((r5.error_vs_law.unwrap() - 0.8 / 1.2).abs() < 1e-12);
    assert!(by(20, 0.5).is_reference);
    assert_eq!(by(20, 0.5).error_vs_reference, Some(0.0));
    // Within the substep sweep the finest is CFL 0.125.
    let s = by(10, 0.25);
    assert!((s.error_vs_sweep_finest.unwrap() - 0.15 / 1.65).abs() < 1e-12);
    assert!((s.error_vs_reference.unwrap() - 0.3 / 1.5).abs() < 1e-12);
    // Fronts: against the reference 5 cells (fastest), then 10 cells (0.067 at 4 s) …
    // CFL 0.25 (0.2 at 8 s) and CFL 0.125 (0.1 at 12 s) are beaten by 10 cells.
    let front: Vec<bool> = [(5, 0.5), (10, 0.5), (10, 0.25), (10, 0.125)]
        .iter()
        .map(|&(c, f)| by(c, f).pareto)
        .collect();
    assert_eq!(front, vec![true, true, false, false]);
    assert!(
        !by(20, 0.5).pareto,
        "the reference is not a point against itself"
    );
    // … and against the law the reference may be on the front (it is the closest here).
    assert!(by(20, 0.5).pareto_vs_law);
}

#[test]
fn gradient_error_is_relative_to_the_reference() {
    let a = [1.0, 0.0, 0.0, 0.0, 0.0];
    let b = [2.0, 0.0, 0.0, 0.0, 0.0];
    assert_eq!(gradient_error(&a, &b), 0.5);
}

#[test]
fn the_full_plan_sweeps_four_resolutions_or_more_per_case() {
    let p = plan(false, Path::new("scenes/powder_transport.ron"), None).unwrap();
    for case in [Case::ColumnCollapse, Case::PowderTransport] {
        let n = p
            .iter()
            .filter(|c| c.case == case && c.sweep == Sweep::Resolution)
            .count();
        assert!(n >= 4, "{case:?}: {n} resolutions");
    }
    // Substeps scale with 1/dx: the CFL number of the shipped scene at every level.
    let sub: Vec<usize> = p
        .iter()
        .filter(|c| c.case == Case::PowderTransport && c.sweep == Sweep::Resolution)
        .map(|c| c.substeps.unwrap())
        .collect();
    assert_eq!(sub, vec![8, 10, 12, 16, 24]);
}
