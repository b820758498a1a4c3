//! `--save-state` writes a PLY that reads back to the final state, byte-for-byte the same on
//! every run.

use std::process::Command;

fn run(out: &std::path::Path, threads: &str) -> Vec<u8> {
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/free_fall.ron");
    let st = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .args([
            "simulate",
            scene,
            "--steps",
            "3",
            "--threads",
            threads,
            "--save-state",
        ])
        .arg(out)
        .status()
        .unwrap();
    assert!(st.success());
    std::fs::read(out).unwrap()
}

#[test]
fn ply_is_byte_identical_and_reads_back() {
    let dir = std::env::temp_dir().join(format!("powderlab-ply-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let a = run(&dir.join("a.ply"), "1");
    let b = run(&dir.join("b.ply"), "2");
    assert_eq!(a, b);
    let verts = powderlab::ply::read_ply(&a).expect("valid PLY");
    assert_eq!(verts.len(), 4096);
    assert!(verts.iter().all(|v| v.iter().all(|x| x.is_finite())));
    assert!(
        String::from_utf8_lossy(&a[..200]).starts_with("ply\nformat binary_little_endian 1.0\n")
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bad_input_exits_non_zero_with_one_line() {
    let o = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .args(["simulate", "no/such/scene.ron"])
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("no/such/scene.ron"));
}
