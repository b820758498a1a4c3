//! `powderlab demo make` films a demonstration (with a demonstrator's spoon of its own) that
//! `demo fit` reads back and fits, writing the fit and a recording of the track; `optimize
//! --init` takes the fit; a malformed demonstration folder or init file gets one line naming
//! the file and the field, and exit 2.

#![cfg(all(feature = "lab", feature = "rerun"))]

use std::path::Path;
use std::process::Command;

mod common;

/// The demonstrated skill parameters, as `demo make --theta` takes them.
const THETA: [f64; 5] = [0.4, -0.3, 0.5, -0.6, 0.2];

fn powderlab() -> Command {
    Command::new(env!("CARGO_BIN_EXE_powderlab"))
}

fn temp(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("powderlab_{name}_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

#[test]
fn a_made_demonstration_is_fitted_back() {
    let dir = temp("demo");
    let out = powderlab()
        .args(["demo", "make", "tests/scenes/tiny_transport.ron"])
        .args([
            "--theta",
            &THETA.map(|t| t.to_string()).join(","),
            "--size",
            "64x48",
            "--every",
            "10",
            // The demonstrator's spoon: the scene's is 11, 7 and 30 mm.
            "--spoon",
            "0.012,0.0065,0.034",
        ])
        .arg("--out")
        .arg(&dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let demo = powderlab::lab::demo::format::load(&dir).unwrap();
    assert_eq!(demo.cameras.len(), 2);
    let index: Vec<usize> = demo.frames.iter().map(|f| f.0).collect();
    let (last, before) = index.split_last().unwrap();
    assert!(
        before.iter().enumerate().all(|(k, &i)| i == 10 * k),
        "{index:?}"
    );
    assert!(*last > 100 && before.len() >= 10, "{index:?}");
    // The spoon is seen in every frame, and powder is marked unknown in some.
    for (_, views) in &demo.frames {
        assert!(views.iter().any(|m| m.contains(&1.0)));
    }
    assert!(demo
        .frames
        .iter()
        .flat_map(|f| &f.1)
        .any(|m| m.iter().any(|v| v.is_nan())));
    let out = powderlab()
        .args(["demo", "fit"])
        .arg(&dir)
        .args(["--scene", "tests/scenes/tiny_transport.ron"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let fit: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("fit.json")).unwrap()).unwrap();
    let theta: Vec<f64> = serde_json::from_value(fit["theta"].clone()).unwrap();
    assert_eq!(theta.len(), 5);
    // Θ's accuracy, in the units the cameras see: the three lengths (scoop depth, lift height,
    // transport distance) within a pixel, about 2.5 mm at the spoon, and the two angles within
    // the angle a pixel subtends at the bowl's rim (2.5 mm over its 11 mm radius, 13°). Many
    // frames of one skill should pin it at least as well as one frame pins the pose.
    let scene =
        powderlab::scene::Scene::load(common::test_scene_path("tiny_transport.ron")).unwrap();
    let spoon = &scene.colliders[powderlab::rollout::skill_tool(&scene).unwrap()];
    let Some(powderlab::scene::ControlSpec::Skill(sk)) = &spoon.control else {
        unreachable!("skill_tool finds the skill-driven tool")
    };
    let powderlab::math::sdf::Shape::Spoon { bowl_radius, .. } = spoon.shape else {
        panic!("the tiny scene's tool is a spoon")
    };
    let r = &sk.ranges;
    let truth = THETA;
    let span = [
        r.scoop_depth,
        r.scoop_angle_deg,
        r.lift_height,
        r.transport_distance,
        r.pour_angle_deg,
    ];
    const PIXEL_M: f64 = 0.0025;
    let pixel_deg = (PIXEL_M / bowl_radius).atan().to_degrees();
    for k in 0..5 {
        // value = min + (θ + 1)/2·(max − min)
        let error = (theta[k] - truth[k]).abs() / 2.0 * (span[k].1 - span[k].0);
        let bound = if k == 1 || k == 4 { pixel_deg } else { PIXEL_M };
        assert!(
            error <= bound,
            "Θ[{k}] = {} against {}: {error} above {bound} (m or degrees)",
            theta[k],
            truth[k]
        );
    }
    // 64×48 pixels of about 2.5 mm at the spoon: the median pose within a pixel.
    let median_mm = fit["score"]["pose_mm"][0].as_f64().unwrap();
    assert!(median_mm < 2.5, "median pose error {median_mm} mm");
    // The shape fit brings the handle, 4 mm longer than the scene's (more than a pixel), to
    // within a pixel's 2.5 mm; the joint fit lowers the silhouette loss.
    let handle = fit["spoon"]["handle_length"].as_f64().unwrap();
    assert!((handle - 0.034).abs() < 0.0025, "handle {handle} m");
    let losses: Vec<f64> =
        serde_json::from_value(fit["silhouette_loss_tracked_then_joint"].clone()).unwrap();
    assert!(losses[1] < losses[0], "{losses:?}");
    // The recording of the track over the frames opens in the official Rerun CLI.
    let rrd = dir.join("fit.rrd");
    common::assert_rrd_has(
        &rrd,
        &[
            "/world/cameras/front/image",
            "/world/cameras/front/track",
            "/world/cameras/side/track",
            "/world/tracked_spoon",
        ],
    );
    // `optimize --init` reads Θ_demo from the fit; a file without a valid Θ is one line naming
    // it and the field, exit 2.
    std::fs::write(dir.join("bad.json"), r#"{"theta": [0.1, 2.0, 0, 0, 0]}"#).unwrap();
    let out = powderlab()
        .args(["optimize", "tests/scenes/tiny_transport.ron", "--init"])
        .arg(dir.join("bad.json"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.json: theta = [0.1,2.0,0,0,0]"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    // With the fit, every seed's first rollout is Θ_demo.
    let out = powderlab()
        .args(["optimize", "tests/scenes/tiny_transport.ron", "--init"])
        .arg(dir.join("fit.json"))
        .args([
            "--method", "random", "--epochs", "1", "--seeds", "2", "--json", "--out",
        ])
        .arg(dir.join("opt"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let summary: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let seeds = summary["methods"]["random"]["seeds"].as_array().unwrap();
    assert_eq!(seeds.len(), 2);
    for s in seeds {
        let t: Vec<f64> = serde_json::from_value(s["theta_init"].clone()).unwrap();
        assert_eq!(t, theta, "seed {}", s["seed"]);
    }
}

#[test]
fn a_malformed_demonstration_is_one_line_naming_the_file_and_field() {
    let dir = temp("bad_demo");
    std::fs::create_dir_all(&dir).unwrap();
    let camera = r#"{"name": "front", "width": 4, "height": 3, "fx": 4, "fy": 4, "position": [0, 0.1, 0.3], "look_at": [0, 0, 0]}"#;
    let frame = r#"{"index": 0, "images": {"front": "f.png"}}"#;
    let png = powderlab::lab::render::encode_png(4, 3, &[0; 36]);
    std::fs::write(dir.join("f.png"), &png).unwrap();
    std::fs::write(
        dir.join("small.png"),
        powderlab::lab::render::encode_png(2, 2, &[0; 12]),
    )
    .unwrap();
    let cases = [
        (
            format!(r#"{{"fps": 0, "cameras": [{camera}], "frames": [{frame}]}}"#),
            "field `fps`",
        ),
        (
            format!(r#"{{"fps": 100, "cameras": [{camera}], "frames": []}}"#),
            "field `frames`",
        ),
        (
            format!(r#"{{"fps": 100, "cameras": [{camera}], "frames": [{frame}]}}"#),
            "field `frames[0].masks.front`",
        ),
        (
            format!(
                r#"{{"fps": 100, "cameras": [{camera}], "key_colour": [200, 50, 50], "frames": [{{"index": 0, "images": {{"front": "small.png"}}}}]}}"#
            ),
            "field `frames[0].images.front`: small.png is 2×2",
        ),
        (
            format!(
                r#"{{"fps": 100, "cameras": [{camera}], "frames": [{{"index": 0, "images": {{"front": "none.png"}}}}], "key_colour": [1, 2, 3]}}"#
            ),
            "none.png: cannot read it",
        ),
        (
            format!(r#"{{"fps": 100, "camera": [{camera}]}}"#),
            "unknown field `camera`",
        ),
    ];
    for (text, expected) in &cases {
        std::fs::write(dir.join("demo.json"), text).unwrap();
        let e = powderlab::lab::demo::format::load(&dir).err().unwrap();
        let json = dir.join("demo.json");
        assert!(e.starts_with(&json.display().to_string()), "{e}");
        assert!(e.contains(expected), "{e}");
        assert!(!e.contains('\n'), "{e}");
    }
    let out = powderlab()
        .args(["demo", "fit"])
        .arg(&dir)
        .args(["--scene", "tests/scenes/tiny_transport.ron"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("demo.json"));
    assert!(!Path::new(&dir.join("fit.json")).exists());
}
