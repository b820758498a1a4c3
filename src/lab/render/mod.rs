//! Pictures of a run: RGB frames from pinhole cameras ([`camera`]), encoded as PNG.
//!
//! - **Powder** is drawn as shaded sphere splats, one per particle, nearest first by a depth
//!   buffer filled in particle order.
//! - **Tools** are opaque: each pixel's ray is sphere-traced against the tool's SDF in its local
//!   frame, inside the shape's bounding sphere, and lit by its SDF gradient.
//! - **Containers** are glass: the ray's first two crossings of the wall (its near outer face
//!   and the inner face behind) are blended over what lies behind, so the powder in a cup shows.
//! - **The floor** is a checkerboard of 1 cm squares at the height the powder rests on.
//!
//! Lambert shading with one directional light and an ambient term. Every pixel is computed on
//! its own in f64 and quantised by rounding, and the PNG encoder is deterministic, so a frame's
//! bytes depend only on the state and the camera, not on the thread count.

pub mod camera;
pub mod silhouette;

pub use camera::Camera;

use crate::components::ColliderKind;
use crate::math::pose::Pose;
use crate::math::sdf::Shape;
use glam::DVec3;
use rayon::prelude::*;

/// What one frame shows.
pub struct View<'a> {
    /// Every collider: name, kind, shape and pose.
    pub colliders: &'a [(String, ColliderKind, Shape, Pose)],
    /// Particle positions, all bodies.
    pub particles: &'a [DVec3],
    /// Splat radius (m).
    pub radius: f64,
    /// The floor, drawn as a checkerboard: its height (m) and its x–z extent
    /// `(x_lo, z_lo, x_hi, z_hi)`; `None` draws none.
    pub floor: Option<(f64, [f64; 4])>,
    /// The tools' colour (linear RGB in 0–1): steel grey by default, a key colour for a
    /// demonstration whose spoon is segmented by colour.
    pub tool_colour: DVec3,
}

/// The tools' default colour.
pub const STEEL: DVec3 = DVec3::new(0.78, 0.79, 0.82);
/// What a pixel shows, nearest first (glass aside): [`NOTHING`], [`POWDER`], [`FLOOR`] or the
/// scene index of the tool.
pub const NOTHING: u8 = 255;
pub const POWDER: u8 = 254;
pub const FLOOR: u8 = 253;

/// A sphere-tracing hit counts within 10 µm of the surface: a hundredth of the thinnest wall
/// of the shipped scenes (1.5 mm) and far above the SDFs' round-off.
pub const HIT_EPS: f64 = 1e-5;
/// Sphere-tracing steps per ray and collider. A ray grazing a surface takes many short steps;
/// 256 of them reach past every shipped shape's bounding sphere.
pub const MAX_MARCH: usize = 256;

const SAND: DVec3 = DVec3::new(0.86, 0.74, 0.50);
const GLASS: DVec3 = DVec3::new(0.55, 0.70, 0.90);
const GLASS_ALPHA: f64 = 0.35;

fn light() -> DVec3 {
    DVec3::new(0.4, 1.0, 0.6).normalize()
}

/// Lambert with an ambient term; `n` is turned to face the viewer.
fn shade(base: DVec3, n: DVec3, ray: DVec3) -> DVec3 {
    let n = if n.dot(ray) > 0.0 { -n } else { n };
    base * (0.3 + 0.7 * n.dot(light()).max(0.0))
}

/// Up to `max_hits` crossings of the surface of `shape` (at `pose`) by the ray `eye + t·d`,
/// `t < t_max`, nearest first: `(t, world normal)`.
pub fn march(
    shape: &Shape,
    pose: &Pose,
    eye: DVec3,
    d: DVec3,
    t_max: f64,
    max_hits: usize,
) -> Vec<(f64, DVec3)> {
    let r = shape.bounding_radius();
    if !r.is_finite() {
        return Vec::new();
    }
    let o = pose.to_local(eye);
    let dl = pose.rotation.inverse() * d;
    // The bounding sphere's span along the ray.
    let b = o.dot(dl);
    let disc = b * b - (o.length_squared() - r * r);
    if disc < 0.0 {
        return Vec::new();
    }
    let (mut t, t1) = ((-b - disc.sqrt()).max(0.0), (-b + disc.sqrt()).min(t_max));
    let mut hits = Vec::new();
    let mut steps = 0;
    while t < t1 && hits.len() < max_hits && steps < MAX_MARCH {
        steps += 1;
        let (s, g) = shape.sdf(o + t * dl);
        if s < HIT_EPS {
            hits.push((t, (pose.rotation * g).normalize_or_zero()));
            // Through the wall: step until outside again.
            t += 2.0 * HIT_EPS;
            while t < t1 && steps < MAX_MARCH {
                steps += 1;
                let (s, _) = shape.sdf(o + t * dl);
                if s > HIT_EPS {
                    break;
                }
                t += (-s).max(HIT_EPS);
            }
        } else {
            t += 0.95 * s;
        }
    }
    hits
}

