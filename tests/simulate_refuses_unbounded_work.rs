//! `simulate` prints its work estimate, and refuses a run over the work limit before it starts,
//! naming what drives the work, unless `--force` is given.

mod common;

use std::process::Command;

fn simulate(scene_text: &str, name: &str, extra: &[&str]) -> (i32, String) {
    let dir = std::env::temp_dir().join(format!("powderlab-work-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(name);
    std::fs::write(&path, scene_text).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .arg("simulate")
        .arg(&path)
        .args(extra)
        .output()
        .unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

fn sand_box() -> String {
    std::fs::read_to_string(common::scene_path("sand_box.ron"))
        .unwrap()
        .replace("stability: Strict", "stability: Auto")
}

#[test]
fn a_nearly_incompressible_powder_is_refused_naming_its_material() {
    // ν → 0.5 sends the wave speed, and the guard's substeps, to 19,033 per step.
    let text = sand_box().replace("poisson_ratio: 0.3", "poisson_ratio: 0.4999999");
    let (code, err) = simulate(&text, "incompressible.ron", &[]);
    assert_eq!(code, 2, "{err}");
    let last = err.trim_end().lines().last().unwrap();
    assert!(
        last.contains("incompressible.ron")
            && last.contains("19033 substeps")
            && last.contains("materials.sand.youngs_modulus")
            && last.contains("--force"),
        "{last}"
    );
}

#[test]
fn a_horizon_of_millions_of_steps_is_refused_naming_the_steps() {
    let text = sand_box().replace("steps: Some(20)", "steps: Some(20000000)");
    let (code, err) = simulate(&text, "long.ron", &[]);
    assert_eq!(code, 2, "{err}");
    let last = err.trim_end().lines().last().unwrap();
    assert!(
        last.contains("`simulation.steps`") && last.contains("--force"),
        "{last}"
    );
    // The file holds the field, so the refusal points at it.
    let (line, _) = text
        .lines()
        .enumerate()
        .find(|(_, l)| l.contains("steps: Some(20000000)"))
        .unwrap();
    assert!(last.contains(&format!("long.ron:{}:", line + 1)), "{last}");
}

#[test]
fn a_horizon_the_tool_takes_is_not_blamed_on_a_field_the_file_lacks() {
    // Found by `study reliability` (multi_scoop_dosing, case 397): a skill scene has no
    // `simulation.steps`; its horizon comes from the tool's speeds, and a crawling tool takes
    // hundreds of thousands of steps. The refusal named `simulation.steps` as if it were set.
    let text = std::fs::read_to_string(common::scene_path("powder_transport.ron"))
        .unwrap()
        .replace("linear_speed: 0.2,", "linear_speed: 1e-4,");
    let (code, err) = simulate(&text, "crawling.ron", &[]);
    assert_eq!(code, 2, "{err}");
    let last = err.trim_end().lines().last().unwrap();
    assert!(
        last.contains("the horizon of")
            && last.contains("tool's controls")
            && !last.contains("`simulation.steps` ="),
        "{last}"
    );
}

#[test]
fn an_ordinary_run_prints_its_estimate_and_runs() {
    let (code, err) = simulate(&sand_box(), "ordinary.ron", &["--steps", "1"]);
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains("work: 54872 particles × 20 substeps × 1 steps"),
        "{err}"
    );
}

/// `optimize` prints the most a rollout may cost (its longest horizon over Θ) and the run's
/// compute in forward rollouts before it starts.
#[cfg(feature = "lab")]
#[test]
fn optimize_prints_its_estimate() {
    let dir = std::env::temp_dir().join(format!("powderlab-work-opt-{}", std::process::id()));
    let o = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .args(["optimize", "tests/scenes/tiny_transport.ron"])
        .args([
            "--method",
            "random,grad",
            "--epochs",
            "1",
            "--seeds",
            "2",
            "--out",
        ])
        .arg(&dir)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    // The tiny scene's skill takes at most 154 steps at 14 substeps; random's rollout is one
    // forward rollout and grad's 3.4, on each of two seeds.
    assert!(
        err.contains("work: a rollout at most 1070 particles × 14 substeps × 154 steps"),
        "{err}"
    );
    assert!(err.contains("9 forward rollouts' worth in all"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_grid_without_particles_still_announces_its_work() {
    // Found by `study reliability` (policy_dosing, case 66): a spoon 15 m thick displaces
    // every grain, the skill's horizon grows to 3,935 steps and the guard raises the substeps
    // to 198. The run is all grid work, about a minute, and the estimate must say so rather
    // than "0 s".
    let text = std::fs::read_to_string(common::scene_path("policy_dosing.ron"))
        .unwrap()
        .replace("thickness: 0.0015", "thickness: 1.5e1");
    let path = std::env::temp_dir().join(format!("powderlab-grid-work-{}.ron", std::process::id()));
    std::fs::write(&path, text).unwrap();
    let mut sim =
        powderlab::sim::Simulation::from_file(&path, &powderlab::sim::SimOptions::default())
            .unwrap();
    std::fs::remove_file(&path).ok();
    assert_eq!(sim.particle_count(), 0);
    let horizon = sim.horizon;
    let work = sim.work(horizon);
    assert!(work.seconds() > 30.0, "{}", work.describe());
    assert!(
        work.describe().contains("grid nodes"),
        "{}",
        work.describe()
    );
}
