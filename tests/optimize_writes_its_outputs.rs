//! `powderlab optimize` with every method writes metrics.csv (a row per method, seed and
//! epoch), summary.json, the indicator figure, and a best-rollout recording that the official
//! Rerun CLI opens, with the loss curves in it.

#![cfg(feature = "lab")]
#![cfg(feature = "rerun")]

use std::process::Command;

mod common;

const SCENE: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/tests/scenes/tiny_transport.ron"
);

#[test]
fn optimize_writes_metrics_summary_figure_and_recording() {
    let out = std::env::temp_dir().join(format!("powderlab-opt-{}", std::process::id()));
    let o = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .args([
            "optimize", SCENE, "--method", "paper", "--epochs", "2", "--seeds", "1", "--json",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    for m in ["grad", "cmaes", "sac", "random"] {
        let s = &summary["methods"][m];
        assert_eq!(s["rollouts_per_seed"], 2, "{m}: {s}");
        assert!(s["final_indicator_mean"].as_f64().unwrap().is_finite());
        assert!(s["final_loss_mean"].as_f64().unwrap().is_finite());
    }
    assert_eq!(summary["indicator_unit"], "g");
    let on_disk: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(on_disk, summary);

    let csv = std::fs::read_to_string(out.join("metrics.csv")).unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    for col in [
        "method",
        "seed",
        "epoch",
        "loss",
        "indicator",
        "theta_d",
        "theta_p",
        "grad_norm",
        "rollouts",
        "wall_s",
    ] {
        assert!(header.contains(&col), "{col} missing from {header:?}");
    }
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 4 * 2);
    assert!(rows.iter().all(|r| r.len() == header.len()));
    let grad_norm = header.iter().position(|c| *c == "grad_norm").unwrap();
    for r in &rows {
        // Only the gradient method has a gradient.
        assert_eq!(r[0] == "grad", !r[grad_norm].is_empty(), "{r:?}");
    }

    let svg = std::fs::read_to_string(out.join("indicator.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("grad") && svg.contains("random"));

    common::assert_rrd_has(
        &out.join("best.rrd"),
        &[
            "/world/powder/powder",
            "/world/tools/spoon",
            "/metrics/optimize/grad/seed0/loss",
            "/metrics/optimize/random/seed0/indicator",
        ],
    );
    std::fs::remove_dir_all(&out).ok();
}

#[test]
fn without_method_optimize_runs_the_benchmarks_verdict_at_equal_compute() {
    let out = std::env::temp_dir().join(format!("powderlab-opt-default-{}", std::process::id()));
    let o = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .args([
            "optimize", SCENE, "--epochs", "4", "--seeds", "1", "--json", "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let mut ran: Vec<&str> = summary["methods"]
        .as_object()
        .unwrap()
        .keys()
        .map(|k| k.as_str())
        .collect();
    ran.sort_unstable();
    assert_eq!(ran, ["cmaes", "line", "random", "sac"]);
    let settings: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("settings.json")).unwrap()).unwrap();
    assert_eq!(settings["equal_compute"], true, "{settings}");
    assert_eq!(settings["epochs"], 4, "{settings}");
    std::fs::remove_dir_all(&out).ok();
}

/// A stream that starts at seed 2 (`--first-seed 2 --seeds 1`) is seed 2 of a run from seed 0:
/// the same Θ_init and the same randomness for every method, rollout for rollout.
#[test]
fn a_later_stream_reproduces_the_same_seed_of_a_longer_run() {
    let root = std::env::temp_dir().join(format!("powderlab-stream-{}", std::process::id()));
    let run = |dir: &str, extra: &[&str]| {
        let out = root.join(dir);
        let o = Command::new(env!("CARGO_BIN_EXE_powderlab"))
            .args([
                "optimize",
                SCENE,
                "--method",
                "random,cmaes",
                "--epochs",
                "2",
                "--json",
                "--out",
            ])
            .arg(&out)
            .args(extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        // method, seed, epoch, …: the rows of the run's seed `seed`, without the seed and the
        // two timed columns (rollout seconds and the compute counted from them).
        let csv = std::fs::read_to_string(out.join("metrics.csv")).unwrap();
        move |seed: &str| -> Vec<String> {
            csv.lines()
                .skip(1)
                .map(|l| l.split(',').collect::<Vec<_>>())
                .filter(|f| f[1] == seed)
                .map(|f| [&f[..1], &f[2..f.len() - 2]].concat().join(","))
                .collect()
        }
    };
    let long = run("long", &["--seeds", "3"]);
    let later = run("later", &["--seeds", "1", "--first-seed", "2"]);
    assert_eq!(later("0").len(), 4);
    assert_eq!(later("0"), long("2"));
    assert_ne!(later("0"), long("0"));
    std::fs::remove_dir_all(&root).ok();
}
