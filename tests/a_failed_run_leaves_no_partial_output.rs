//! A run that fails mid-way (a NaN injected into one particle's velocity after step 3, through
//! `POWDERLAB_FAULT_NAN_AT_STEP`) names the stage and the scene fields most likely responsible
//! in one line, and leaves no recording under any name, unless `--keep-partial` asks for the
//! recording up to the failure.
#![cfg(feature = "rerun")]

use std::path::PathBuf;
use std::process::Command;

mod common;

fn run(out: &std::path::Path, keep: bool) -> (Option<i32>, String) {
    let mut c = Command::new(env!("CARGO_BIN_EXE_powderlab"));
    c.arg("simulate")
        .arg(common::scene_path("free_fall.ron"))
        .args(["--steps", "8", "--out"])
        .arg(out)
        .env("POWDERLAB_FAULT_NAN_AT_STEP", "3");
    if keep {
        c.arg("--keep-partial");
    }
    let o = c.output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    let last = err.lines().last().unwrap_or("").to_string();
    (o.status.code(), last)
}

fn scratch() -> PathBuf {
    let d = std::env::temp_dir().join(format!("powderlab-partial-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn a_failed_run_leaves_no_partial_output_unless_asked() {
    let d = scratch();
    let out = d.join("run.rrd");
    let partial = d.join("run.rrd.partial");
    let (code, err) = run(&out, false);
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.starts_with("error: non-finite value at step 4"),
        "{err}"
    );
    assert!(err.contains("most likely responsible:"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(
        !out.exists() && !partial.exists(),
        "an output was left: {err}"
    );

    let (code, err) = run(&out, true);
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("kept the recording up to the failure in") && err.contains("run.rrd.partial"),
        "{err}"
    );
    assert!(!out.exists());
    assert!(std::fs::metadata(&partial).unwrap().len() > 0);
}
