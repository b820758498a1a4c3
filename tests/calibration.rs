//! Calibration from observations (`powderlab calibrate`): the gradient of an observation loss
//! with respect to the fitted parameters against central differences, recovery of a friction
//! angle on a tiny scene, and one-line refusals of bad observation files.
#![cfg(feature = "lab")]

mod common;

use powderlab::lab::calibrate::observation::Observed;
use powderlab::lab::calibrate::{self, params, AdamConfig, Calibration};
use std::path::PathBuf;
use std::process::Command;

/// The tiny collapse with its friction angle set, observed as a height map at `step` (no noise:
/// the test checks the optimiser and the gradient, not the noise).
fn observed(truth: f64, step: usize, heights: bool) -> Observed {
    let mut scene = common::load_test_scene("calibration_tiny.ron");
    let p = params::parse(&scene, &["friction_deg".into()], &[]).unwrap();
    p[0].apply(&mut scene, truth);
    Observed {
        path: PathBuf::from(format!("tiny@{step}")),
        step: Some(step),
        body: None,
        what: calibrate::observe(&scene, step, heights, 0.005, 0.0, 1, Some(1)).unwrap(),
    }
}

fn problem(fit: &[&str], obs: &[Observed]) -> Calibration {
    let scene = common::load_test_scene("calibration_tiny.ron");
    let names: Vec<String> = fit.iter().map(|s| s.to_string()).collect();
    let p = params::parse(&scene, &names, &[]).unwrap();
    let mut c = Calibration::new(&scene, p, obs, None).unwrap();
    c.threads = Some(1);
    c
}

/// A central difference of 1e-4 in unit coordinates (0.005° of friction angle, 0.03 % of E):
/// the flow's contact switches make the loss rough below about 1e-5, and the curvature's error
/// at 1e-4 is under 1e-3 relative on these losses.
const H: f64 = 1e-4;
/// Relative agreement of the adjoint with the central difference.
const TOL: f64 = 2e-2;

#[test]
fn observation_losses_gradient_matches_central_differences_through_the_collapse() {
    // A height map midway and a point cloud at the end: a sequence, so the intermediate term's
    // gradient enters the reverse sweep at its step.
    let obs = [observed(36.0, 25, true), observed(36.0, 50, false)];
    let cal = problem(&["friction_deg", "floor.friction", "youngs_modulus"], &obs);
    let u = vec![0.45, 0.3, 0.5];
    let e = cal.evaluate(&u, true).unwrap();
    let g = e.grad.clone().unwrap();
    let fwd = cal.evaluate(&u, false).unwrap().loss;
    assert!(
        (fwd - e.loss).abs() <= 1e-12 * e.loss.abs(),
        "taped {} vs forward {fwd}",
        e.loss
    );
    for i in 0..u.len() {
        let (mut up, mut dn) = (u.clone(), u.clone());
        up[i] += H;
        dn[i] -= H;
        let fd = (cal.evaluate(&up, false).unwrap().loss - cal.evaluate(&dn, false).unwrap().loss)
            / (2.0 * H);
        let rel = (fd - g[i]).abs() / fd.abs().max(g[i].abs()).max(1e-12);
        assert!(
            rel < TOL,
            "{}: adjoint {:e}, central difference {fd:e} (relative {rel:e})",
            cal.params[i].label,
            g[i]
        );
    }
}

#[test]
fn each_layers_friction_angle_gets_its_own_gradient_through_a_layered_collapse() {
    // Two layers of their own materials: a parameter per material, each gradient the sum over
    // the bodies made of it. The layers' gradients must differ (the bottom holds the pile's toe,
    // the top slides over it) and each must match its central difference.
    let path = common::test_scene_path("calibration_layers_tiny.ron");
    let mut scene = powderlab::scene::Scene::load(&path).unwrap();
    let names = [
        "layer0.friction_deg".to_string(),
        "layer1.friction_deg".to_string(),
    ];
    let p = params::parse(&scene, &names, &[]).unwrap();
    p[0].apply(&mut scene, 38.0);
    p[1].apply(&mut scene, 24.0);
    let obs: Vec<Observed> = [25, 50]
        .iter()
        .map(|&step| Observed {
            path: PathBuf::from(format!("layers@{step}")),
            step: Some(step),
            body: None,
            what: calibrate::observe(&scene, step, true, 0.005, 0.0, 1, Some(1)).unwrap(),
        })
        .collect();
    let mut cal = Calibration::new(&scene, p, &obs, None).unwrap();
    cal.threads = Some(1);
    let u = vec![0.4, 0.5];
    let g = cal.evaluate(&u, true).unwrap().grad.unwrap();
    for i in 0..u.len() {
        let (mut up, mut dn) = (u.clone(), u.clone());
        up[i] += H;
        dn[i] -= H;
        let fd = (cal.evaluate(&up, false).unwrap().loss - cal.evaluate(&dn, false).unwrap().loss)
            / (2.0 * H);
        let rel = (fd - g[i]).abs() / fd.abs().max(g[i].abs()).max(1e-12);
        assert!(
            rel < TOL,
            "{}: adjoint {:e}, central difference {fd:e} (relative {rel:e})",
            cal.params[i].label,
            g[i]
        );
    }
    let rel = (g[0] - g[1]).abs() / g[0].abs().max(g[1].abs());
    assert!(rel > 0.1, "the layers' gradients {g:?} are the same");
}

