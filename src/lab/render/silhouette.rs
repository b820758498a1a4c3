//! A differentiable silhouette of a spoon (seed B's eqs. 1–4 for an SDF): each pixel's soft
//! occupancy is `o = σ(−m/τ)`, with `m` the smallest SDF value along the pixel's ray and `τ`
//! a temperature in metres.
//!
//! **The minimum.** Along a ray the SDF is 1-Lipschitz; `m` is found by sampling the ray's
//! chord of the spoon's bounding sphere ([`RAY_SAMPLES`] points) and refining the best bracket
//! by golden-section search ([`GOLDEN_STEPS`]). Rays that pass farther than [`REACH_TAUS`]·τ
//! outside the bounding sphere have `o = 0` (below `σ(−20)` = 2e-9) and no gradient.
//!
//! **The gradient.** At the minimiser `t*`, `∂m/∂θ = ∂φ/∂θ` at the point `x(t*)` (the envelope
//! theorem: `∂φ/∂t = 0` there), so the adjoint needs the SDF's gradient in space and in the
//! shape parameters ([`Spoon::sdf_dshape`]) at one point per pixel. With the pose as a world
//! translation `T` and a world rotation vector `ω` (`R ← exp(ω)·R`), and `y = x − T`:
//! `∂φ/∂T = −∇φ`, `∂φ/∂ω = ∇φ × y` (world-frame gradient). A ray through the bowl's shell
//! crosses its mid-surface, where `φ = |‖p‖ − r| − t/2` has a kink: there `m = −t/2` exactly
//! and does not depend on the pose or the three shape parameters.
//!
//! **The bias.** `σ(−m/τ)` is ½ on the surface, so the soft silhouette's edge sits on the
//! true one, but it spreads about τ to both sides, and a part thinner than a few τ (the shell
//! seen edge-on, at `m = −t/2`) never reaches full occupancy: at τ = t/2 it is σ(1) = 0.73.
//! Fitting starts at a τ of a few pixels' footprint, so the loss sees a misplaced spoon from
//! afar, and halves τ to a fraction of a pixel, where the silhouette is sharp (docs/design.md).

use super::Camera;
use crate::math::pose::{quat_from_rotation_vector, Pose};
use crate::math::sdf::Spoon;
use glam::DVec3;
use rayon::prelude::*;

/// Samples along each ray's chord of the bounding sphere before refining: at the shipped
/// spoons' sizes (bounding radius ≤ 0.15 m) they lie ≤ 2.5 mm apart, closer than a bowl's
/// shell crossed obliquely is wide, so the bracket holds the global minimum.
pub const RAY_SAMPLES: usize = 128;
/// Golden-section steps in the bracket: 0.618⁶⁰ ≈ 3e-13 of it, below f64 round-off of `t`.
pub const GOLDEN_STEPS: usize = 60;
/// Rays farther than this many τ outside the bounding sphere are empty (σ(−20) = 2e-9).
pub const REACH_TAUS: f64 = 20.0;

/// The silhouette's parameters: the pose's world translation (3) and rotation vector (3),
/// then the spoon's bowl radius, bowl depth and handle length.
pub const PARAMS: [&str; 9] = [
    "x",
    "y",
    "z",
    "rx",
    "ry",
    "rz",
    "bowl_radius",
    "bowl_depth",
    "handle_length",
];

/// A pixel's smallest SDF value along its ray and its derivatives in [`PARAMS`] order.
pub type RayMin = (f64, [f64; 9]);

