//! Helpers shared by the integration tests.
#![allow(dead_code)]

use powderlab::scene::Scene;
use powderlab::sim::{SimOptions, Simulation};
use std::path::{Path, PathBuf};

pub fn scene_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenes")
        .join(name)
}

pub fn load(name: &str) -> Scene {
    Scene::load(scene_path(name)).unwrap_or_else(|e| panic!("{e}"))
}

pub fn parse(src: &str) -> Result<Scene, powderlab::error::SceneError> {
    Scene::parse(src, Path::new("test.ron"))
}

pub fn build(scene: &Scene, threads: usize) -> Simulation {
    Simulation::new(
        scene,
        &SimOptions {
            threads: Some(threads),
            ..Default::default()
        },
    )
    .unwrap_or_else(|e| panic!("{e}"))
}

/// Asserts every particle field is finite.
pub fn assert_finite(sim: &mut Simulation) {
    for b in sim.body_states() {
        for (i, (x, v)) in b.x.iter().zip(&b.v).enumerate() {
            assert!(
                x.is_finite() && v.is_finite(),
                "body {} particle {i}: x {x:?} v {v:?}",
                b.name
            );
        }
        assert!(b.f.iter().all(|f| f.is_finite()) && b.c.iter().all(|c| c.is_finite()));
    }
}

/// The path of a scene of `tests/scenes`.
pub fn test_scene_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests")
        .join("scenes")
        .join(name)
}

/// A scene of `tests/scenes`.
pub fn load_test_scene(name: &str) -> Scene {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests")
        .join("scenes")
        .join(name);
    Scene::load(p).unwrap_or_else(|e| panic!("{e}"))
}

/// The official Rerun CLI (PyPI rerun-sdk==0.36.3), analytics off: `rerun` where it is on the
/// PATH, else `python3 -m rerun`, the same CLI through the Python that installed it (pip puts
/// the `rerun` script in a folder that is not always on the PATH, e.g. `~/.local/bin`).
pub fn rerun_cli() -> std::process::Command {
    let on_path = std::process::Command::new("rerun")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    let mut c = if on_path {
        std::process::Command::new("rerun")
    } else {
        let mut c = std::process::Command::new("python3");
        c.args(["-m", "rerun"]);
        c
    };
    c.env("RERUN_ANALYTICS", "0");
    c
}

/// Opens `rrd` with the official Rerun CLI (`rerun rrd stats`, PyPI rerun-sdk==0.36.3) and
/// asserts that it reads and holds every one of `entities`.
pub fn assert_rrd_has(rrd: &Path, entities: &[&str]) {
    let stats = rerun_cli()
        .args(["rrd", "stats"])
        .arg(rrd)
        .output()
        .unwrap_or_else(|e| {
            panic!("the Rerun CLI is needed for this test: pip install rerun-sdk==0.36.3 ({e})")
        });
    let text = String::from_utf8_lossy(&stats.stdout).to_string()
        + &String::from_utf8_lossy(&stats.stderr);
    assert!(
        stats.status.success(),
        "rerun rrd stats failed (the CLI comes from pip install rerun-sdk==0.36.3): {text}"
    );
    for entity in entities {
        assert!(
            text.contains(entity),
            "entity {entity} missing from:\n{text}"
        );
    }
}