/// Per pixel: the nearest splat's ray distance and world normal (`t = ∞` where none).
fn splat(cam: &Camera, view: &View) -> (Vec<f64>, Vec<DVec3>) {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let mut depth = vec![f64::INFINITY; w * h];
    let mut normal = vec![DVec3::ZERO; w * h];
    let r = view.radius;
    for &x in view.particles {
        let c = cam.to_camera(x);
        if c.z <= r {
            continue;
        }
        let (pu, pv) = cam.project(c);
        let (ru, rv) = (cam.fx * r / c.z, cam.fy * r / c.z);
        let u0 = (pu - ru).floor().max(0.0) as usize;
        let v0 = (pv - rv).floor().max(0.0) as usize;
        let u1 = ((pu + ru).ceil().max(0.0) as usize).min(w);
        let v1 = ((pv + rv).ceil().max(0.0) as usize).min(h);
        let dist = (x - cam.position).length();
        for v in v0..v1 {
            for u in u0..u1 {
                let dx = (u as f64 + 0.5 - pu) / ru;
                let dy = (v as f64 + 0.5 - pv) / rv;
                let q = dx * dx + dy * dy;
                if q >= 1.0 {
                    continue;
                }
                let hz = (1.0 - q).sqrt();
                let t = dist - r * hz;
                let k = v * w + u;
                if t < depth[k] {
                    depth[k] = t;
                    normal[k] = cam.rotation * DVec3::new(dx, dy, -hz);
                }
            }
        }
    }
    (depth, normal)
}

/// Renders one frame: RGB8, row-major, `width × height × 3` bytes.
pub fn render(cam: &Camera, view: &View) -> Vec<u8> {
    render_layers(cam, view).0
}

/// [`render`], with what each pixel shows (row-major): the mask of a tool is the pixels that
/// show its index.
pub fn render_layers(cam: &Camera, view: &View) -> (Vec<u8>, Vec<u8>) {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let (depth, normal) = splat(cam, view);
    let eye = cam.position;
    let rows: Vec<(Vec<u8>, Vec<u8>)> = (0..h)
        .into_par_iter()
        .map(|v| {
            let mut row = Vec::with_capacity(3 * w);
            let mut ids = Vec::with_capacity(w);
            for u in 0..w {
                let mut id = NOTHING;
                let d = cam.ray(u as u32, v as u32);
                let k = v * w + u;
                // Sky: a vertical gradient.
                let s = v as f64 / h.max(1) as f64;
                let mut col = DVec3::new(0.93, 0.95, 0.98).lerp(DVec3::new(0.80, 0.85, 0.92), s);
                let mut t_opaque = f64::INFINITY;
                if depth[k].is_finite() {
                    t_opaque = depth[k];
                    col = shade(SAND, normal[k], d);
                    id = POWDER;
                }
                if let Some((y, [x0, z0, x1, z1])) = view.floor {
                    if d.y < 0.0 {
                        let t = (y - eye.y) / d.y;
                        let p = eye + t * d;
                        if t > 0.0
                            && t < t_opaque
                            && (x0..=x1).contains(&p.x)
                            && (z0..=z1).contains(&p.z)
                        {
                            let odd = ((p.x / 0.01).floor() as i64 + (p.z / 0.01).floor() as i64)
                                .rem_euclid(2)
                                == 1;
                            let base = if odd {
                                DVec3::splat(0.70)
                            } else {
                                DVec3::splat(0.82)
                            };
                            t_opaque = t;
                            col = shade(base, DVec3::Y, d);
                            id = FLOOR;
                        }
                    }
                }
                for (i, (_, kind, shape, pose)) in view.colliders.iter().enumerate() {
                    if *kind == ColliderKind::Tool {
                        if let Some(&(t, n)) = march(shape, pose, eye, d, t_opaque, 1).first() {
                            t_opaque = t;
                            col = shade(view.tool_colour, n, d);
                            id = i.min(FLOOR as usize - 1) as u8;
                        }
                    }
                }
                let mut glass: Vec<(f64, DVec3)> = view
                    .colliders
                    .iter()
                    .filter(|c| c.1 == ColliderKind::Container)
                    .flat_map(|(_, _, shape, pose)| march(shape, pose, eye, d, t_opaque, 2))
                    .collect();
                // Far to near, each layer over what lies behind it.
                glass.sort_by(|a, b| b.0.total_cmp(&a.0));
                for (_, n) in glass {
                    col = col.lerp(shade(GLASS, n, d), GLASS_ALPHA);
                }
                row.extend(
                    col.to_array()
                        .map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8),
                );
                ids.push(id);
            }
            (row, ids)
        })
        .collect();
    let (rgb, ids): (Vec<Vec<u8>>, Vec<Vec<u8>>) = rows.into_iter().unzip();
    (rgb.concat(), ids.concat())
}

