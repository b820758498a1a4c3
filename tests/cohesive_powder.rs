//! The cohesive Drucker–Prager material in a scene: a block of powder whose height is below
//! Rankine's critical height `H_c = 4c·tan(45° + φ/2)/(ρg)` stands, the same block without
//! cohesion slumps, and the scene machinery (`--set`, the calibration's names) knows `cohesion`.
//! End to end, the adjoint's gradient in every parameter of the material agrees with central
//! differences on a block that partly fails (plasticity and the apex both active).
#![cfg(feature = "lab")]

use powderlab::scene::Scene;
use powderlab::sim::{SimOptions, Simulation};

mod common;

/// A 4 cm cube of powder on a rough floor, at dx = 5 mm.
fn block(cohesion: f64) -> Scene {
    common::parse(&block_text(cohesion)).unwrap()
}

fn block_text(cohesion: f64) -> String {
    format!(
        r#"Scene(
    simulation: (
        domain_min: (0.0, 0.0, 0.0),
        cells: (24, 12, 24),
        dx: 0.005,
        dt: 0.01,
        substeps: 20,
        stability: Auto,
        walls: (cells: 2, contact: Sticky, friction: 0.5),
    ),
    materials: {{
        "powder": CohesiveDruckerPrager((density: 1500.0, youngs_modulus: 1e5, friction_deg: 30.0, cohesion: {cohesion})),
    }},
    bodies: [
        (name: "powder", material: "powder",
         fill: Box(min: (0.04, 0.01, 0.04), max: (0.08, 0.05, 0.08))),
    ],
)"#
    )
}

/// The block's top (the highest particle) after `steps`, over its height at the start.
fn standing(scene: &Scene, steps: usize) -> f64 {
    let mut sim = Simulation::new(scene, &SimOptions::default()).unwrap();
    let top = |sim: &mut Simulation| {
        sim.body_states()[0]
            .x
            .iter()
            .map(|p| p.y)
            .fold(f64::MIN, f64::max)
    };
    let h0 = top(&mut sim) - 0.01;
    sim.run(steps, |_| {}).unwrap();
    (top(&mut sim) - 0.01) / h0
}

#[test]
fn a_block_below_the_rankine_height_stands_and_without_cohesion_it_slumps() {
    // H_c = 4c·tan 60°/(ρg): 400 Pa holds 19 cm, far above the 4 cm block; 0 Pa holds nothing.
    let h_c = |c: f64| 4.0 * c * 60f64.to_radians().tan() / (1500.0 * 9.81);
    assert!(h_c(400.0) > 4.0 * 0.04);
    let with = standing(&block(400.0), 60);
    let without = standing(&block(0.0), 60);
    println!("after 0.6 s: {with:.3} of its height with c = 400 Pa, {without:.3} without");
    assert!(with > 0.95, "the cohesive block fell to {with}");
    assert!(without < 0.85, "the cohesionless block stood at {without}");
}

#[test]
fn cohesion_is_a_named_parameter_of_the_scene() {
    let scene = block(100.0);
    let p = powderlab::lab::calibrate::params::parse(&scene, &["cohesion".to_string()], &[])
        .unwrap()
        .remove(0);
    assert_eq!(p.value(&scene), 100.0);
    let mut s = scene.clone();
    p.apply(&mut s, 250.0);
    assert_eq!(p.value(&s), 250.0);
    // A negative cohesion is refused by name.
    let err = common::parse(&block_text(-5.0)).unwrap_err().to_string();
    assert!(err.contains("cohesion") && err.contains("-5"), "{err}");
}

#[test]
fn the_gradient_in_every_material_parameter_agrees_with_central_differences() {
    // 60 Pa holds 2.8 cm (Rankine), so the 4 cm block's upper part fails: the return mapping
    // runs on the cone and at the apex, not only inside it.
    // E's step is 1e-4 of it: at 1e-6 (0.1 Pa) the differences scatter by a few parts per
    // million between steps (9.76521e-6 at 0.1 Pa, 9.76531e-6 at 0.01 Pa, 9.76624e-6 at
    // 0.005 Pa: grains switching between the cone and the apex within the step), more than
    // their own error estimate says; at 10 and 5 Pa they agree with each other and bracket the
    // adjoint's 9.76528e-6.
    common::check_material_gradients::<
        powderlab::materials::cohesive_drucker_prager::CohesiveDruckerPrager,
    >(
        &block(60.0),
        "powder",
        8,
        glam::DVec3::new(0.06, 0.0, 0.06),
        &[
            ("youngs_modulus", 1e1),
            ("poisson_ratio", 1e-6),
            ("friction_deg", 1e-6),
            ("cohesion", 1e-3),
        ],
    );
}

/// Rankine's vertical cut (`validate rankine`'s case) on a coarse slab: a column of height H
/// slides off its foot at half the cohesion Rankine's plane-strain height asks for at H, and
/// stands at twice it. A material that ignored cohesion would fail both.
#[test]
fn a_cut_fails_below_rankines_cohesion_and_stands_above_it() {
    use powderlab::lab::validate::rankine::{column, rankine_cohesion, stands};
    use powderlab::lab::validate::run_collapse;
    let (phi, cells) = (20.0, 10);
    let h = column(phi, 0.0, cells).length;
    let c = rankine_cohesion(h, phi);
    let moved = |k: f64| {
        let col = column(phi, k * c, cells);
        run_collapse(&col, Some(2), |_| {}).unwrap().runout_ratio * cells as f64
    };
    let (weak, strong) = (moved(0.5), moved(2.0));
    assert!(
        !stands(weak, cells),
        "at half Rankine's cohesion the foot moved {weak} cells"
    );
    assert!(
        stands(strong, cells),
        "at twice it the foot moved {strong} cells"
    );
}
