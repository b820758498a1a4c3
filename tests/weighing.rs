//! Weighing (`powderlab::lab::weigh`, `powderlab weigh`): the balance reads what rests in its
//! boat, a tap moves the spatula as its settings say, a dose of nothing delivers only what the
//! carry sheds, and bad settings are refused.
//!
//! The doses run on `vial_weighing.ron` coarsened to dx = 2 mm (about 5k grains instead of 37k),
//! seconds each; the geometry, the skill and the rule are the shipped scene's.
#![cfg(feature = "lab")]

use powderlab::lab::weigh::{dose, Dispense, DoseReport};
use powderlab::scene::Scene;
use powderlab::sim::{SimOptions, Simulation};

mod common;

fn coarse(noise_mg: f64) -> Scene {
    common::coarse_weighing(noise_mg)
}

fn run(scene: &Scene, target_mg: f64, d: &Dispense) -> DoseReport {
    let opts = SimOptions::threads(Some(2));
    dose(scene, target_mg, d, &opts, None, &mut |_, _| {}).unwrap()
}

#[test]
fn once_settled_the_balance_reads_what_rests_in_the_boat() {
    // A block of 0.19 g dropped into the boat: after 4.5 s (nine time constants, so the lag has
    // closed to 1e-4 of the load, below the display's step) the noiseless display shows the content rounded to 0.1 mg, and with noise it stays
    // within five standard deviations and a step of it.
    for noise_mg in [0.0, 0.1] {
        let mut scene = coarse(noise_mg);
        scene.colliders.retain(|c| c.name != "spatula");
        scene.randomize = None;
        scene.bodies[0].fill = powderlab::scene::Fill::Box {
            min: (0.048, 0.008, 0.012),
            max: (0.056, 0.010, 0.020),
        };
        scene.validate().unwrap();
        let mut sim = Simulation::new(&scene, &SimOptions::default()).unwrap();
        sim.run(450, |_| {}).unwrap();
        let load = sim.balance_load_g().unwrap();
        let reading = sim.balance_reading_g().unwrap();
        // The load, counted here from the particles and the boat's cavity.
        let boat = scene.colliders.iter().find(|c| c.name == "boat").unwrap();
        let region =
            powderlab::math::geometry::CupRegion::of(&boat.shape, Scene::collider_pose(boat))
                .unwrap();
        let mass = scene.particle_masses()[0];
        let x = &sim.body_states()[0].x;
        let inside = x.iter().filter(|p| region.inside(**p)).count();
        assert_eq!(inside, x.len(), "grains outside the boat");
        assert!(((inside as f64 * mass * 1e3) - load).abs() < 1e-12);
        let tol = 5.0 * noise_mg * 1e-3 + 1e-4;
        assert!(
            (reading - load).abs() <= tol,
            "noise {noise_mg} mg: reads {reading} g for {load} g"
        );
    }
}

#[test]
fn a_dose_of_nothing_delivers_only_what_the_carry_sheds_and_a_tap_moves_as_set() {
    let scene = coarse(0.1);
    let d = Dispense::default();
    let zero = run(&scene, 0.0, &d);
    // Nothing tilts: the reading plus its lead meets a target of 0 at once.
    assert!(zero.trace.iter().all(|t| t.1 == 0.0), "the spatula tilted");
    assert_eq!((zero.scoops, zero.taps), (1, 0));
    // The same carry and stillness without the rule: the boat gets the same grains.
    let mut sim = Simulation::new(&scene, &SimOptions::default()).unwrap();
    let (tool, sk) = powderlab::lab::weigh::skill_tool(&scene).unwrap();
    let (controls, phases) = sk.controls(
        scene.simulation.dt,
        Scene::tool_bottom(&scene.colliders[tool]),
    );
    let carry = phases[..4].iter().sum::<usize>();
    let still = std::iter::repeat([0.0; 6]);
    for u in controls[..carry]
        .iter()
        .copied()
        .chain(still)
        .take(zero.steps)
    {
        sim.drive_tool(tool, u);
        sim.step().unwrap();
    }
    let shed = sim.balance_load_g().unwrap() * 1e3;
    assert_eq!(zero.delivered_mg, shed);
    assert!(zero.delivered_mg <= 5.0 * zero.grain_mg, "{zero:?}");

    // A dose: every tap drops the spatula by tap_mm in one step and lifts it back the next,
    // every tap_every steps, while it tilts.
    let d = Dispense {
        tap_mm: 0.7,
        tap_every: 3,
        ..Dispense::default()
    };
    let r = run(&scene, 5.0, &d);
    assert!(r.taps > 3, "{} taps", r.taps);
    let h: Vec<f64> = r.trace.iter().map(|t| t.2).collect();
    let mut drops = 0;
    for k in 1..h.len() - 1 {
        let (down, up) = (h[k] - h[k - 1], h[k + 1] - h[k]);
        if down < -1e-9 && r.trace[k].1 > 0.0 && r.trace[k].1 != r.trace[k - 1].1 {
            assert!((down + 0.7).abs() < 1e-9, "step {k}: dropped {down} mm");
            assert!((up - 0.7).abs() < 1e-9, "step {k}: rose {up} mm");
            drops += 1;
        }
    }
    assert_eq!(drops, r.taps);
    // Taps are tap_every steps apart within a tilt.
    let at: Vec<usize> = (1..h.len())
        .filter(|&k| h[k] - h[k - 1] < -1e-9 && r.trace[k].1 > 0.0)
        .collect();
    assert!(at.windows(2).any(|w| w[1] - w[0] == 3));
    assert!(at.windows(2).all(|w| w[1] - w[0] >= 3));
    assert!(r.delivered_mg > 0.0);
}

