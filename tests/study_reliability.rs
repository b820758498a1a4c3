//! The reliability study's harness end to end on a tiny seed scene: every mutated case runs
//! `simulate` in a process of its own under a cap and a timeout, is classified, journalled,
//! and not run again when the study resumes; the page counts what the journal holds.

#![cfg(feature = "lab")]

use powderlab::lab::study::reliability::{self, Config, Outcome};
use std::path::Path;

const SEED: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/tests/scenes/calibration_tiny.ron"
);

fn root_with_one_seed(dir: &Path) {
    std::fs::create_dir_all(dir.join("scenes")).unwrap();
    std::fs::create_dir_all(dir.join("tests/scenes")).unwrap();
    std::fs::copy(SEED, dir.join("scenes/calibration_tiny.ron")).unwrap();
}

#[test]
fn mutated_cases_are_classified_journalled_and_not_run_again() {
    let root = std::env::temp_dir().join(format!("powderlab-reliability-{}", std::process::id()));
    std::fs::remove_dir_all(&root).ok();
    root_with_one_seed(&root);
    let dir = root.join("out");
    let cfg = Config {
        cases: 24,
        cap_bytes: 8 << 30,
        timeout_s: 20.0,
        jobs: 2,
    };
    let exe = Path::new(env!("CARGO_BIN_EXE_powderlab"));
    let first = reliability::run(exe, &root, &dir, &cfg, &|_, _| {}).unwrap();
    assert_eq!(first.len(), 24);
    assert!(first.iter().all(|r| r.seed == "calibration_tiny.ron"));
    let ks: Vec<u64> = first.iter().map(|r| r.k).collect();
    assert_eq!(ks, (0..24).collect::<Vec<_>>());
    // The mutations both refuse and accept: the harness sees both kinds of exit.
    assert!(first.iter().any(|r| r.outcome == Outcome::Refused));
    assert!(first.iter().any(|r| r.outcome == Outcome::Ran));
    for r in &first {
        assert!(
            r.problem.is_none(),
            "calibration_tiny#{}: {:?}: {}",
            r.k,
            r.problem,
            r.last_line
        );
    }
    let journal = dir.join("cases.jsonl");
    let lines = std::fs::read_to_string(&journal).unwrap().lines().count();
    assert_eq!(lines, 24);
    // A resumed study reads the journal and runs nothing again; the mutated files are gone.
    let again = reliability::run(exe, &root, &dir, &cfg, &|_, _| {}).unwrap();
    assert_eq!(
        std::fs::read_to_string(&journal).unwrap().lines().count(),
        24
    );
    assert_eq!(
        serde_json::to_string(&first).unwrap(),
        serde_json::to_string(&again).unwrap()
    );
    assert_eq!(std::fs::read_dir(dir.join("work")).unwrap().count(), 0);
    let page = reliability::report(&again, &cfg, "cmd", "machine");
    let refused = again
        .iter()
        .filter(|r| r.outcome == Outcome::Refused)
        .count();
    assert!(page.contains(&format!("| refused before running (exit 2) | {refused} |")));
    assert!(page.contains("| panics | 0 |"));
    std::fs::remove_dir_all(&root).ok();
}
