//! `powderlab gradcheck --json` prints one JSON object with a row per parameter and
//! `max_rel_error`, and passes on a shipped scene.

#![cfg(feature = "lab")]

use std::process::Command;

#[test]
fn gradcheck_json_on_free_fall() {
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/free_fall.ron");
    let o = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .args(["gradcheck", scene, "--steps", "3", "--json"])
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{out}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    let rows = v["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 9, "v0 ×3, x0 ×3, E, ν, gravity");
    for r in rows {
        for key in [
            "parameter",
            "adjoint",
            "finite_difference",
            "rel_error",
            "eps",
        ] {
            assert!(r.get(key).is_some(), "row lacks {key}: {r}");
        }
    }
    assert!(v["max_rel_error"].as_f64().unwrap() <= 1e-3);
    assert_eq!(v["passed"], true);
}

#[test]
fn gradcheck_refuses_a_scene_it_cannot_differentiate() {
    // Klár hardening has no adjoint yet: the answer is an error, never a wrong gradient.
    let dir = std::env::temp_dir().join(format!("powderlab-gc-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let scene = dir.join("hardening.ron");
    std::fs::write(
        &scene,
        r#"Scene(
    simulation: (cells: (16, 16, 16), dx: 0.01, steps: Some(2)),
    materials: { "sand": DruckerPrager((youngs_modulus: 2e4, hardening: Some((35.0, 9.0, 0.2, 10.0)))) },
    bodies: [(name: "sand", material: "sand", fill: Box(min: (0.05, 0.05, 0.05), max: (0.08, 0.08, 0.08)))],
)"#,
    )
    .unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .args(["gradcheck"])
        .arg(&scene)
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("cannot be differentiated yet") && err.contains("hardening"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).ok();
}
