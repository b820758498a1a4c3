//! Synthetic demonstrations (`powderlab demo make`): a hand scoops with the scene's spoon along
//! the skill's path at Θ*, but not as g(Θ*) would: with its own timing (a smooth warp of the
//! pace) and a small tremor. The powder moves under the hand's spoon (the scene run with the
//! hand's per-step displacements), and the cameras film it: PNG frames with the spoon in a key
//! colour, exact masks (unless asked not to; powder pixels are marked unknown there, since
//! powder may hide the spoon), optional pixel noise, and `truth.json` (Θ* and
//! the hand's pose in every frame) to score a fit against.

use super::format::{DemoSpec, FrameSpec};
use super::shape::dimensions;
use super::skill_fit::trajectory;
use super::spoon_map::{demonstrated_skill, transfer};
use crate::lab::render::{self, Camera, View};
use crate::math::pose::Pose;
use crate::math::sdf::{Shape, Spoon};
use crate::rollout::skill_tool;
use crate::scene::{ControlSpec, Scene};
use crate::sim::{SimOptions, Simulation};
use crate::skills::Theta;
use crate::util::{write_atomic, SplitMix64};
use glam::{DQuat, DVec3};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// The demonstration spoon's colour (sRGB 0–255): a red no other object has.
pub const KEY_COLOUR: [u8; 3] = [217, 64, 51];

/// How the demonstration is made.
#[derive(Clone, Debug)]
pub struct MakeOptions {
    pub theta: Theta,
    pub cameras: Vec<Camera>,
    /// A frame every this many global steps.
    pub every: usize,
    /// Amplitude of the hand's tremor (m); its rotation shakes by this over the spoon's
    /// bounding radius (rad).
    pub tremor: f64,
    /// The pace's warp, in [0, 1): the hand's progress along the path is
    /// `x − warp·sin(2πx)/2π` of its time `x` (slow at the ends, fast in the middle).
    pub warp: f64,
    /// Gaussian pixel noise (σ in 0–1 of the full scale) on the images, not on the masks.
    pub noise: f64,
    pub masks: bool,
    pub seed: u64,
    /// The demonstrator's spoon, when it is not the scene's: the hand carries the skill's
    /// motion over to it through the bowls' frames ([`spoon_map`](super::spoon_map)).
    pub spoon: Option<Spoon>,
}

/// What `truth.json` holds.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Truth {
    pub theta: Theta,
    /// The demonstrator's spoon: bowl radius, bowl depth, handle length (m).
    #[serde(default)]
    pub spoon: Option<[f64; 3]>,
    /// The hand's pose in each frame: translation (m) and quaternion `[x, y, z, w]`.
    pub poses: Vec<([f64; 3], [f64; 4])>,
}

/// The hand's pose at every global step: g(Θ*)'s poses, resampled at a warped pace, with a
/// tremor.
pub fn hand_motion(path: &[Pose], warp: f64, tremor: f64, lever: f64, seed: u64) -> Vec<Pose> {
    let n = path.len().saturating_sub(1);
    let mut rng = SplitMix64(seed);
    let phase: Vec<f64> = (0..6)
        .map(|_| rng.uniform() * std::f64::consts::TAU)
        .collect();
    let period = [7.3, 5.1, 6.7, 8.9, 4.3, 9.7];
    (0..=n)
        .map(|k| {
            let x = k as f64 / n.max(1) as f64;
            let s =
                (x - warp * (std::f64::consts::TAU * x).sin() / std::f64::consts::TAU) * n as f64;
            let (i, f) = (s.floor() as usize, s - s.floor());
            let (a, b) = (path[i.min(n)], path[(i + 1).min(n)]);
            let shake = |j: usize| (std::f64::consts::TAU * k as f64 / period[j] + phase[j]).sin();
            let dt = tremor * DVec3::new(shake(0), shake(1), shake(2));
            let dr = tremor / lever * DVec3::new(shake(3), shake(4), shake(5));
            // The tremor fades in and out, so the hand starts and ends where the path does.
            let fade = (std::f64::consts::PI * x).sin();
            Pose {
                translation: a.translation.lerp(b.translation, f) + fade * dt,
                rotation: (DQuat::from_scaled_axis(fade * dr) * a.rotation.slerp(b.rotation, f))
                    .normalize(),
            }
        })
        .collect()
}

/// The per-step displacements that take a tool through `poses`.
pub fn displacements(poses: &[Pose]) -> Vec<[f64; 6]> {
    poses
        .windows(2)
        .map(|w| {
            let t = w[1].translation - w[0].translation;
            let r = (w[1].rotation * w[0].rotation.inverse()).to_scaled_axis();
            [t.x, t.y, t.z, r.x, r.y, r.z]
        })
        .collect()
}

