//! `powderlab render`: frames show the powder, the spoon and the cups where they are; a frame's
//! bytes do not depend on the thread count; a bad camera file is one line naming the file and
//! the field.

#![cfg(feature = "lab")]

mod common;

use glam::DVec3;
use powderlab::lab::render::{self, camera, Camera};
use std::process::Command;

fn pixel(rgb: &[u8], cam: &Camera, x: DVec3) -> [u8; 3] {
    let (u, v) = cam.project(cam.to_camera(x));
    let k = 3 * (v as usize * cam.width as usize + u as usize);
    [rgb[k], rgb[k + 1], rgb[k + 2]]
}

#[test]
fn frames_show_the_scene_and_do_not_depend_on_the_thread_count() {
    let scene = common::load_test_scene("tiny_transport.ron");
    let mut sim = common::build(&scene, 1);
    sim.run(20, |_| {}).unwrap();
    let cam = render::default_camera(&mut sim, 160, 120);
    let png = |threads: usize, sim: &mut powderlab::sim::Simulation| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| render::frames(sim, std::slice::from_ref(&cam)))
    };
    let one = png(1, &mut sim);
    let two = png(2, &mut sim);
    assert_eq!(one, two, "the same bytes at 1 and 2 threads");

    // What the picture shows, pixel by pixel, at the start: the spoon above the source cup.
    let mut sim = common::build(&scene, 1);
    let colliders = sim.collider_poses();
    let particles: Vec<DVec3> = sim.body_states().into_iter().flat_map(|b| b.x).collect();
    let mut view = render::View {
        colliders: &colliders,
        particles: &particles,
        radius: render::particle_radius(&scene),
        floor: None,
        tool_colour: render::STEEL,
    };
    let rgb = render::render(&cam, &view);
    assert_eq!(rgb.len(), 160 * 120 * 3);
    // The spoon's handle near its tip: steel grey (no colour cast).
    let spoon = colliders.iter().find(|c| c.0 == "spoon").unwrap();
    let tip = spoon.3.to_world(DVec3::new(0.011 + 0.03, 0.05, 0.0) * 0.95);
    let steel = pixel(&rgb, &cam, tip);
    let spread = steel.iter().max().unwrap() - steel.iter().min().unwrap();
    assert!(spread < 20, "spoon pixel {steel:?}");
    // The empty target cup's middle: glass over the sky, blue above red.
    let cup = colliders.iter().find(|c| c.0 == "target_cup").unwrap();
    let glass = pixel(&rgb, &cam, cup.3.to_world(DVec3::new(0.0, 0.02, 0.0)));
    assert!(
        glass[2] as i32 - glass[0] as i32 > 15,
        "glass pixel {glass:?}"
    );
    // The top-left corner: sky, lighter than anything lit.
    assert!(rgb[..3].iter().all(|&c| c > 200), "sky {:?}", &rgb[..3]);
    // Without the cups, the powder's top particle: sand, red above blue.
    let open: Vec<_> = colliders
        .iter()
        .filter(|c| c.0 == "spoon")
        .cloned()
        .collect();
    view.colliders = &open;
    let rgb = render::render(&cam, &view);
    let top = particles
        .iter()
        .copied()
        .max_by(|a, b| a.y.total_cmp(&b.y))
        .unwrap();
    let sand = pixel(&rgb, &cam, top);
    assert!(
        sand[0] as i32 - sand[2] as i32 > 40,
        "powder pixel {sand:?}"
    );
}

#[test]
fn a_bad_camera_file_is_one_line_naming_the_file_and_field() {
    let dir = std::env::temp_dir().join(format!("powderlab_cams_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cases = [
        (
            r#"{"cameras": [{"name": "front", "width": 0, "height": 48, "fx": 50, "fy": 50, "position": [0, 0.1, 0.3], "look_at": [0, 0, 0]}]}"#,
            "cameras['front'].width = 0",
        ),
        (
            r#"{"cameras": [{"name": "front", "width": 64, "height": 48, "fx": 50, "fy": 50, "position": [0, 0.1, 0.3]}]}"#,
            "cameras['front'].look_at",
        ),
        (
            r#"{"cameras": [{"name": "front", "width": 64, "height": 48, "fx": 50, "fy": 50, "position": [0, 0.1, 0.3], "rotation": [0, 0, 0, 2]}]}"#,
            "cameras['front'].rotation",
        ),
        (r#"{"cameras": [{"name": "front", "widht": 64}]}"#, ":1:"),
        (r#"{"cameras": []}"#, "field `cameras` is empty"),
    ];
    for (k, (text, expected)) in cases.iter().enumerate() {
        let path = dir.join(format!("cams{k}.json"));
        std::fs::write(&path, text).unwrap();
        let e = camera::load(&path).unwrap_err();
        assert!(e.starts_with(&path.display().to_string()), "{e}");
        assert!(e.contains(expected), "{e}");
        assert!(!e.contains('\n'), "{e}");
    }
    // Through the command: exit code 2 and the same line.
    let path = dir.join("cams0.json");
    let out = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .args(["render", "tests/scenes/tiny_transport.ron", "--cameras"])
        .arg(&path)
        .args(["--out"])
        .arg(dir.join("frames"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("cameras['front'].width = 0"), "{err}");
    assert!(
        !dir.join("frames").exists(),
        "nothing written before the checks"
    );
}

#[test]
fn the_command_writes_the_asked_frames_as_png() {
    let dir = std::env::temp_dir().join(format!("powderlab_render_{}", std::process::id()));
    let out = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .args([
            "render",
            "tests/scenes/tiny_transport.ron",
            "--at",
            "0,3",
            "--size",
            "64x48",
            "--out",
        ])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names, ["default_00000.png", "default_00003.png"]);
    let decoder = png::Decoder::new(std::io::BufReader::new(
        std::fs::File::open(dir.join("default_00003.png")).unwrap(),
    ));
    let reader = decoder.read_info().unwrap();
    assert_eq!((reader.info().width, reader.info().height), (64, 48));
    let bad = Command::new(env!("CARGO_BIN_EXE_powderlab"))
        .args([
            "render",
            "tests/scenes/tiny_transport.ron",
            "--size",
            "0x48",
        ])
        .output()
        .unwrap();
    assert_eq!(bad.status.code(), Some(2));
}
