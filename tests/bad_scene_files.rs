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
fn cup_fillet_wider_than_the_cavity() {
    let msg = error_of(&GOOD.replace(
        "wall_thickness: 0.004",
        "wall_thickness: 0.004, fillet_radius: Some(0.5)",
    ));
    assert!(
        msg.contains("colliders[0].shape.fillet_radius")
            && msg.contains("= 0.5")
            && msg.contains("leave it out")
            && msg.contains("scenes/bad.ron:7:"),
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

/// A field without its own range check (a rotation) must not carry a NaN into the simulation:
/// it used to clear every particle out of the fill (`NaN > margin` is false) and run empty.
#[test]
fn non_finite_rotation() {
    let msg = error_of(&GOOD.replace(
        "position: (0.11, 0.11, 0.11)),",
        "position: (0.11, 0.11, 0.11), rotation_deg: (0.0, NaN, 0.0)),",
    ));
    assert!(
        msg.contains("colliders[0].rotation_deg")
            && msg.contains("NaN")
            && msg.contains("scenes/bad.ron:8:"),
        "{msg}"
    );
}

/// A loss target of NaN used to give a NaN loss and zero gradients without a word.
#[test]
fn non_finite_loss_target() {
    let msg = error_of(&GOOD.replace(
        "steps: Some(1)),",
        "steps: Some(1)),\n    loss: Some(SumDistance((0.1, inf, 0.1))),",
    ));
    assert!(
        msg.contains("loss") && msg.contains("inf") && msg.contains("finite"),
        "{msg}"
    );
}

#[test]
fn negative_target_amount() {
    let msg = error_of(&GOOD.replace(
        "steps: Some(1)),",
        "steps: Some(1)),\n    task: Some((target: \"cup\", target_value: Grams(-5.0))),",
    ));
    assert!(
        msg.contains("task.target_value") && msg.contains("-5") && msg.contains(">= 0 g"),
        "{msg}"
    );
}

/// A slow tool asked for a horizon of 1e10 steps, whose per-step controls alone aborted the
/// process on a failed 190 GB allocation.
#[test]
fn skill_too_slow_for_its_horizon() {
    let src = GOOD.replace(
        "position: (0.11, 0.11, 0.11)),",
        &SKILL_TOOL.replace("linear_speed: 0.2", "linear_speed: 1e-9"),
    );
    let msg = error_of(&src);
    assert!(
        msg.contains("colliders[1].control.linear_speed")
            && msg.contains("1000000 steps")
            && msg.contains("raise linear_speed"),
        "{msg}"
    );
}

#[test]
fn constant_control_too_long() {
    let msg = error_of(&GOOD.replace(
        "position: (0.11, 0.11, 0.11)),",
        "position: (0.11, 0.11, 0.11)),\n        (name: \"rod\", kind: Tool, shape: Sphere(radius: 0.01), position: (0.11, 0.2, 0.11),\n         control: Constant(linear: (0.0, 0.0, 0.0), angular: (0.0, 0.0, 0.0), steps: 10000000000)),",
    ));
    assert!(
        msg.contains("colliders[1].control.steps") && msg.contains("at most 1000000"),
        "{msg}"
    );
}

/// A stiffness beyond any material is out of range, with its value in scientific notation.
#[test]
fn absurd_stiffness_is_out_of_range() {
    let msg = error_of(&GOOD.replace("youngs_modulus: 2e4", "youngs_modulus: 1e300"));
    assert!(
        msg.contains("field `materials.sand.youngs_modulus` = 1e300"),
        "{msg}"
    );
}

/// A stiffness that needs more substeps than Auto ever takes names the material that sets the
/// limit; the advice used to be "raise simulation.substeps to at least 18446744073709551615"
/// (a saturated cast).
#[test]
fn a_step_too_stiff_for_auto_names_the_stiffest_material() {
    let msg = error_of(
        &GOOD
            .replace("youngs_modulus: 2e4", "youngs_modulus: 1e13")
            .replace("steps: Some(1)", "steps: Some(1), dt: 10.0"),
    );
    assert!(
        msg.contains("field `materials.sand`")
            && msg.contains("unstable time step")
            && msg.contains("youngs_modulus")
            && msg.contains("substeps per step")
            && !msg.contains("18446744073709551615"),
        "{msg}"
    );
}

/// A grid far beyond any machine's memory is refused before it is allocated (the allocation
/// used to abort the process). Where the available memory is unknown the check is skipped, and
/// so is this test.
#[test]
fn grid_beyond_the_memory() {
    if powderlab::util::available_memory_bytes().is_none() {
        return;
    }
    let msg = error_of(&GOOD.replace("cells: (24, 24, 24)", "cells: (4096, 4096, 4096)"));
    assert!(
        msg.contains("simulation.cells")
            && msg.contains("fits in memory")
            && msg.contains("GB are available")
            && msg.contains("scenes/bad.ron:2:"),
        "{msg}"
    );
}

#[test]
fn non_positive_point_radius() {
    let msg = error_of(&GOOD.replace(
        "steps: Some(1)),",
        "steps: Some(1)),\n    record: Some((every: 1, point_radius: Some(0.0))),",
    ));
    assert!(
        msg.contains("record.point_radius") && msg.contains("> 0 m"),
        "{msg}"
    );
}

/// `threads: 100000` is a typo: `--threads 100000` had started 15,589 OS threads after 14
/// minutes without finishing a step (see `MAX_THREADS`).
#[test]
fn too_many_threads() {
    let msg = error_of(&GOOD.replace("steps: Some(1)", "steps: Some(1), threads: 100000"));
    assert!(
        msg.contains("simulation.threads") && msg.contains("<= 1024"),
        "{msg}"
    );
}

/// The same bound for a caller in code, whose thread count does not come from the scene file.
#[test]
fn too_many_threads_from_code() {
    let s = Scene::parse(GOOD, Path::new("scenes/good.ron")).unwrap();
    let opts = |threads| SimOptions::threads(Some(threads));
    let msg = Simulation::new(&s, &opts(100_000))
        .map(|_| ())
        .expect_err("refused")
        .to_string();
    assert!(
        msg.contains("SimOptions::threads") && msg.contains("100000") && msg.contains("<= 1024"),
        "{msg}"
    );
    Simulation::new(&s, &opts(4)).unwrap();
}

/// ron says "Integer is out of bounds" without the field; the message adds its path.
#[test]
fn negative_integer_names_its_field() {
    let msg = error_of(&GOOD.replace("steps: Some(1)", "steps: Some(1), substeps: -3"));
    assert!(
        msg.contains("scenes/bad.ron:2:") && msg.contains("field `simulation.substeps`"),
        "{msg}"
    );
    // Inside a tuple, the field that holds the tuple.
    let msg = error_of(&GOOD.replace("cells: (24, 24, 24)", "cells: (24, -24, 24)"));
    assert!(
        msg.starts_with("scenes/bad.ron:2:") && msg.contains("field `simulation.cells`"),
        "{msg}"
    );
}

/// A container written in millimetres (110 for 0.11 m) sits far outside the grid and used to
/// run silently with no container at all.
#[test]
fn collider_outside_the_domain() {
    let msg = error_of(&GOOD.replace(
        "position: (0.11, 0.11, 0.11)",
        "position: (110.0, 110.0, 110.0)",
    ));
    assert!(
        msg.contains("colliders[0].position")
            && msg.contains("reaches the simulation domain")
            && msg.contains("metres"),
        "{msg}"
    );
}

#[test]
fn a_value_spanning_lines_is_echoed_on_one_line() {
    // Found by the AFL++ target (`fuzz/`): a string may hold a newline, and the refusal that
    // echoed it took two lines.
    let msg = error_of(&GOOD.replace(r#"material: "sand""#, "material: \"sa\n// a comment\nnd\""));
    assert!(msg.contains(r"sa\n// a comment\nnd"), "{msg}");
    assert!(msg.contains("field `bodies[0].material`"), "{msg}");
}
