//! The fuzzer's reproducers, made by hand from shipped scenes: each physical quantity has an
//! admissible range (what the model can run, not merely what is finite), a scene too large for
//! the memory it may take is refused before the allocation and names the field that drives it,
//! and every refusal is one bounded line with the file, the position and the field.

mod common;

use powderlab::scene::Scene;
use std::path::Path;

/// The shipped scene `name` with `from` replaced by `to` (which must occur).
fn edited(name: &str, from: &str, to: &str) -> String {
    let src = std::fs::read_to_string(common::scene_path(name)).unwrap();
    assert!(src.contains(from), "{name} has no `{from}`");
    src.replacen(from, to, 1)
}

/// The one-line refusal of `src`, parsed and prepared with `limit` bytes of memory at most.
fn refusal_within(src: &[u8], limit: u64) -> String {
    let msg = Scene::parse_bytes(src, Path::new("scenes/edited.ron"))
        .and_then(|s| s.prepare_within(Some(limit)).map(|_| ()))
        .expect_err("the scene must be refused")
        .to_string();
    assert!(!msg.contains('\n'), "one line: {msg}");
    assert!(msg.starts_with("scenes/edited.ron:"), "the file: {msg}");
    msg
}

fn refusal(src: &str) -> String {
    refusal_within(src.as_bytes(), 8 << 30)
}

fn names(msg: &str, field: &str) {
    assert!(msg.contains(&format!("field `{field}`")), "{field}: {msg}");
}

#[test]
fn a_million_particles_per_cell_is_refused_before_any_allocation() {
    let msg = refusal(&edited(
        "free_fall.ron",
        "velocity: (0.1, 0.5, -0.05)",
        "velocity: (0.1, 0.5, -0.05), particles_per_cell: 1000000",
    ));
    names(&msg, "bodies[0].particles_per_cell");
}

#[test]
fn a_fill_over_the_memory_limit_names_its_particles_per_cell_not_the_grid() {
    // 729 per cell over the block: 2.8e5 lattice points, 6.7 MB, against a 4 MB limit.
    let msg = refusal_within(
        edited(
            "free_fall.ron",
            "velocity: (0.1, 0.5, -0.05)",
            "velocity: (0.1, 0.5, -0.05), particles_per_cell: 729",
        )
        .as_bytes(),
        4 << 20,
    );
    names(&msg, "bodies[0].particles_per_cell");
    assert!(msg.contains("fits in memory"), "{msg}");
}

#[test]
fn an_oversized_container_fill_is_refused_naming_the_body() {
    // A 3 m cup filled at 2.5 mm spacing: billions of lattice points.
    let msg = refusal_within(
        edited(
            "powder_transport_fine.ron",
            "shape: Cup(outer_radius: 0.03,",
            "shape: Cup(outer_radius: 3.0,",
        )
        .as_bytes(),
        1 << 30,
    );
    assert!(msg.contains("field `bodies[0]"), "{msg}");
}

#[test]
fn a_cell_size_outside_a_micron_to_ten_metres_is_refused() {
    for dx in ["1e-300", "1e308"] {
        let msg = refusal(&edited("free_fall.ron", "dx: 0.01", &format!("dx: {dx}")));
        names(&msg, "simulation.dx");
        assert!(!msg.contains("inf"), "{msg}");
    }
}

#[test]
fn gravity_beyond_a_thousand_g_is_refused() {
    let msg = refusal(&edited(
        "sand_box.ron",
        "gravity: (0.0, -9.8, 0.0)",
        "gravity: (0.0, -1e308, 0.0)",
    ));
    names(&msg, "simulation.gravity");
}

#[test]
fn an_explicit_substep_count_above_the_auto_cap_is_refused() {
    let msg = refusal(&edited(
        "free_fall.ron",
        "substeps: 10",
        "substeps: 4294967296",
    ));
    names(&msg, "simulation.substeps");
}

#[test]
fn an_unstable_step_names_its_field_and_position() {
    // free_fall.ron is Strict: one substep per step is far above the stable one.
    let msg = refusal(&edited("free_fall.ron", "substeps: 10", "substeps: 1"));
    names(&msg, "simulation.substeps");
    assert!(
        msg.starts_with("scenes/edited.ron:6:59:"),
        "at `substeps`: {msg}"
    );
}

#[test]
fn a_malformed_number_in_a_tuple_names_the_tuple_s_field() {
    let msg = refusal(&edited(
        "free_fall.ron",
        "cells: (24, 40, 24)",
        "cells: (24, 1e-320, 24)",
    ));
    names(&msg, "simulation.cells");
}

#[test]
fn invalid_utf8_gives_its_byte_offset_and_field() {
    let mut src = edited("free_fall.ron", "dx: 0.01", "dx: 0.01\u{1}").into_bytes();
    let at = src.iter().position(|&b| b == 1).unwrap();
    src[at] = 0xFF;
    let msg = refusal_within(&src, 8 << 30);
    assert!(msg.contains(&format!("byte {at} (0xFF)")), "{msg}");
    names(&msg, "simulation.dx");
    assert!(!msg.contains("check the path"), "{msg}");
}

#[test]
fn a_ten_megabyte_field_name_is_cut_in_the_message() {
    let long = "a".repeat(10 << 20);
    let msg = refusal(&edited(
        "free_fall.ron",
        "dx: 0.01",
        &format!("dx: 0.01, {long}: 1"),
    ));
    assert!(msg.len() < 1000, "{} bytes", msg.len());
    assert!(msg.contains(&format!("({} characters)", 10 << 20)), "{msg}");
}

#[test]
fn a_shape_dimension_beyond_a_hundred_metres_names_itself() {
    let msg = refusal(&edited(
        "powder_transport.ron",
        "bowl_radius: 0.015",
        "bowl_radius: 1e308",
    ));
    names(&msg, "colliders[2].shape.bowl_radius");
}

#[test]
fn a_domain_corner_beyond_a_kilometre_names_the_domain() {
    let msg = refusal(&edited(
        "sand_box.ron",
        "domain_min: (0.0, 0.0, 0.0)",
        "domain_min: (-1e40, 0.0, 0.0)",
    ));
    names(&msg, "simulation.domain_min");
}

#[test]
fn rotations_friction_and_wall_layers_have_ranges() {
    for (name, from, to, field) in [
        (
            "powder_transport.ron",
            "rotation_deg: (0.0, -90.0, 0.0)",
            "rotation_deg: (0.0, -90.0, 1e300)",
            "colliders[2].rotation_deg",
        ),
        (
            "sand_box.ron",
            "friction: 0.0, contact: Separate",
            "friction: 1e9, contact: Separate",
            "colliders[0].friction",
        ),
        (
            "sand_box.ron",
            "walls: (cells: 3,",
            "walls: (cells: 0,",
            "simulation.walls.cells",
        ),
    ] {
        names(&refusal(&edited(name, from, to)), field);
    }
}
