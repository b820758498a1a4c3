//! Planar granular column collapse: the run-out follows the two published regimes of Lube et
//! al. 2005 (`ΔL/L₀ ≈ 1.2a` below a ≈ 2.3, `≈ 1.9a^(2/3)` above), at a coarse resolution that
//! keeps the test fast. `powderlab validate column_collapse` runs the full sweep at 20 cells.

use powderlab::validate::{lube_runout, run_collapse, Collapse};

/// Every run-out within this factor of the law (as in shared/validation/granular.md).
const FACTOR: f64 = 2.0;
/// Cells across the column: coarse, for speed (the validate sweep uses 20).
const CELLS: usize = 8;

fn runout(a: f64) -> f64 {
    let r = run_collapse(&Collapse::new(a, CELLS), Some(2), |_| {}).unwrap();
    println!(
        "a = {a}: ΔL/L0 = {:.3} (law {:.3}), arrest {:?} T_c, {} particles, {:.1} s",
        r.runout_ratio,
        lube_runout(a),
        r.arrest_tc,
        r.particles,
        r.wall_s
    );
    r.runout_ratio
}

#[test]
fn small_and_large_aspect_ratios_follow_the_published_regimes() {
    let small = [(0.5, runout(0.5)), (1.0, runout(1.0))];
    let large = [(4.0, runout(4.0)), (6.0, runout(6.0))];
    for &(a, r) in small.iter().chain(&large) {
        let law = lube_runout(a);
        assert!(
            r > law / FACTOR && r < law * FACTOR,
            "a = {a}: {r} not within ×{FACTOR} of {law}"
        );
    }
    let slope = |p: &[(f64, f64); 2]| (p[1].1 / p[0].1).ln() / (p[1].0 / p[0].0).ln();
    let (s_small, s_large) = (slope(&small), slope(&large));
    println!("slopes: small a {s_small:.3}, large a {s_large:.3}");
    // The regime change: run-out grows about linearly for small a and clearly slower for large a.
    assert!((s_small - 1.0).abs() < 0.3, "small-a slope {s_small}");
    assert!(
        (s_large - 2.0 / 3.0).abs() < 0.25,
        "large-a slope {s_large}"
    );
    assert!(s_large < s_small);
}
