//! `powderlab study directions --quick` on a seconds-long skill scene: every loss gets a cosine
//! against the dose error's secants at each point, and a second run reuses every rollout.

#![cfg(feature = "lab")]

use std::process::Command;

const SCENE: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/tests/scenes/tiny_transport.ron"
);

#[test]
fn the_direction_test_compares_each_loss_with_the_secants_and_resumes() {
    let dir = std::env::temp_dir().join(format!("powderlab-directions-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let run = || {
        let o = Command::new(env!("CARGO_BIN_EXE_powderlab"))
            .args([
                "study",
                "directions",
                "--quick",
                "--json",
                "--scene",
                SCENE,
                "--out",
            ])
            .arg(&dir)
            .arg("--results")
            .arg(dir.join("results"))
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    run();
    let md = std::fs::read_to_string(dir.join("results/directions.md")).unwrap();
    for loss in ["eq. 5", "dosing", "carry"] {
        assert!(md.contains(&format!("\n| {loss} | 0.1 |")), "{loss}:\n{md}");
    }
    let csv = std::fs::read_to_string(dir.join("results/directions.csv")).unwrap();
    // Two points, three losses, one step.
    assert_eq!(csv.lines().count(), 1 + 2 * 3, "{csv}");
    let cosines: Vec<f64> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(4).unwrap().parse().unwrap())
        .collect();
    assert!(cosines
        .iter()
        .all(|c| c.is_nan() || (-1.0 - 1e-12..=1.0 + 1e-12).contains(c)));
    // 2 points × (3 gradient rollouts + 1 + 10 secant rollouts), each once.
    let rollouts = std::fs::read_to_string(dir.join("directions/rollouts.jsonl")).unwrap();
    assert_eq!(rollouts.lines().count(), 2 * 14);
    run();
    let again = std::fs::read_to_string(dir.join("directions/rollouts.jsonl")).unwrap();
    assert_eq!(
        again.lines().count(),
        2 * 14,
        "the second run reran rollouts"
    );
    assert_eq!(
        std::fs::read_to_string(dir.join("results/directions.csv")).unwrap(),
        csv
    );
    let _ = std::fs::remove_dir_all(&dir);
}
