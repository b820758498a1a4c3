//! `powderlab study landscape` writes its map (CSV and Markdown) and, run again on the same
//! folder, reuses every rollout it finished instead of simulating it again.

#![cfg(feature = "lab")]

use std::process::Command;

const SCENE: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/tests/scenes/tiny_transport.ron"
);

fn landscape(out: &std::path::Path, samples: &str) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .args([
            "study",
            "landscape",
            "--scene",
            SCENE,
            "--samples",
            samples,
            "--json",
            "--out",
        ])
        .arg(out)
        .output()
        .unwrap()
}

#[test]
fn the_map_is_written_and_a_second_run_reuses_its_rollouts() {
    let out = std::env::temp_dir().join(format!("powderlab-landscape-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let o = landscape(&out, "3");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let md = std::fs::read_to_string(out.join("landscape.md")).unwrap();
    assert!(
        md.starts_with("3 rollouts") && md.contains("| θ_d |"),
        "{md}"
    );
    let lines = |p: &str| {
        std::fs::read_to_string(out.join(p))
            .unwrap()
            .lines()
            .count()
    };
    assert_eq!(lines("landscape.csv"), 4);
    assert_eq!(lines("rollouts.jsonl"), 3);
    // Two more samples: only those run; the first three are read back.
    let o = landscape(&out, "5");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(lines("rollouts.jsonl"), 5);
    assert_eq!(lines("landscape.csv"), 6);
    let _ = std::fs::remove_dir_all(&out);
}
