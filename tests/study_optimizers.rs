//! `powderlab study optimizers` on a seconds-long skill scene: every method named runs on the
//! paired seeds within the same compute, the hybrid stays inside its budget, and the page,
//! figure and table come out with a Wilcoxon p-value against each baseline. The carry method
//! descends its own loss but reports the scene's.

#![cfg(feature = "lab")]

use std::process::Command;

const SCENE: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/tests/scenes/tiny_transport.ron"
);

#[test]
fn the_benchmark_scores_every_method_at_equal_compute_and_resumes() {
    let dir = std::env::temp_dir().join(format!("powderlab-study-opt-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let run = || {
        Command::new(env!("CARGO_BIN_EXE_powderlab"))
            .args([
                "study",
                "optimizers",
                "--tasks",
                SCENE,
                "--seeds",
                "2",
                "--budget",
                "7",
                "--method",
                "hybrid,grad,carry,random,line,ray",
                "--json",
                "--out",
            ])
            .arg(&dir)
            .arg("--results")
            .arg(dir.join("results"))
            .output()
            .unwrap()
    };
    let o = run();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let page = std::fs::read_to_string(dir.join("results/optimisation.md")).unwrap();
    assert!(page.starts_with("# Optimisation benchmark"));
    assert!(page.contains("Regenerate: `powderlab study optimizers --tasks"));
    for m in ["hybrid", "grad", "carry", "random", "line", "ray"] {
        assert!(page.contains(&format!("\n| {m} |")), "{m} missing:\n{page}");
    }
    assert!(
        std::fs::metadata(dir.join("results/optimisation.svg"))
            .unwrap()
            .len()
            > 1000
    );
    let csv = std::fs::read_to_string(dir.join("results/optimisation.csv")).unwrap();
    // One row per method and seed.
    assert_eq!(csv.lines().count(), 1 + 6 * 2, "{csv}");
    // line is tested against its ablation ray.
    assert!(page.contains("| p < ray |"), "{page}");
    assert!(page.contains("line against its ablation ray (random axes): p = "));
    assert!(
        page.contains("No worse than the best baseline? The one-sided p that "),
        "{page}"
    );

    // The hybrid's run: half the budget (3 forward rollouts, Θ_init first) on Sobol points,
    // then a gradient rollout at the best of them; its compute never passes 7 forward
    // rollouts, a gradient rollout counted at 1 + BACKWARD_COST.
    let journal =
        std::fs::read_to_string(dir.join("optimizers/tiny_transport/journal.jsonl")).unwrap();
    for seed in 0..2 {
        let hybrid: Vec<serde_json::Value> = journal
            .lines()
            .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
            .filter(|r| r["method"] == "hybrid" && r["seed"] == seed)
            .collect();
        let grads: Vec<bool> = hybrid.iter().map(|r| !r["grad"].is_null()).collect();
        assert_eq!(&grads[..4], &[false, false, false, true], "{grads:?}");
        let units: f64 = grads
            .iter()
            .map(|g| {
                if *g {
                    1.0 + powderlab::lab::optim::report::BACKWARD_COST
                } else {
                    1.0
                }
            })
            .sum();
        assert!(units <= 7.0 + 1e-9, "{units}");
        // The gradient rollout runs at the global phase's best Θ.
        let best = hybrid[..3]
            .iter()
            .min_by(|a, b| {
                a["loss"]
                    .as_f64()
                    .unwrap()
                    .total_cmp(&b["loss"].as_f64().unwrap())
            })
            .unwrap();
        assert_eq!(best["theta"], hybrid[3]["theta"]);
    }
    // Equal compute gives grad ⌈7/3.4⌉ = 3 gradient rollouts per seed.
    let grad_rollouts = journal
        .lines()
        .filter(|l| l.contains("\"method\":\"grad\""))
        .count();
    assert_eq!(grad_rollouts, 3 * 2);

    // carry's first rollout runs at the same Θ_init as grad's, and reports the scene's loss
    // (what selects the best rollout), bitwise grad's; its gradient is the carry loss's.
    let first = |m: &str, seed: u64| -> serde_json::Value {
        journal
            .lines()
            .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
            .find(|r| r["method"] == m && r["seed"] == seed && r["batch"] == 0)
            .unwrap()
    };
    for seed in 0..2 {
        let (g, c) = (first("grad", seed), first("carry", seed));
        assert_eq!(g["theta"], c["theta"]);
        assert_eq!(g["loss"], c["loss"]);
        assert_ne!(g["grad"], c["grad"]);
    }
    // line and ray: the hybrid's global phase (the same three points and rollouts), then
    // line's gradient rollout at its lowest-loss point, ray's forward rollouts only, all within
    // 7 forward rollouts of compute. (Where the phase both over- and under-delivers, the segment
    // between the two comes first: `optim::line`'s unit tests cover that; this scene's phase
    // does not, which the test checks so that the gradient's place below holds.)
    let rollouts = |m: &str, seed: u64| -> Vec<serde_json::Value> {
        let mut v: Vec<serde_json::Value> = journal
            .lines()
            .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
            .filter(|r| r["method"] == m && r["seed"] == seed)
            .collect();
        v.sort_by_key(|r| r["batch"].as_u64());
        v
    };
    for seed in 0..2 {
        let (hybrid, line, ray) = (
            rollouts("hybrid", seed),
            rollouts("line", seed),
            rollouts("ray", seed),
        );
        for i in 0..3 {
            assert_eq!(line[i]["theta"], hybrid[i]["theta"]);
            assert_eq!(line[i]["loss"], hybrid[i]["loss"]);
            assert_eq!(ray[i]["loss"], hybrid[i]["loss"]);
        }
        let f = |r: &serde_json::Value| r["indicator"].as_f64().unwrap();
        assert!(
            !(hybrid[..3].iter().any(|r| f(r) > 0.0) && hybrid[..3].iter().any(|r| f(r) < 0.0)),
            "this scene's global phase brackets the target: {hybrid:?}"
        );
        // 3 + 3.4: no forward rollout fits after the gradient's.
        assert_eq!(line.len(), 4, "{line:?}");
        assert_eq!(
            line[3]["theta"], hybrid[3]["theta"],
            "at the global phase's best"
        );
        assert!(!line[3]["grad"].is_null());
        assert!(ray.iter().all(|r| r["grad"].is_null()));
        assert_eq!(ray.len(), 7);
    }
    // A second run replays every rollout from the journals and writes the same table.
    let o2 = run();
    assert!(
        o2.status.success(),
        "{}",
        String::from_utf8_lossy(&o2.stderr)
    );
    let csv2 = std::fs::read_to_string(dir.join("results/optimisation.csv")).unwrap();
    assert_eq!(csv, csv2);

    // Resuming with fewer methods replays them and runs nothing new; --page names the files.
    let journal_path = dir.join("optimizers/tiny_transport/journal.jsonl");
    let before = std::fs::read_to_string(&journal_path).unwrap();
    let o3 = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .args(["study", "optimizers", "--tasks", SCENE, "--seeds", "2"])
        .args([
            "--budget",
            "7",
            "--method",
            "line,random",
            "--page",
            "subset",
        ])
        .args(["--json", "--out"])
        .arg(&dir)
        .arg("--results")
        .arg(dir.join("results"))
        .output()
        .unwrap();
    assert!(
        o3.status.success(),
        "{}",
        String::from_utf8_lossy(&o3.stderr)
    );
    assert_eq!(std::fs::read_to_string(&journal_path).unwrap(), before);
    let subset = std::fs::read_to_string(dir.join("results/subset.md")).unwrap();
    assert!(
        subset.contains("--method line,random --page subset`"),
        "{subset}"
    );
    assert!(subset.contains("](subset.svg)") && subset.contains("\n| line |"));
    assert!(!subset.contains("\n| hybrid |"));
    assert!(dir.join("results/subset.csv").exists());
    let _ = std::fs::remove_dir_all(&dir);
}