#[test]
fn adam_recovers_a_friction_angle_on_a_tiny_scene() {
    let truth = 32.0;
    let mut cal = problem(&["friction_deg"], &[observed(truth, 50, true)]);
    cal.params[0].apply(&mut cal.scene, 22.0);
    let u0 = cal.start();
    let trace = calibrate::adam(&u0, 60.0, AdamConfig::default(), |_, u, g| {
        cal.evaluate(u, g)
    })
    .unwrap();
    let best = calibrate::lowest(&trace).unwrap();
    assert!(
        (best.values[0] - truth).abs() < 1.0,
        "fitted {} for a true {truth} from 22 (losses {:?})",
        best.values[0],
        trace.iter().map(|e| e.loss).collect::<Vec<_>>()
    );
    assert!(best.loss < 0.1 * trace[0].loss);
}

#[test]
fn bfgs_recovers_a_friction_angle_from_a_start_near_the_bound_on_a_tiny_scene() {
    // The start is 25° off and near the top of the 10–60° range; the scan's quarters hold the
    // truth's basin, and the descent refines it.
    let truth = 32.0;
    let mut cal = problem(&["friction_deg"], &[observed(truth, 50, true)]);
    cal.params[0].apply(&mut cal.scene, 57.0);
    let u0 = cal.start();
    let cfg = calibrate::TrustConfig::for_dims(1);
    let trace = calibrate::trust_region(&u0, 30.0, cfg, 1, |_, u, g| cal.evaluate(u, g)).unwrap();
    let spent: f64 = trace.iter().map(|e| e.cost).sum();
    assert!(spent <= 30.0 + 1e-9, "spent {spent} of 30");
    assert!(
        trace.iter().any(|e| e.grad.is_some()),
        "no gradient rollout ran"
    );
    let best = calibrate::lowest(&trace).unwrap();
    assert!(
        (best.values[0] - truth).abs() < 1.0,
        "fitted {} for a true {truth} from 57 (trace {:?})",
        best.values[0],
        trace
            .iter()
            .map(|e| (e.values[0], e.loss))
            .collect::<Vec<_>>()
    );
}

