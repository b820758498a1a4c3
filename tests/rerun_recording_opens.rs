//! A recording written by `powderlab simulate --out` opens in the official Rerun CLI
//! (`rerun rrd stats`, PyPI rerun-sdk==0.36.3) and holds the documented entities.
#![cfg(feature = "rerun")]

use std::process::Command;

mod common;

#[test]
fn recording_opens_in_rerun_and_has_the_entities() {
    let dir = std::env::temp_dir().join(format!("powderlab-rrd-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("pt.rrd");
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/powder_transport.ron");
    let st = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .args(["simulate", scene, "--steps", "4", "--out"])
        .arg(&out)
        .status()
        .unwrap();
    assert!(st.success());
    assert!(
        out.exists(),
        "the recording is renamed into place when finished"
    );
    assert!(!dir.join("pt.rrd.partial").exists());
    common::assert_rrd_has(
        &out,
        &[
            "/world/powder/powder",
            "/world/tools/spoon",
            "/world/containers/source_cup",
            "/world/containers/target_cup",
            "/metrics/transported_particles",
            "/metrics/mean_height",
            "/metrics/kinetic_energy",
            "/metrics/gravitational_energy",
            "/metrics/elastic_energy",
            "/metrics/total_energy",
        ],
    );
    let verify = common::rerun_cli()
        .args(["rrd", "verify"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        verify.status.success(),
        "rerun rrd verify: {}",
        String::from_utf8_lossy(&verify.stderr)
    );
    std::fs::remove_dir_all(&dir).ok();
}
