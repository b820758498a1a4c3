//! Extreme cases end in a stable run or a clear error, never a NaN: a tool at the CFL speed,
//! friction angles 0° and 60°, powder packed against the domain wall, a near-singular and an
//! inverted deformation gradient.

use glam::{DMat3, DVec3};
use powderlab::components::DeformationGradient;

mod common;

fn sand_scene(friction_deg: f64, fill: &str, tool: &str, stability: &str) -> String {
    format!(
        r#"Scene(
        simulation: (cells: (24, 24, 24), dx: 0.01, dt: 0.01, substeps: 10, steps: Some(5), stability: {stability}),
        materials: {{ "sand": DruckerPrager((youngs_modulus: 2e4, friction_deg: {friction_deg})) }},
        bodies: [(name: "sand", material: "sand", fill: {fill})],
        colliders: [{tool}],
    )"#
    )
}

const BLOCK: &str = "Box(min: (0.06, 0.03, 0.06), max: (0.16, 0.10, 0.16))";

fn run_finite(src: &str, steps: usize) -> powderlab::sim::Simulation {
    let mut sim = common::build(&common::parse(src).unwrap_or_else(|e| panic!("{e}")), 2);
    sim.run(steps, |_| {}).unwrap_or_else(|e| panic!("{e}"));
    common::assert_finite(&mut sim);
    sim
}

#[test]
fn friction_angle_zero_and_sixty() {
    for phi in [0.0, 60.0] {
        let sim = run_finite(&sand_scene(phi, BLOCK, "", "Auto"), 5);
        assert!(!sim.stability.raised());
    }
}

#[test]
fn tool_at_and_beyond_the_cfl_speed() {
    // The wave speed of E = 2e4 is 4.2 m/s; dt_sub = 1e-3, dx = 1 cm, C = 0.5: the CFL speed
    // is 5 m/s in total, so a tool at 2 m/s and one at 20 m/s are pushing the guard.
    for speed in [2.0, 20.0] {
        let tool = format!(
            "(name: \"paddle\", kind: Tool, shape: Box(half_extents: (0.01, 0.03, 0.05)), position: (0.04, 0.07, 0.11),
              control: Constant(linear: ({speed}, 0.0, 0.0), steps: 1))"
        );
        let sim = run_finite(&sand_scene(30.0, BLOCK, &tool, "Auto"), 1);
        let s = &sim.stability;
        println!("tool {speed} m/s: {s:?}");
        assert!(s.max_speed >= speed);
        assert!(sim.params().dt_sub <= s.dt_max);
        let err = powderlab::sim::Simulation::new(
            &common::parse(&sand_scene(30.0, BLOCK, &tool, "Strict")).unwrap(),
            &Default::default(),
        );
        if speed > 5.0 {
            let msg = err
                .err()
                .expect("strict refuses a tool beyond the CFL speed")
                .to_string();
            assert!(msg.contains("largest speed 20.000 m/s"), "{msg}");
        }
    }
}

#[test]
fn powder_packed_against_the_domain_wall() {
    // The box fills the grid's safe region up to one cell from the boundary, deep inside the
    // 3-cell wall layers on every side.
    let fill = "Box(min: (0.01, 0.01, 0.01), max: (0.22, 0.12, 0.22))";
    let mut sim = run_finite(&sand_scene(30.0, fill, "", "Auto"), 5);
    let st = sim.body_states();
    assert!(st[0]
        .x
        .iter()
        .all(|x| x.cmpge(DVec3::splat(0.01)).all() && x.cmple(DVec3::splat(0.22)).all()));
}

#[test]
fn near_singular_and_inverted_deformation_gradient() {
    for f in [
        DMat3::from_diagonal(DVec3::new(1.0, 1.0, 1e-9)),
        DMat3::from_diagonal(DVec3::new(1.0, -0.5, 1.0)),
        DMat3::ZERO,
    ] {
        let mut sim = common::build(
            &common::parse(&sand_scene(30.0, BLOCK, "", "Auto")).unwrap(),
            2,
        );
        let mut q = sim.world.query::<&mut DeformationGradient>();
        for mut fg in q.iter_mut(&mut sim.world) {
            for (i, x) in fg.0.iter_mut().enumerate() {
                if i % 3 == 0 {
                    *x = f;
                }
            }
        }
        sim.run(3, |_| {})
            .unwrap_or_else(|e| panic!("F = {f:?}: {e}"));
        common::assert_finite(&mut sim);
    }
}

#[test]
fn a_single_particle_and_an_empty_body() {
    let one = "Box(min: (0.10, 0.10, 0.10), max: (0.105, 0.105, 0.105))";
    let mut sim = run_finite(&sand_scene(30.0, one, "", "Auto"), 3);
    assert_eq!(sim.particle_count(), 1);
    // An empty region: the lattice has no point inside a box thinner than one spacing.
    let empty = "Box(min: (0.10, 0.10, 0.10), max: (0.101, 0.101, 0.101))";
    let mut sim = run_finite(&sand_scene(30.0, empty, "", "Auto"), 3);
    assert_eq!(sim.particle_count(), 0);
}
