//! A thin layer launched along a rough floor stops where Coulomb friction says,
//! `s = v₀²/(2μg)`, at two resolutions: the floor's grid friction acting on a sliding layer.
//!
//! The layer is 5 mm thick: one cell at dx = 5 mm, two at 2.5 mm, so at the coarse resolution
//! all of it lies within the floor nodes' stencil and at the fine one half of it does not.
//! Two materials: a stiff elastic layer (a rigid block, for which the law is exact) and
//! Drucker–Prager sand (φ = 30°, whose internal friction tan 30° = 0.58 exceeds the floor's 0.5,
//! so the layer slides on the floor rather than shearing inside).

#![cfg(feature = "lab")]

mod common;

/// Launch speed (m/s), floor friction, gravity.
const V0: f64 = 0.5;
const MU: f64 = 0.5;
const G: f64 = 9.81;
/// Layer thickness (m).
const THICKNESS: f64 = 0.005;
/// Tolerance on the elastic layer's slide against Coulomb's law: the layer lands with its weight
/// switched on at t = 0, so the normal force rings for the first substeps (0.12 % was measured).
const ELASTIC_REL_TOL: f64 = 0.01;
/// Tolerance on the sand layer's slide: it is not rigid, and its front particles spread a
/// little as it stops (4–5 % was measured, always further than the law).
const SAND_REL_TOL: f64 = 0.1;
/// The two resolutions must agree more closely than the sand agrees with the law (1 % was
/// measured).
const RESOLUTION_REL_TOL: f64 = 0.03;

fn scene(dx: f64, material: &str) -> String {
    let wall = 3;
    let floor = wall as f64 * dx;
    let nx = (0.16 / dx).round() as usize + 2 * wall;
    let ny = (0.02 / dx).round() as usize + 2 * wall;
    let nz = (0.03 / dx).round() as usize + 2 * wall;
    let z0 = floor + 0.005;
    format!(
        r#"Scene(
    simulation: (cells: ({nx}, {ny}, {nz}), dx: {dx}, dt: 0.002, substeps: 1, stability: Auto,
                 walls: (cells: {wall}, contact: Separate, friction: 0.0)),
    materials: {{ "layer": {material} }},
    bodies: [(name: "layer", material: "layer", velocity: ({V0}, 0.0, 0.0),
              fill: Box(min: ({x0}, {floor}, {z0}), max: ({x1}, {top}, {z1})))],
    colliders: [(name: "floor", kind: Container, shape: Plane(normal: (0.0, 1.0, 0.0)),
                 position: (0.0, {floor}, 0.0), friction: {MU}, particle_contact: false)],
)"#,
        x0 = floor + 0.01,
        x1 = floor + 0.05,
        top = floor + THICKNESS,
        z1 = z0 + 0.02,
    )
}

/// The layer's centre-of-mass slide (m) after 0.2 s (twice the law's stopping time).
fn slide(dx: f64, material: &str) -> f64 {
    let scene = common::parse(&scene(dx, material)).unwrap_or_else(|e| panic!("{e}"));
    let mut sim = common::build(&scene, 2);
    let x0 = powderlab::lab::validate::mean_x(&mut sim);
    for _ in 0..100 {
        sim.step().unwrap_or_else(|e| panic!("{e}"));
    }
    common::assert_finite(&mut sim);
    powderlab::lab::validate::mean_x(&mut sim) - x0
}

#[test]
fn thin_layer_stops_where_coulomb_says_at_two_resolutions() {
    let law = V0 * V0 / (2.0 * MU * G);
    let cases = [
        (
            "elastic",
            "Elastic((density: 1500.0, youngs_modulus: 1e6, poisson_ratio: 0.3))",
            ELASTIC_REL_TOL,
        ),
        (
            "sand",
            "DruckerPrager((density: 1500.0, youngs_modulus: 1e6, poisson_ratio: 0.3, \
             friction_deg: 30.0))",
            SAND_REL_TOL,
        ),
    ];
    for (name, material, tol) in cases {
        let coarse = slide(0.005, material);
        let fine = slide(0.0025, material);
        println!("{name}: slide {coarse:.5} m (dx 5 mm), {fine:.5} m (dx 2.5 mm), law {law:.5} m");
        for (s, dx) in [(coarse, "5 mm"), (fine, "2.5 mm")] {
            assert!(
                (s - law).abs() <= tol * law,
                "{name}, dx {dx}: slide {s} m against Coulomb's {law} m"
            );
        }
        assert!(
            (coarse - fine).abs() <= RESOLUTION_REL_TOL * law,
            "{name}: slides {coarse} and {fine} m differ by more than {RESOLUTION_REL_TOL} of {law} m"
        );
    }
}