/// PNG bytes of an RGB8 image (the encoder's output depends only on the pixels).
pub fn encode_png(width: u32, height: u32, rgb: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, width, height);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut writer = enc.write_header().expect("writing to memory");
        writer.write_image_data(rgb).expect("writing to memory");
    }
    out
}

/// The splat radius of a scene's particles: the scene's `record.point_radius`, or half the
/// finest particle spacing.
pub fn particle_radius(scene: &crate::scene::Scene) -> f64 {
    scene
        .record
        .as_ref()
        .and_then(|r| r.point_radius)
        .unwrap_or_else(|| {
            0.5 * scene
                .bodies
                .iter()
                .map(|b| scene.particle_spacing(b))
                .fold(scene.simulation.dx, f64::min)
        })
}

/// The floor of a scene: the height the powder rests on, over the domain's x–z extent.
pub fn floor(scene: &crate::scene::Scene) -> (f64, [f64; 4]) {
    let (lo, hi) = scene.domain();
    (scene.floor_height(), [lo.x, lo.z, hi.x, hi.z])
}

/// Renders the simulation's current state from each camera: `(camera name, PNG bytes)`.
pub fn frames(sim: &mut crate::sim::Simulation, cameras: &[Camera]) -> Vec<(String, Vec<u8>)> {
    let colliders = sim.collider_poses();
    let particles: Vec<DVec3> = sim.body_states().into_iter().flat_map(|b| b.x).collect();
    let view = View {
        colliders: &colliders,
        particles: &particles,
        radius: particle_radius(&sim.scene),
        floor: Some(floor(&sim.scene)),
        tool_colour: STEEL,
    };
    cameras
        .iter()
        .map(|c| {
            (
                c.name.clone(),
                encode_png(c.width, c.height, &render(c, &view)),
            )
        })
        .collect()
}

/// The default camera of a scene: [`Camera::framing`] of the box of its particles and its
/// containers (the tools move about them).
pub fn default_camera(sim: &mut crate::sim::Simulation, width: u32, height: u32) -> Camera {
    let (lo, hi) = scene_box(sim);
    Camera::framing("default", lo, hi, width, height)
}

/// The box of a simulation's particles and containers (the domain where it has neither).
pub fn scene_box(sim: &mut crate::sim::Simulation) -> (DVec3, DVec3) {
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    for b in sim.body_states() {
        for x in b.x {
            lo = lo.min(x);
            hi = hi.max(x);
        }
    }
    for (_, kind, shape, pose) in sim.collider_poses() {
        let r = shape.bounding_radius();
        if r.is_finite() && kind == ColliderKind::Container {
            lo = lo.min(pose.translation - DVec3::splat(r));
            hi = hi.max(pose.translation + DVec3::splat(r));
        }
    }
    if !(lo.is_finite() && hi.is_finite()) {
        return sim.scene.domain();
    }
    (lo, hi)
}
