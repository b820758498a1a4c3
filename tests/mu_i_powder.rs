//! The μ(I) material in a scene: end to end, the adjoint's gradient in every differentiable
//! parameter agrees with central differences on a block that flows; the rate term acts (a
//! collapse of coarse grains, whose flow reaches a larger inertial number, runs out less than
//! one of fine grains, which flows as the Drucker–Prager cone of the same static friction); and
//! bad parameters are refused by name.
#![cfg(feature = "lab")]

use powderlab::lab::validate::{run_collapse, Collapse, Rheology};

mod common;

/// A 4 cm cube of glass-bead powder on a rough floor at dx = 5 mm, with grains of `grain_mm`.
fn block_text(mu_s: f64, grain_mm: f64) -> String {
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
        "powder": MuI((density: 1500.0, youngs_modulus: 1e5, mu_s: {mu_s}, mu_2: 0.64,
                       grain_diameter: {}, grain_density: 2450.0)),
    }},
    bodies: [
        (name: "powder", material: "powder",
         fill: Box(min: (0.04, 0.01, 0.04), max: (0.08, 0.05, 0.08))),
    ],
)"#,
        grain_mm * 1e-3
    )
}

#[test]
fn the_gradient_in_every_material_parameter_agrees_with_central_differences() {
    // A cube slumps: its grains flow on the rate-dependent surface, and some stay inside it.
    let scene = common::parse(&block_text(0.38, 2.0)).unwrap();
    // E's step is 1e-5 of it: at 1e-4 and 1e-3 (10 and 100 Pa) grains switch between flow and
    // rest within the step and the differences move by 2e-5 and 8e-4 of the gradient (2.77660e-6
    // and 2.77879e-6 against the adjoint's 2.776658e-6); at 1 Pa they agree with it to 3e-8.
    common::check_material_gradients::<powderlab::materials::mu_i::MuI>(
        &scene,
        "powder",
        8,
        glam::DVec3::new(0.06, 0.0, 0.06),
        &[
            ("youngs_modulus", 1e0),
            ("poisson_ratio", 1e-6),
            ("mu_s", 1e-6),
            ("mu_2", 1e-6),
        ],
    );
}

/// A planar collapse (a = 1, 8 cells across L₀): with grains of 1 µm the inertial number stays
/// near 0 and the powder flows as Klár's cone of the same static friction, so the run-out is
/// the Drucker–Prager one's; with 5 mm grains the flow's friction rises toward μ₂ and the
/// front stops at least a cell short of it.
#[test]
fn coarse_grains_run_out_less_than_fine_ones_which_flow_as_drucker_prager() {
    let runout = |rheology: Rheology| {
        let mut c = Collapse::new(1.0, 8);
        c.rheology = rheology;
        run_collapse(&c, Some(2), |_| {}).unwrap().runout_ratio
    };
    let dp = runout(Rheology::DruckerPrager);
    let phi = Collapse::new(1.0, 8).friction_deg;
    let fine = runout(Rheology::mu_i_matching(phi, 1e-6));
    let coarse = runout(Rheology::mu_i_matching(phi, 5e-3));
    println!("run-out: Drucker–Prager {dp}, μ(I) 1 µm {fine}, 5 mm {coarse}");
    // Within one cell (1/8 of L₀) of the cone's run-out.
    assert!(
        (fine - dp).abs() <= 0.125 + 1e-9,
        "fine {fine} against {dp}"
    );
    // At least one cell shorter (1 against 0.875 when written).
    assert!(
        coarse <= fine - 0.125 + 1e-9,
        "coarse {coarse} against fine {fine}"
    );
}

#[test]
fn bad_parameters_are_refused_by_name() {
    let err = common::parse(&block_text(-0.2, 0.5))
        .unwrap_err()
        .to_string();
    assert!(err.contains("mu_s") && err.contains("-0.2"), "{err}");
    let err = common::parse(&block_text(0.38, 0.0))
        .unwrap_err()
        .to_string();
    assert!(err.contains("grain_diameter"), "{err}");
}
