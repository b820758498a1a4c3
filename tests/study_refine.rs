//! `powderlab study refine` on a seconds-long skill scene: each dimension's methods run on the
//! paired seeds from the plain skill, the page has a row per dimension and method, and a second
//! run replays every rollout.

#![cfg(feature = "lab")]

use std::process::Command;

const SCENE: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/tests/scenes/tiny_transport.ron"
);

#[test]
fn refinement_compares_the_adjoint_with_the_baselines_by_dimension_and_resumes() {
    let dir = std::env::temp_dir().join(format!("powderlab-refine-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let run = || {
        let o = Command::new(env!("CARGO_BIN_EXE_powderlab"))
            .args([
                "study", "refine", "--scene", SCENE, "--knots", "1,2", "--seeds", "2", "--budget",
                "4", "--json", "--out",
            ])
            .arg(&dir)
            .arg("--results")
            .arg(dir.join("results"))
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice::<serde_json::Value>(&o.stdout).unwrap()
    };
    let first = run();
    let md = std::fs::read_to_string(dir.join("results/refinement.md")).unwrap();
    for dim in [6, 12] {
        for m in ["line", "adam", "trust", "ray", "cmaes", "random", "sac"] {
            assert!(
                md.contains(&format!("\n| {dim} | {m} |")),
                "{dim} {m}:\n{md}"
            );
        }
    }
    let rollouts = std::fs::read_to_string(dir.join("refine/rollouts.jsonl")).unwrap();
    let rows: Vec<serde_json::Value> = rollouts
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    // Per dimension and seed: adam's ⌈4/3.4⌉ = 2 gradient rollouts, 4 CMA-ES, 4 random, 4 ray
    // and 4 SAC ones, and trust's and line's one gradient rollout each (3.4), after which a
    // forward trial (1) would pass the budget of 4.
    assert_eq!(rows.len(), 2 * 2 * (2 + 1 + 1 + 4 + 4 + 4 + 4));
    // Every method starts from the plain skill: adam's and random's first rollouts are the same
    // simulation, so the same loss to the bit.
    for seed in 0..2 {
        let at = |m: &str| {
            rows.iter()
                .find(|r| {
                    r["method"] == m && r["seed"] == seed && r["index"] == 0 && r["knots"] == 1
                })
                .unwrap()["loss"]
                .as_f64()
                .unwrap()
        };
        assert_eq!(at("adam"), at("random"));
        assert_eq!(at("trust"), at("random"));
        assert_eq!(at("line"), at("random"));
        assert_eq!(at("ray"), at("random"));
        assert_eq!(
            at("sac"),
            at("random"),
            "SAC's first action is the plain skill"
        );
    }
    let second = run();
    assert_eq!(
        std::fs::read_to_string(dir.join("refine/rollouts.jsonl"))
            .unwrap()
            .lines()
            .count(),
        rows.len(),
        "the second run reran rollouts"
    );
    assert_eq!(first["cells"], second["cells"]);
    let _ = std::fs::remove_dir_all(&dir);
}