#[test]
fn weigh_prints_its_keys_and_refuses_bad_settings() {
    let dir = std::env::temp_dir().join(format!("powderlab-weigh-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let scene = dir.join("coarse.ron");
    let text = std::fs::read_to_string(common::scene_path("vial_weighing.ron"))
        .unwrap()
        .replace("cells: (72, 48, 32)", "cells: (36, 24, 16)")
        .replace("dx: 0.001", "dx: 0.002")
        .replace("walls: (cells: 3", "walls: (cells: 2");
    std::fs::write(&scene, text).unwrap();
    let bin = env!("CARGO_BIN_EXE_powderlab");
    let out = common::succeeds(
        std::process::Command::new(bin)
            .arg("weigh")
            .arg(&scene)
            .args(["--target-mg", "0", "--json", "--out"])
            .arg(dir.join("run")),
    );
    // The recording holds the balance's reading beside the 3D view.
    common::assert_rrd_has(
        &dir.join("run/weigh.rrd"),
        &[
            "balance/reading_mg",
            "world/powder/powder",
            "spatula/tilt_deg",
        ],
    );
    assert!(dir.join("run/dose.json").is_file());
    let v: serde_json::Value =
        serde_json::from_str(String::from_utf8_lossy(&out.stdout).lines().last().unwrap()).unwrap();
    for key in [
        "target_mg",
        "delivered_mg",
        "error_mg",
        "scoops",
        "sim_s",
        "wall_s",
    ] {
        assert!(v.get(key).is_some(), "no {key} in {v}");
    }
    for (args, says) in [
        (vec!["--dispense", "tap_mm=-1"], "dispense.tap_mm"),
        (vec!["--dispense", "shake=1"], "no such setting"),
        (vec!["--dispense", "max_scoops=2.5"], "dispense.max_scoops"),
        (vec!["--set", "friction_deg=abc"], "not a finite number"),
        (vec!["--set", "colour=3"], "colour"),
        (vec!["--target-mg=-5"], "--target-mg"),
    ] {
        refused(bin, &scene, &args, says);
    }
    // A scene without a balance, and a balance on no boat.
    let text = std::fs::read_to_string(&scene).unwrap();
    for (name, from, to, says) in [
        (
            "plain",
            "balance: Some((container: \"boat\")),",
            "",
            "field balance: missing",
        ),
        (
            "wrong",
            "container: \"boat\")",
            "container: \"vial2\")",
            "balance.container",
        ),
    ] {
        let path = dir.join(format!("{name}.ron"));
        std::fs::write(&path, text.replace(from, to)).unwrap();
        refused(bin, &path, &[], says);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// `powderlab weigh SCENE ARGS` exits with code 2 and one line that contains `says`.
fn refused(bin: &str, scene: &std::path::Path, args: &[&str], says: &str) {
    let out = std::process::Command::new(bin)
        .arg("weigh")
        .arg(scene)
        .args(args)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
    assert!(err.contains(says), "{args:?}: {err}");
    assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
}