/// The smallest SDF value of `spoon` (at `pose`) along the ray `eye + t·d` (unit `d`), with
/// its derivatives; `None` when the ray passes farther than `reach` outside the bounding
/// sphere.
pub fn ray_min(spoon: &Spoon, pose: &Pose, eye: DVec3, d: DVec3, reach: f64) -> Option<RayMin> {
    let r = spoon.bounding_radius() + reach;
    let o = pose.to_local(eye);
    let dl = pose.rotation.inverse() * d;
    let b = o.dot(dl);
    let disc = b * b - (o.length_squared() - r * r);
    if disc < 0.0 {
        return None;
    }
    let (t0, t1) = ((-b - disc.sqrt()).max(0.0), -b + disc.sqrt());
    if t1 <= t0 {
        return None;
    }
    let phi = |t: f64| spoon.sdf(o + t * dl).0;
    let step = (t1 - t0) / RAY_SAMPLES as f64;
    let mut best = (f64::INFINITY, 0);
    for k in 0..RAY_SAMPLES {
        let v = phi(t0 + (k as f64 + 0.5) * step);
        if v < best.0 {
            best = (v, k);
        }
    }
    let (mut lo, mut hi) = (
        t0 + best.1 as f64 * step - 0.5 * step,
        t0 + best.1 as f64 * step + 1.5 * step,
    );
    lo = lo.max(t0);
    hi = hi.min(t1);
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let (mut a, mut c) = (hi - g * (hi - lo), lo + g * (hi - lo));
    let (mut fa, mut fc) = (phi(a), phi(c));
    for _ in 0..GOLDEN_STEPS {
        if fa < fc {
            hi = c;
            (c, fc) = (a, fa);
            a = hi - g * (hi - lo);
            fa = phi(a);
        } else {
            lo = a;
            (a, fa) = (c, fc);
            c = lo + g * (hi - lo);
            fc = phi(c);
        }
    }
    let t = if fa < fc { a } else { c };
    let p = o + t * dl;
    let s = spoon.sdf_dshape(p);
    if s.shell_interior {
        return Some((-0.5 * spoon.thickness, [0.0; 9]));
    }
    let gw = pose.rotation * s.grad;
    let y = pose.rotation * p;
    let gr = gw.cross(y);
    Some((
        s.phi,
        [
            -gw.x,
            -gw.y,
            -gw.z,
            gr.x,
            gr.y,
            gr.z,
            s.dshape[0],
            s.dshape[1],
            s.dshape[2],
        ],
    ))
}

/// The logistic function.
#[inline]
pub fn sigmoid(x: f64) -> f64 {
    if x >= 0.0 {
        1.0 / (1.0 + (-x).exp())
    } else {
        let e = x.exp();
        e / (1.0 + e)
    }
}

/// A soft silhouette: per pixel (row-major) its occupancy and, where the ray comes near the
/// spoon, `m` and `∂m/∂θ`.
#[derive(Clone, Debug)]
pub struct Silhouette {
    pub tau: f64,
    pub occupancy: Vec<f64>,
    pub rays: Vec<Option<RayMin>>,
}

/// The soft silhouette of `spoon` at `pose` seen by `cam` with temperature `tau` (m).
pub fn silhouette(cam: &Camera, spoon: &Spoon, pose: &Pose, tau: f64) -> Silhouette {
    let (w, h) = (cam.width, cam.height);
    let rays: Vec<Option<RayMin>> = (0..w * h)
        .into_par_iter()
        .map(|k| {
            let d = cam.ray(k % w, k / w);
            ray_min(spoon, pose, cam.position, d, REACH_TAUS * tau)
        })
        .collect();
    let occupancy = rays
        .iter()
        .map(|r| r.map_or(0.0, |(m, _)| sigmoid(-m / tau)))
        .collect();
    Silhouette {
        tau,
        occupancy,
        rays,
    }
}

/// The adjoint of [`silhouette`]: `Σ_pixels g_i·∂o_i/∂θ` in [`PARAMS`] order, for the
/// occupancy adjoint `g` (e.g. `2(o − mask)` for a squared error).
pub fn silhouette_adj(s: &Silhouette, g: &[f64]) -> [f64; 9] {
    let mut out = [0.0; 9];
    for ((o, ray), gi) in s.occupancy.iter().zip(&s.rays).zip(g) {
        if let Some((_, dm)) = ray {
            // ∂σ(−m/τ)/∂m = −o(1 − o)/τ.
            let w = gi * -o * (1.0 - o) / s.tau;
            for k in 0..9 {
                out[k] += w * dm[k];
            }
        }
    }
    out
}

/// The pose moved by a world translation `dt` and a world rotation vector `dr` (the
/// parameterisation of [`PARAMS`]).
pub fn perturbed(pose: &Pose, dt: DVec3, dr: DVec3) -> Pose {
    Pose {
        translation: pose.translation + dt,
        rotation: (quat_from_rotation_vector(dr) * pose.rotation).normalize(),
    }
}

