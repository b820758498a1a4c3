//! `powderlab optimize --method smoothed` (seed B's smoothed gradient): each step runs its
//! samples as gradient rollouts around Θ and counts them against the same rollout budget, and
//! the summary ranks it by the dose error with the others.

#![cfg(feature = "lab")]

use std::process::Command;

const SCENE: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/tests/scenes/tiny_transport.ron"
);

#[test]
fn smoothed_runs_its_samples_within_the_rollout_budget() {
    let out = std::env::temp_dir().join(format!("powderlab-smoothed-{}", std::process::id()));
    let o = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .args([
            "optimize",
            SCENE,
            "--method",
            "smoothed,random",
            "--epochs",
            "5",
            "--seeds",
            "1",
            "--smooth-samples",
            "2",
            "--json",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    // 5 rollouts allow 2 steps of 2 samples; the fifth is not run.
    assert_eq!(summary["methods"]["smoothed"]["rollouts_per_seed"], 4);
    assert_eq!(summary["methods"]["random"]["rollouts_per_seed"], 5);
    let ranked = summary["ranking_equal_compute"].as_array().unwrap();
    assert_eq!(ranked.len(), 2, "{summary}");
    // Every smoothed rollout carries its gradient, so it costs 3.4 forward rollouts.
    let csv = std::fs::read_to_string(out.join("metrics.csv")).unwrap();
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let g = header.iter().position(|c| *c == "grad_norm").unwrap();
    let rows: Vec<Vec<&str>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .filter(|r: &Vec<&str>| r[0] == "smoothed")
        .collect();
    assert_eq!(rows.len(), 4);
    assert!(rows.iter().all(|r| !r[g].is_empty()));
    let eq = &summary["methods"]["smoothed"]["equal_compute"];
    assert!(eq["rollouts_mean"].as_f64().unwrap() < 4.0, "{eq}");
    let _ = std::fs::remove_dir_all(&out);
}
