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
    // Every cosine and dose error, recomputed here from the journal's rollouts: the secant of
    // each parameter from the forward rollouts at Θ ± h·e_k (clamped to the box), against the
    // gradient of each loss at Θ.
    let journal: Vec<serde_json::Value> =
        std::fs::read_to_string(dir.join("directions/rollouts.jsonl"))
            .unwrap()
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
    let find = |kind: &str, theta: &[f64; 5]| {
        journal
            .iter()
            .find(|r| {
                r["kind"] == kind
                    && serde_json::from_value::<[f64; 5]>(r["theta"].clone()).unwrap() == *theta
            })
            .unwrap_or_else(|| panic!("no {kind} rollout at {theta:?}"))
    };
    let h = 0.1;
    let mut finite = 0;
    for line in csv.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let k: usize = f[1].strip_prefix("seed").unwrap().parse().unwrap();
        let theta: [f64; 5] = *powderlab::lab::optim::theta_init(k);
        let forward = |t: &[f64; 5]| find("forward", t)["value"].as_f64().unwrap();
        let secant: Vec<f64> = (0..5)
            .map(|i| {
                let (mut lo, mut hi) = (theta, theta);
                lo[i] = (theta[i] - h).max(-1.0);
                hi[i] = (theta[i] + h).min(1.0);
                (forward(&hi) - forward(&lo)) / (hi[i] - lo[i])
            })
            .collect();
        let kind = match f[2] {
            "eq. 5" => "eq5",
            other => other,
        };
        let grad: Vec<f64> = serde_json::from_value(find(kind, &theta)["grad"].clone()).unwrap();
        let dot: f64 = grad.iter().zip(&secant).map(|(a, b)| a * b).sum();
        let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
        let expected = dot / (norm(&grad) * norm(&secant));
        let cosine: f64 = f[4].parse().unwrap();
        assert!(
            (cosine - expected).abs() <= 1e-12 || (cosine.is_nan() && expected.is_nan()),
            "{line}: the cosine recomputed from the rollouts is {expected}"
        );
        finite += usize::from(cosine.is_finite());
        let dose: f64 = f[5].parse().unwrap();
        assert_eq!(dose, forward(&theta), "{line}");
    }
    assert!(finite > 0, "no finite cosine:\n{csv}");
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
