//! Bad scene files give one-line errors naming the file, the position and the field.

use powderlab::scene::Scene;
use powderlab::sim::{SimOptions, Simulation};
use std::path::Path;

mod common;

const GOOD: &str = r#"Scene(
    simulation: (cells: (24, 24, 24), dx: 0.01, steps: Some(1)),
    materials: { "sand": DruckerPrager((youngs_modulus: 2e4, friction_deg: 30.0)) },
    bodies: [(name: "sand", material: "sand", fill: Box(min: (0.06, 0.03, 0.06), max: (0.16, 0.10, 0.16)))],
    colliders: [
        (name: "cup", kind: Container,
         shape: Cup(outer_radius: 0.05, height: 0.1, wall_thickness: 0.004, floor_thickness: 0.004),
         position: (0.11, 0.11, 0.11)),
    ],
)"#;

fn error_of(src: &str) -> String {
    let r = Scene::parse(src, Path::new("scenes/bad.ron"))
        .and_then(|s| Simulation::new(&s, &SimOptions::default()).map(|_| ()));
    let msg = r.expect_err("the scene must be refused").to_string();
    println!("{msg}");
    assert!(!msg.contains('\n'), "one line: {msg}");
    assert!(msg.starts_with("scenes/bad.ron:"), "names the file: {msg}");
    msg
}

#[test]
fn the_template_is_good() {
    let s = Scene::parse(GOOD, Path::new("good.ron")).unwrap();
    Simulation::new(&s, &SimOptions::default()).unwrap();
}

#[test]
fn malformed_ron() {
    let msg = error_of(&GOOD.replace("dx: 0.01,", "dx: 0.01"));
    assert!(msg.starts_with("scenes/bad.ron:2:"), "{msg}");
}

#[test]
fn unknown_field() {
    let msg = error_of(&GOOD.replace("dx: 0.01,", "dx: 0.01, dxx: 3,"));
    assert!(msg.starts_with("scenes/bad.ron:2:"), "{msg}");
    assert!(msg.contains("dxx"), "{msg}");
}

#[test]
fn missing_file() {
    let msg = Scene::load("scenes/does_not_exist.ron")
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains("scenes/does_not_exist.ron") && msg.contains("cannot read"),
        "{msg}"
    );
}

#[test]
fn negative_dx() {
    let msg = error_of(&GOOD.replace("dx: 0.01", "dx: -0.01"));
    assert!(
        msg.contains("scenes/bad.ron:2:") && msg.contains("simulation.dx") && msg.contains("-0.01"),
        "{msg}"
    );
}

#[test]
fn friction_angle_out_of_range() {
    let msg = error_of(&GOOD.replace("friction_deg: 30.0", "friction_deg: 80.0"));
    assert!(
        msg.contains("scenes/bad.ron:3:")
            && msg.contains("materials.sand.friction_deg")
            && msg.contains("[0, 80)"),
        "{msg}"
    );
}

#[test]
fn unknown_material_name() {
    let msg = error_of(&GOOD.replace("material: \"sand\"", "material: \"snad\""));
    assert!(
        msg.contains("scenes/bad.ron:4:")
            && msg.contains("bodies[0].material")
            && msg.contains("snad"),
        "{msg}"
    );
}

#[test]
fn particles_outside_the_domain() {
    let msg = error_of(&GOOD.replace("max: (0.16, 0.10, 0.16)", "max: (0.16, 0.10, 0.30)"));
    assert!(
        msg.contains("scenes/bad.ron:4:") && msg.contains("bodies[0].fill"),
        "{msg}"
    );
}

#[test]
fn tool_starting_inside_a_container_wall() {
    let src = GOOD.replace(
        "position: (0.11, 0.11, 0.11)),",
        "position: (0.11, 0.11, 0.11)),
        (name: \"stick\", kind: Tool, shape: Sphere(radius: 0.005), position: (0.158, 0.15, 0.11),
         control: Constant(linear: (0.0, 0.0, 0.0), steps: 1)),",
    );
    let msg = error_of(&src);
    assert!(
        msg.contains("colliders[1].position") && msg.contains("container 'cup'"),
        "{msg}"
    );
    assert!(msg.contains("scenes/bad.ron:9:"), "{msg}");
}

