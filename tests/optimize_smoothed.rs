//! `powderlab optimize --method smoothed` (seed B's smoothed gradient): each step runs its
//! samples as gradient rollouts around Θ and counts them against the same rollout budget, and
//! the summary ranks it by the dose error with the others.

#![cfg(feature = "lab")]

use powderlab::skills::Theta;
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

/// Seed B's initial-state noise: another packing of the same powder, reproducible from its
/// seed, a tenth of a spacing on average, and the scene's own packing bit for bit at 0.
#[test]
fn a_repacked_rollout_moves_the_powder_a_fraction_of_a_spacing_and_is_reproducible() {
    use powderlab::lab::optim::problem::Problem;
    let scene = powderlab::scene::Scene::load(SCENE).unwrap();
    let spacing = scene.particle_spacing(&scene.bodies[0]);
    let p = Problem::new(scene, 1 << 30).unwrap();
    let theta = Theta([0.1, -0.2, 0.3, 0.0, 0.5]);
    let x = |sim: &mut powderlab::sim::Simulation| -> Vec<glam::DVec3> {
        sim.body_states().into_iter().flat_map(|b| b.x).collect()
    };
    let base = x(&mut p.simulation(theta, false).unwrap());
    assert_eq!(
        x(&mut p.simulation_repacked(theta, false, 0.0, 7).unwrap()),
        base
    );
    let a = x(&mut p.simulation_repacked(theta, false, 0.1, 7).unwrap());
    let b = x(&mut p.simulation_repacked(theta, false, 0.1, 7).unwrap());
    let c = x(&mut p.simulation_repacked(theta, false, 0.1, 8).unwrap());
    assert_eq!(a, b, "the same seed gives the same packing");
    assert_ne!(a, c, "another seed gives another packing");
    // Per axis a normal draw of 0.1 spacing: the RMS displacement is 0.1·√3 spacings.
    let rms = (a
        .iter()
        .zip(&base)
        .map(|(p, q)| (*p - *q).length_squared())
        .sum::<f64>()
        / a.len() as f64)
        .sqrt();
    let expected = 0.1 * 3f64.sqrt() * spacing;
    assert!(
        (rms / expected - 1.0).abs() < 0.1,
        "{rms} against {expected}"
    );
    let o = p.evaluate_repacked(theta, false, 0.1, 7).unwrap();
    assert!(o.loss.is_finite() && o.grad.unwrap().iter().all(|g| g.is_finite()));
    assert_eq!(o, {
        let mut again = p.evaluate_repacked(theta, false, 0.1, 7).unwrap();
        again.wall_s = o.wall_s;
        again
    });
}