/// The spoon with its bowl radius, bowl depth and handle length moved by `d`.
pub fn reshaped(spoon: &Spoon, d: [f64; 3]) -> Spoon {
    Spoon {
        bowl_radius: spoon.bowl_radius + d[0],
        bowl_depth: spoon.bowl_depth + d[1],
        handle_length: spoon.handle_length + d[2],
        ..*spoon
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::lab::render::camera::CameraSpec;

    /// The tiny scene's spoon.
    pub(crate) fn spoon() -> Spoon {
        Spoon {
            bowl_radius: 0.011,
            bowl_depth: 0.007,
            thickness: 0.0015,
            handle_length: 0.03,
            handle_radius: 0.0025,
            handle_rise: 0.05,
        }
    }

    fn camera(w: u32, h: u32) -> Camera {
        Camera::from_spec(&CameraSpec {
            name: "test".into(),
            width: w,
            height: h,
            fx: 1.1 * w as f64,
            fy: 1.1 * w as f64,
            cx: None,
            cy: None,
            position: [0.05, 0.09, 0.11],
            look_at: Some([0.0, 0.02, 0.0]),
            up: None,
            rotation: None,
        })
        .unwrap()
    }

    fn pose() -> Pose {
        Pose {
            translation: DVec3::new(0.002, 0.0, -0.001),
            rotation: quat_from_rotation_vector(DVec3::new(0.3, -1.2, 0.2)),
        }
    }

    /// Central differences of a smooth loss in f64 at ε = 1e-7 (m, rad): the adjoint agrees
    /// to 1e-5 of the largest component where no pixel's minimiser jumps between branches.
    const ADJ_TOL: f64 = 1e-5;

    #[test]
    fn adjoint_matches_central_differences() {
        let cam = camera(40, 30);
        let tau = 0.0008;
        let base = silhouette(&cam, &spoon(), &pose(), tau);
        assert!(base.occupancy.iter().filter(|&&o| o > 0.5).count() > 20);
        // A weighted sum with weights that change sign.
        let weights: Vec<f64> = (0..base.occupancy.len())
            .map(|k| ((k * 7919) % 13) as f64 / 6.0 - 1.0)
            .collect();
        let loss =
            |s: &Silhouette| -> f64 { s.occupancy.iter().zip(&weights).map(|(o, w)| o * w).sum() };
        let adj = silhouette_adj(&base, &weights);
        let eps = 1e-7;
        let scale = adj.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for k in 0..9 {
            let at = |e: f64| {
                let mut v = [0.0; 9];
                v[k] = e;
                let p = perturbed(
                    &pose(),
                    DVec3::new(v[0], v[1], v[2]),
                    DVec3::new(v[3], v[4], v[5]),
                );
                loss(&silhouette(
                    &cam,
                    &reshaped(&spoon(), [v[6], v[7], v[8]]),
                    &p,
                    tau,
                ))
            };
            let fd = (at(eps) - at(-eps)) / (2.0 * eps);
            assert!(
                (fd - adj[k]).abs() <= ADJ_TOL * scale,
                "{}: adjoint {} against central difference {fd}",
                PARAMS[k],
                adj[k]
            );
        }
    }

    #[test]
    fn occupancy_is_a_half_on_the_edge_and_zero_far_away() {
        let s = spoon();
        let p = Pose::default();
        // A ray grazing the bowl's bottom at distance 0 and one passing 5 mm below it.
        let eye = DVec3::new(-0.2, -0.011, 0.0);
        let (m, _) = ray_min(&s, &p, eye, DVec3::X, 0.01).unwrap();
        assert!(m.abs() < 0.5 * s.thickness + 1e-9, "{m}");
        let (m, _) = ray_min(&s, &p, eye - DVec3::new(0.0, 0.005, 0.0), DVec3::X, 0.01).unwrap();
        assert!((m - (0.005 - 0.5 * s.thickness)).abs() < 1e-9, "{m}");
        assert!(ray_min(&s, &p, DVec3::new(0.0, 1.0, 0.0), DVec3::X, 0.01).is_none());
    }
}