#[test]
fn container_with_a_control() {
    let msg = error_of(&GOOD.replace(
        "position: (0.11, 0.11, 0.11)),",
        "position: (0.11, 0.11, 0.11), control: Constant(linear: (1.0, 0.0, 0.0), steps: 1)),",
    ));
    assert!(msg.contains("colliders[0].control"), "{msg}");
}

#[test]
fn cup_wall_thicker_than_the_cup() {
    let msg = error_of(&GOOD.replace("wall_thickness: 0.004", "wall_thickness: 0.06"));
    assert!(
        msg.contains("colliders[0].shape.wall_thickness") && msg.contains("scenes/bad.ron:7:"),
        "{msg}"
    );
}

#[test]
fn unstable_time_step_under_strict() {
    let msg = error_of(&GOOD.replace(
        "steps: Some(1)",
        "steps: Some(1), stability: Strict, substeps: 1",
    ));
    assert!(
        msg.contains("unstable time step") && msg.contains("at least"),
        "{msg}"
    );
}

#[test]
fn non_finite_number() {
    // RON accepts `NaN`; the validator must not.
    let msg = error_of(&GOOD.replace("dx: 0.01", "dx: NaN"));
    assert!(
        msg.contains("simulation.dx") && msg.contains("NaN"),
        "{msg}"
    );
}

/// A template tool with a skill control; `ranges` is replaced by the tests.
const SKILL_TOOL: &str = r#"position: (0.11, 0.11, 0.11)),
        (name: "spoon", kind: Tool,
         shape: Spoon(bowl_radius: 0.015, bowl_depth: 0.009, thickness: 0.0015, handle_length: 0.04, handle_radius: 0.0025),
         position: (0.11, 0.19, 0.11),
         control: Skill((
             theta: (0.0, 0.0, 0.0, 0.0, 0.0),
             ranges: (scoop_depth: (0.008, 0.02), scoop_angle_deg: (10.0, 50.0), lift_height: (0.04, 0.08),
                      transport_distance: (0.02, 0.04), pour_angle_deg: (60.0, 150.0)),
             linear_speed: 0.2, angular_speed_deg: 180.0, scoop_stroke: 0.008, surface_height: 0.1,
         ))),"#;

#[test]
fn the_skill_template_is_good() {
    let s = Scene::parse(
        &GOOD.replace("position: (0.11, 0.11, 0.11)),", SKILL_TOOL),
        Path::new("good.ron"),
    )
    .unwrap();
    Simulation::new(&s, &SimOptions::default()).unwrap();
}

#[test]
fn malformed_skill_range() {
    let src = GOOD.replace(
        "position: (0.11, 0.11, 0.11)),",
        &SKILL_TOOL.replace("lift_height: (0.04, 0.08)", "lift_height: (0.08, 0.04)"),
    );
    let msg = error_of(&src);
    assert!(
        msg.contains("colliders[1].control.ranges.lift_height")
            && msg.contains("(0.08, 0.04)")
            && msg.contains("min <= max")
            && msg.contains("scenes/bad.ron:14:"),
        "{msg}"
    );
}

#[test]
fn skill_parameter_outside_the_box() {
    let src = GOOD.replace(
        "position: (0.11, 0.11, 0.11)),",
        &SKILL_TOOL.replace(
            "theta: (0.0, 0.0, 0.0, 0.0, 0.0)",
            "theta: (0.0, 1.5, 0.0, 0.0, 0.0)",
        ),
    );
    let msg = error_of(&src);
    assert!(
        msg.contains("colliders[1].control.theta[1]") && msg.contains("[-1, 1]"),
        "{msg}"
    );
}

#[test]
fn dosing_loss_without_a_task() {
    let msg = error_of(&GOOD.replace(
        "steps: Some(1)),",
        "steps: Some(1)),\n    loss: Some(Dosing(grams: 5.0)),",
    ));
    assert!(
        msg.contains("loss") && msg.contains("task") && msg.contains("scenes/bad.ron:3:"),
        "{msg}"
    );
}
