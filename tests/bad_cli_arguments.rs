//! Bad command-line arguments are refused before any work starts, in one clear message that
//! names the option, and leave no output file behind.

#![cfg(feature = "lab")]

use std::path::{Path, PathBuf};
use std::process::Command;

const SCENE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/free_fall.ron");

/// Runs `powderlab ARGS`, expects it to fail, and returns its standard error.
fn refused(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .args(args)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    println!("{err}");
    assert!(!out.status.success(), "must fail: {args:?}");
    assert!(!err.contains("panicked"), "no panic: {err}");
    err
}

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("powderlab-cli-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Runs `powderlab ARGS FLAG DIR/missing/FILE`, expects the refusal to name `flag` and the
/// missing folder, and that folder still not to exist; returns the error.
fn into_missing_folder(args: &[&str], flag: &str, file: &str) -> String {
    let d = scratch(flag.trim_start_matches('-'));
    let out = d.join("missing").join(file);
    let err = refused(&[args, &[flag, s(&out)]].concat());
    assert!(
        err.contains(flag) && err.contains("does not exist"),
        "{err}"
    );
    assert!(!d.join("missing").exists());
    std::fs::remove_dir_all(&d).ok();
    err
}

#[test]
fn recording_into_a_missing_folder() {
    let err = into_missing_folder(&["simulate", SCENE, "--steps", "1"], "--out", "run.rrd");
    assert!(err.contains("mkdir -p"), "{err}");
    // One statement of the cause, not the Rerun sink's three nested copies of it.
    assert_eq!(err.matches("does not exist").count(), 1, "{err}");
}

#[test]
fn state_into_a_missing_folder_or_onto_a_folder() {
    into_missing_folder(
        &["simulate", SCENE, "--steps", "1"],
        "--save-state",
        "state.ply",
    );
    let d = scratch("ply");
    let err = refused(&["simulate", SCENE, "--steps", "1", "--save-state", s(&d)]);
    assert!(
        err.contains("--save-state") && err.contains("is a folder"),
        "{err}"
    );
    assert_eq!(std::fs::read_dir(&d).unwrap().count(), 0, "nothing written");
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn report_into_a_missing_folder() {
    into_missing_folder(&["validate", "free_fall"], "--report", "report.json");
}

#[test]
fn absurd_thread_count() {
    let err = refused(&["bench", SCENE, "--steps", "1", "--threads", "100000"]);
    assert!(
        err.contains("--threads") && err.contains("0 (all cores) to 1024"),
        "{err}"
    );
    let err = refused(&["simulate", SCENE, "--threads=-2"]);
    assert!(err.contains("--threads"), "{err}");
}

#[test]
fn missing_scene_states_its_cause_once() {
    let err = refused(&["simulate", "scenes/does_not_exist.ron"]);
    assert!(err.contains("does_not_exist.ron: cannot read"), "{err}");
    assert_eq!(err.matches("os error 2").count(), 1, "{err}");
}

#[test]
fn output_folder_that_is_a_file() {
    let d = scratch("outfile");
    let f = d.join("a_file");
    std::fs::write(&f, b"keep me").unwrap();
    let tiny = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/scenes/tiny_transport.ron"
    );
    let err = refused(&[
        "optimize",
        tiny,
        "--epochs",
        "1",
        "--seeds",
        "1",
        "--out",
        s(&f),
    ]);
    assert!(
        err.contains("--out") && err.contains("is a file, not a folder"),
        "{err}"
    );
    assert_eq!(std::fs::read(&f).unwrap(), b"keep me", "left untouched");
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn gradcheck_tolerance_must_be_positive() {
    for tol in ["--tol=-1", "--tol=nan", "--tol=0"] {
        let err = refused(&["gradcheck", SCENE, "--steps", "1", tol]);
        assert!(err.contains("--tol") && err.contains("positive"), "{err}");
    }
}

#[test]
fn tape_budget_too_small_says_which_option() {
    let err = refused(&[
        "bench",
        SCENE,
        "--steps",
        "2",
        "--backward",
        "--budget-mb",
        "0",
    ]);
    assert!(
        err.contains("raise --budget-mb to at least") && !err.contains("cannot be differentiated"),
        "{err}"
    );
}