fn powderlab(args: &[&str]) -> (i32, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .args(args)
        .output()
        .unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn bad_or_mismatched_observations_are_refused_in_one_line() {
    let dir = std::env::temp_dir().join(format!("powderlab-calib-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let scene = common::scene_path("calibration_collapse.ron");
    let scene = scene.to_str().unwrap();
    let malformed = dir.join("malformed.csv");
    std::fs::write(
        &malformed,
        "# pixel=0.0025 origin_x=0 origin_z=0\n0.01,0.02\n0.01\n",
    )
    .unwrap();
    // A cloud in millimetres: every point far outside the 12 cm domain.
    let mm = dir.join("millimetres.ply");
    let pts: Vec<glam::DVec3> = (0..50)
        .map(|i| glam::DVec3::new(10.0 + i as f64, 12.0, 10.0))
        .collect();
    std::fs::write(&mm, powderlab::lab::calibrate::observation::cloud_ply(&pts)).unwrap();
    let cases = [
        (malformed.to_str().unwrap().to_string(), "line 3: 1 values"),
        (
            mm.to_str().unwrap().to_string(),
            "outside the scene's domain",
        ),
        (
            format!("{}@x", dir.join("none.csv").display()),
            "cannot read",
        ),
    ];
    for (obs, want) in &cases {
        let (code, err) = powderlab(&[
            "calibrate",
            scene,
            "--observed",
            obs,
            "--fit",
            "friction_deg",
            "--out",
            dir.join("out").to_str().unwrap(),
        ]);
        assert_eq!(code, 2, "{obs}: {err}");
        let file = obs.split('@').next().unwrap();
        assert!(err.contains(file) && err.contains(want), "{obs}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    }
    // A well-formed cloud of a body the scene does not have.
    let inside = dir.join("inside.ply");
    let pts: Vec<glam::DVec3> = (0..50)
        .map(|i| glam::DVec3::new(0.02 + 0.001 * i as f64, 0.01, 0.01))
        .collect();
    std::fs::write(
        &inside,
        powderlab::lab::calibrate::observation::cloud_ply(&pts),
    )
    .unwrap();
    let (code, err) = powderlab(&[
        "calibrate",
        scene,
        "--observed",
        &format!("layer9={}@40", inside.display()),
        "--fit",
        "friction_deg",
        "--out",
        dir.join("out").to_str().unwrap(),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains(inside.to_str().unwrap()) && err.contains("no body 'layer9'"),
        "{err}"
    );
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    let (code, err) = powderlab(&[
        "calibrate",
        scene,
        "--observed",
        malformed.to_str().unwrap(),
        "--fit",
        "cohesion",
    ]);
    assert_eq!(code, 2);
    assert!(err.contains("--fit cohesion"), "{err}");
    // A search box reaching outside what a scene may hold is refused before any rollout.
    let (code, err) = powderlab(&[
        "calibrate",
        scene,
        "--observed",
        malformed.to_str().unwrap(),
        "--fit",
        "friction_deg",
        "--bounds",
        "friction_deg=20:95",
    ]);
    assert_eq!(code, 2);
    assert!(
        err.contains("--bounds sand.friction_deg") && err.contains("95"),
        "{err}"
    );
}

#[test]
fn calibrate_writes_a_loadable_fitted_scene_and_resumes_from_its_journal() {
    let dir = std::env::temp_dir().join(format!("powderlab-calib-cli-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let scene = common::test_scene_path("calibration_tiny.ron");
    let scene = scene.to_str().unwrap();
    let obs = dir.join("pile.png");
    let (code, err) = powderlab(&[
        "observe",
        scene,
        "--out",
        obs.to_str().unwrap(),
        "--set",
        "friction_deg=35",
        "--noise",
        "0.0005",
    ]);
    assert_eq!(code, 0, "{err}");
    let out = dir.join("run");
    let args = [
        "calibrate",
        scene,
        "--observed",
        obs.to_str().unwrap(),
        "--fit",
        "friction_deg",
        "--budget",
        "8",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ];
    let (code, err) = powderlab(&args);
    assert_eq!(code, 0, "{err}");
    for f in [
        "fitted.ron",
        "report.md",
        "loss.svg",
        "trace.csv",
        "summary.json",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    #[cfg(feature = "rerun")]
    common::assert_rrd_has(
        &out.join("calibration.rrd"),
        &["/world/powder/column", "/world/observed/0"],
    );
    let fitted = powderlab::scene::Scene::load(out.join("fitted.ron")).unwrap();
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let best = summary["best"]["values"][0].as_f64().unwrap();
    let p = params::parse(&fitted, &["friction_deg".into()], &[]).unwrap();
    assert_eq!(p[0].value(&fitted), best);
    // The same settings again: every rollout is read back from the journal, the same answer.
    // Without --quiet it prints its work estimate before it starts.
    let loud: Vec<&str> = args.iter().copied().filter(|a| *a != "--quiet").collect();
    let (code, err) = powderlab(&loud);
    assert_eq!(code, 0, "{err}");
    assert!(
        err.contains("work: a rollout") && err.contains("11 forward rollouts' worth in all"),
        "{err}"
    );
    let again: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(again["best"], summary["best"]);
    // The trace, then the curvature's 1 + 2k² forward rollouts (k = 1).
    assert_eq!(again["replayed"], again["rollouts"].as_u64().unwrap() + 3);
    // Other settings in the same folder are refused.
    let mut other = args.to_vec();
    other[7] = "12";
    let (code, err) = powderlab(&other);
    assert_eq!(code, 2);
    assert!(err.contains("other settings"), "{err}");
}

#[test]
fn one_layers_cloud_observed_apart_calibrates_that_layer() {
    // `observe --body` writes one body's particles; `calibrate --observed BODY=FILE@STEP` fits
    // against that body alone. The top layer is seen at 35°, its start is 25°.
    let dir = std::env::temp_dir().join(format!("powderlab-calib-body-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let scene = common::test_scene_path("calibration_layers_tiny.ron");
    let scene = scene.to_str().unwrap();
    let obs = dir.join("top.ply");
    let (code, err) = powderlab(&[
        "observe",
        scene,
        "--body",
        "bed1",
        "--step",
        "40",
        "--out",
        obs.to_str().unwrap(),
        "--set",
        "layer1.friction_deg=35",
    ]);
    assert_eq!(code, 0, "{err}");
    let n = match powderlab::lab::calibrate::observation::read(&obs).unwrap() {
        powderlab::lab::calibrate::observation::Observation::Cloud(p) => p.len(),
        _ => panic!("a cloud"),
    };
    let scene_ = powderlab::scene::Scene::load(scene).unwrap();
    let mut sim = powderlab::sim::Simulation::new(&scene_, &Default::default()).unwrap();
    assert_eq!(n, sim.body_states()[1].x.len(), "only bed1's particles");
    let out = dir.join("run");
    let (code, err) = powderlab(&[
        "calibrate",
        scene,
        "--observed",
        &format!("bed1={}@40", obs.display()),
        "--fit",
        "layer1.friction_deg",
        "--start",
        "layer1.friction_deg=25",
        "--method",
        "bfgs",
        "--budget",
        "20",
        "--no-curvature",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let best = summary["best"]["values"][0].as_f64().unwrap();
    assert!((best - 35.0).abs() < 1.0, "fitted {best} for a true 35");
    // A height map cannot be of one body.
    let (code, err) = powderlab(&[
        "observe",
        scene,
        "--body",
        "bed1",
        "--out",
        dir.join("top.csv").to_str().unwrap(),
    ]);
    assert_eq!(code, 2);
    assert!(err.contains("--body bed1") && err.contains(".ply"), "{err}");
}