/// Makes a demonstration of `scene`'s skill tool in `dir`; `progress` is called after each
/// step with the steps done and the total.
pub fn make(
    scene: &Scene,
    opts: &MakeOptions,
    dir: &Path,
    mut progress: impl FnMut(usize, usize),
) -> anyhow::Result<Truth> {
    let i = skill_tool(scene)?;
    let tool = &scene.colliders[i];
    let Some(ControlSpec::Skill(sk)) = &tool.control else {
        unreachable!("skill_tool found a Skill control")
    };
    let sk = crate::skills::SkillSpec {
        theta: opts.theta,
        ..sk.clone()
    };
    sk.validate()
        .map_err(|e| anyhow::anyhow!("--theta: {} = {} is not {}", e.field, e.value, e.expected))?;
    // The robot's spoon and the hand's: the skill's path is the robot's, carried over.
    let spoons = match (tool.shape.spoon(), opts.spoon) {
        (_, None) => None,
        (Some(robot), Some(hand)) => Some((robot, hand)),
        (None, Some(_)) => anyhow::bail!(
            "{}: colliders[{i}] ('{}') is a {}: a demonstrator's spoon replaces a spoon",
            scene.path.display(),
            tool.name,
            tool.shape.name()
        ),
    };
    let sk = match spoons {
        Some((robot, hand)) => demonstrated_skill(&sk, &robot, &hand),
        None => sk,
    };
    let dt = scene.simulation.dt;
    let (controls, _) = sk.controls(dt, Scene::tool_bottom(tool));
    let mut path = trajectory(&Scene::collider_pose(tool), &controls);
    let mut demo_scene = scene.clone();
    if let Some((robot, hand)) = spoons {
        path = path.iter().map(|p| transfer(p, &robot, &hand)).collect();
        let c = &mut demo_scene.colliders[i];
        c.shape = Shape::from_spoon(&hand);
        c.position = path[0].translation.into();
    }
    let lever = demo_scene.colliders[i].shape.bounding_radius();
    let hand = hand_motion(&path, opts.warp, opts.tremor, lever, opts.seed);
    demo_scene.colliders[i].control = Some(ControlSpec::Actions(displacements(&hand)));
    let mut sim = Simulation::new(&demo_scene, &SimOptions::default())?;
    let steps = hand.len() - 1;
    let key = DVec3::from_array(KEY_COLOUR.map(|c| c as f64 / 255.0));
    let mut rng = SplitMix64(opts.seed ^ 0x5EED);
    let mut frames = Vec::new();
    let mut truth = Truth {
        theta: opts.theta,
        spoon: spoons.map(|(_, hand)| dimensions(&hand)),
        poses: Vec::new(),
    };
    for k in 0..=steps {
        if k > 0 {
            sim.step()?;
            progress(k, steps);
        }
        if !(k.is_multiple_of(opts.every) || k == steps) {
            continue;
        }
        let colliders = sim.collider_poses();
        let particles: Vec<DVec3> = sim.body_states().into_iter().flat_map(|b| b.x).collect();
        let view = View {
            colliders: &colliders,
            particles: &particles,
            radius: render::particle_radius(scene),
            floor: Some(render::floor(scene)),
            tool_colour: key,
        };
        let mut frame = FrameSpec {
            index: k,
            images: BTreeMap::new(),
            masks: BTreeMap::new(),
        };
        for cam in &opts.cameras {
            let (mut rgb, ids) = render::render_layers(cam, &view);
            if opts.noise > 0.0 {
                for c in rgb.iter_mut() {
                    let v = *c as f64 + 255.0 * opts.noise * rng.normal();
                    *c = v.round().clamp(0.0, 255.0) as u8;
                }
            }
            let name = format!("{}_{k:05}.png", cam.name);
            write_atomic(
                &dir.join(&name),
                &render::encode_png(cam.width, cam.height, &rgb),
            )?;
            frame.images.insert(cam.name.clone(), name);
            if opts.masks {
                let mask: Vec<u8> = ids
                    .iter()
                    .flat_map(|&id| {
                        let v = match id {
                            _ if id as usize == i => 255,
                            // Powder in front of the spoon's place hides it: unknown.
                            render::POWDER => 128,
                            _ => 0,
                        };
                        [v, v, v]
                    })
                    .collect();
                let name = format!("{}_{k:05}_mask.png", cam.name);
                write_atomic(
                    &dir.join(&name),
                    &render::encode_png(cam.width, cam.height, &mask),
                )?;
                frame.masks.insert(cam.name.clone(), name);
            }
        }
        let p = colliders[i].3;
        truth
            .poses
            .push((p.translation.to_array(), p.rotation.to_array()));
        frames.push(frame);
    }
    let spec = DemoSpec {
        fps: 1.0 / dt,
        cameras: opts.cameras.iter().map(camera_spec).collect(),
        key_colour: Some(KEY_COLOUR),
        frames,
    };
    write_atomic(
        &dir.join("demo.json"),
        serde_json::to_string_pretty(&spec)?.as_bytes(),
    )?;
    write_atomic(
        &dir.join("truth.json"),
        serde_json::to_string_pretty(&truth)?.as_bytes(),
    )?;
    Ok(truth)
}

/// A camera as its file gives it (rotation as a quaternion).
pub fn camera_spec(c: &Camera) -> crate::lab::render::camera::CameraSpec {
    crate::lab::render::camera::CameraSpec {
        name: c.name.clone(),
        width: c.width,
        height: c.height,
        fx: c.fx,
        fy: c.fy,
        cx: Some(c.cx),
        cy: Some(c.cy),
        position: c.position.to_array(),
        look_at: None,
        up: None,
        rotation: Some(DQuat::from_mat3(&c.rotation).normalize().to_array()),
    }
}
