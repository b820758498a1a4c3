//! The pile-angle case of `powderlab validate` (shared/validation/granular.md): a low column of
//! the plane-strain collapse slab comes to rest, and the angle of its flank rises with the
//! friction angle. granular.md's 3° band around the plane-strain angle is not met (`docs/results/validation.md`,
//! "Pile angle"), so it is reported by `validate pile_angle`, not asserted here; what is asserted
//! are the laws a correct simulation cannot break.

#![cfg(feature = "lab")]

use powderlab::lab::validate::pile::{
    flank_of, pile_collapse, plane_strain_angle_deg, Pile, MIN_FLANK_POINTS, PILE_FRICTION_DEG,
};
use powderlab::lab::validate::run_collapse;
use serde_json::Value;
use std::process::Command;

/// Cells across L₀: the a = 0.4 column is 8 cells high, 2–3 s a pile on 2 threads. The flank
/// angles at 20 cells are within 4.4° of those at 40 (`docs/results/validation.md`).
const CELLS: usize = 20;

/// How far a particle may move in z, in cells: the slab fills the gap between the walls'
/// innermost node layers, so it stays in plane strain. Measured: under 0.002 cells; the first
/// slab, with a free node layer beside it, moved 0.3 cells.
const PLANE_STRAIN_Z_TOL_CELLS: f64 = 0.05;

/// A cohesionless slope at rest cannot be steeper than the material's static limit, the
/// plane-strain friction angle, by more than granular.md's 3° measuring band.
const STATIC_LIMIT_TOL_DEG: f64 = 3.0;

#[test]
fn flank_angle_rises_with_friction_and_the_slab_stays_in_plane_strain() {
    let mut angles = Vec::new();
    for phi in PILE_FRICTION_DEG {
        let c = pile_collapse(&Pile {
            friction_deg: phi,
            cells_across: CELLS,
        });
        let r = run_collapse(&c, Some(2), |_| {}).unwrap();
        let f = flank_of(&c, &r.deposit).expect("a flank");
        println!(
            "φ = {phi}°: flank {:.2}° (plane strain {:.1}°), {} points, {:.1} s",
            f.angle_deg,
            plane_strain_angle_deg(phi),
            f.points,
            r.wall_s
        );
        assert!(f.points >= MIN_FLANK_POINTS);
        assert!(
            f.angle_deg <= plane_strain_angle_deg(phi) + STATIC_LIMIT_TOL_DEG,
            "φ = {phi}°: {f:?}"
        );
        // The slab lies between z = 2.25 and 5.75 cells (particle centres, 2 per cell).
        let (lo, hi) = r.deposit.iter().fold((f64::MAX, f64::MIN), |a, p| {
            let z = p.z * CELLS as f64;
            (a.0.min(z), a.1.max(z))
        });
        assert!(
            lo >= 2.25 - PLANE_STRAIN_Z_TOL_CELLS && hi <= 5.75 + PLANE_STRAIN_Z_TOL_CELLS,
            "φ = {phi}°: z spans {lo} .. {hi} cells"
        );
        angles.push(f.angle_deg);
    }
    assert!(angles.windows(2).all(|w| w[1] > w[0]), "{angles:?}");
}

#[test]
fn validate_pile_angle_reports_every_friction_angle_and_refuses_a_coarse_grid() {
    let o = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .args([
            "validate",
            "pile_angle",
            "--cells",
            "10",
            "--threads",
            "2",
            "--json",
        ])
        .output()
        .unwrap();
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    let checks = v["checks"].as_array().unwrap();
    assert_eq!(checks.len(), PILE_FRICTION_DEG.len() + 1, "{v}");
    assert!(checks.iter().all(|c| c["case"] == "pile_angle"));
    // It exits non-zero exactly when a check fails.
    assert_eq!(o.status.success(), v["passed"] == true);

    let o = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .args(["validate", "pile_angle", "--cells", "5"])
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("--cells 5") && err.contains("at least 10"),
        "{err}"
    );
}
