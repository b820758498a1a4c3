//! `powderlab optimize` killed in the middle of a run (SIGKILL, no chance to clean up) and then
//! resumed with `--resume` ends with exactly the results of an uninterrupted run, and re-uses
//! every rollout that had finished before the kill.

#![cfg(feature = "lab")]

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const SCENE: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/tests/scenes/tiny_transport.ron"
);
/// Each method and its baselines, 2 seeds x 3 rollouts: the gradient's replay, a CMA-ES
/// generation, SAC's network training and random draws all have to come back identical.
const ARGS: [&str; 8] = [
    "--method",
    "grad,cmaes,sac,random",
    "--epochs",
    "3",
    "--seeds",
    "2",
    "--sac-batch",
    "2",
];
/// Rollouts finished before the kill.
const KILL_AFTER: usize = 5;

fn optimize(out: &Path, extra: &[&str]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_powderlab"));
    c.args(["optimize", SCENE, "--json", "--out"])
        .arg(out)
        .args(ARGS)
        .args(extra);
    c
}

/// metrics.csv without the wall-time column, which differs between runs.
/// metrics.csv without its two timed columns: the rollout seconds, and the particle-substeps,
/// which count a backward pass at the multiple measured from those seconds
/// (`report::measured_backward_cost`). Everything the methods computed must be equal.
fn metrics_without_wall_time(dir: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(dir.join("metrics.csv")).unwrap();
    text.lines()
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            f[..f.len() - 2].join(",")
        })
        .collect()
}

fn journal_lines(dir: &Path) -> usize {
    std::fs::read_to_string(dir.join("journal.jsonl"))
        .map(|t| t.lines().count())
        .unwrap_or(0)
}

#[test]
fn a_killed_run_resumes_to_the_same_results_and_loses_no_rollout() {
    let root = std::env::temp_dir().join(format!("powderlab-resume-{}", std::process::id()));
    let (whole, killed) = (root.join("whole"), root.join("killed"));
    std::fs::create_dir_all(&root).unwrap();

    let st = optimize(&whole, &[])
        .stdout(Stdio::null())
        .status()
        .unwrap();
    assert!(st.success());

    let mut child = optimize(&killed, &[])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    while journal_lines(&killed) < KILL_AFTER {
        assert!(
            child.try_wait().unwrap().is_none(),
            "the run ended before it could be killed"
        );
        assert!(t0.elapsed() < Duration::from_secs(600), "no progress");
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    let finished = journal_lines(&killed);
    assert!(finished >= KILL_AFTER);

    // Starting over in a run directory is refused; so is resuming with other settings.
    let o = optimize(&killed, &[]).output().unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--resume"));
    let o = optimize(&killed, &["--resume", "--lr", "0.1"])
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("other settings"));

    // The time each method had run before the kill, as its journal lines record it.
    let mut before: std::collections::BTreeMap<String, f64> = Default::default();
    for line in std::fs::read_to_string(killed.join("journal.jsonl"))
        .unwrap()
        .lines()
    {
        if let Ok(r) = serde_json::from_str::<serde_json::Value>(line) {
            let t = r["method_elapsed_s"]
                .as_f64()
                .expect("every new line has it");
            let e = before
                .entry(r["method"].as_str().unwrap().into())
                .or_default();
            *e = e.max(t);
        }
    }
    assert!(!before.is_empty());

    let o = optimize(&killed, &["--resume"]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    // A method's wall time counts the processes before the resume too, not only this one.
    for (m, t) in &before {
        let w = summary["methods"][m]["wall_s"].as_f64().unwrap();
        assert!(
            w >= *t,
            "{m}: wall_s {w} after resume, {t} s before the kill"
        );
    }
    let replayed = summary["rollouts_replayed"].as_u64().unwrap() as usize;
    let ran = summary["rollouts_run"].as_u64().unwrap() as usize;
    // A kill can leave a torn last line, which resuming drops: at most one rollout is lost.
    assert!(
        replayed + 1 >= finished,
        "{replayed} replayed of {finished} finished"
    );
    assert_eq!(replayed + ran, 4 * 2 * 3, "every rollout once");
    assert_eq!(
        metrics_without_wall_time(&whole),
        metrics_without_wall_time(&killed)
    );
    std::fs::remove_dir_all(&root).ok();
}
