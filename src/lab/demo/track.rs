//! Tracking the spoon's pose in one frame (seed B's pose step): Levenberg–Marquardt on the
//! squared difference between the soft silhouette and the frame's mask, over one or more
//! calibrated cameras, with τ annealed from a few pixels to a fraction of one.
//!
//! Each pixel's residual `o_i − mask_i` has the Jacobian row `∂o_i/∂θ` from the silhouette's
//! per-pixel derivatives ([`silhouette`](crate::lab::render::silhouette)), so the Gauss–Newton
//! matrix `JᵀJ` (6×6) comes from one rendering. Rotation is scaled by the spoon's bounding
//! radius so that the six parameters are all lengths. An optional prior pulls the pose towards
//! a given one (the previous frame's, for temporal smoothness).

use crate::lab::render::silhouette::{perturbed, silhouette, Silhouette};
use crate::lab::render::Camera;
use crate::math::eigen::symmetric_eigen;
use crate::math::pose::Pose;
use crate::math::sdf::Spoon;
use glam::DVec3;

/// One view of a frame: a camera and the spoon's mask in it (row-major, 0 to 1, NaN where
/// unknown: a pixel showing something that may hide the spoon, such as powder).
#[derive(Clone, Copy)]
pub struct View<'a> {
    pub camera: &'a Camera,
    pub mask: &'a [f64],
}

/// How the fit runs.
#[derive(Clone, Debug)]
pub struct TrackOptions {
    /// τ at the start and at the end, in pixels' footprint at the spoon's distance.
    pub tau_px: (f64, f64),
    /// Levenberg–Marquardt iterations at each τ (τ halves between levels).
    pub iterations: usize,
    /// Weight of the prior `‖θ − θ_prior‖²` (lengths in m, rotations scaled by the bounding
    /// radius), relative to one pixel's squared residual; 0 for none.
    pub prior_weight: f64,
}

impl Default for TrackOptions {
    fn default() -> Self {
        TrackOptions {
            tau_px: (1.0, 0.25),
            iterations: 25,
            prior_weight: 0.0,
        }
    }
}

/// What a fit gives.
#[derive(Clone, Debug)]
pub struct Track {
    pub pose: Pose,
    /// The silhouette loss `Σ (o − mask)²` over every view at the last τ.
    pub loss: f64,
    /// Levenberg–Marquardt steps taken and accepted.
    pub steps: usize,
}

/// The silhouette loss and its Gauss–Newton terms (JᵀJ, Jᵀr) in the six pose parameters.
fn gauss_newton(
    views: &[View],
    spoon: &Spoon,
    pose: &Pose,
    tau: &[f64],
    scale: f64,
) -> (f64, [[f64; 6]; 6], [f64; 6]) {
    let mut loss = 0.0;
    let mut jtj = [[0.0; 6]; 6];
    let mut jtr = [0.0; 6];
    for (v, &t) in views.iter().zip(tau) {
        let s: Silhouette = silhouette(v.camera, spoon, pose, t);
        for ((o, ray), m) in s.occupancy.iter().zip(&s.rays).zip(v.mask) {
            // An unknown pixel (the spoon may be hidden there) is no evidence either way.
            if m.is_nan() {
                continue;
            }
            let r = o - m;
            loss += r * r;
            if let Some((_, dm)) = ray {
                let f = -o * (1.0 - o) / t;
                let j: [f64; 6] =
                    std::array::from_fn(|k| f * dm[k] * if k >= 3 { 1.0 / scale } else { 1.0 });
                for a in 0..6 {
                    jtr[a] += j[a] * r;
                    for b in 0..6 {
                        jtj[a][b] += j[a] * j[b];
                    }
                }
            }
        }
    }
    (loss, jtj, jtr)
}

/// The τ schedule (pixels' footprint): from `start` halved down to `end`, `end` last.
pub fn tau_levels((start, end): (f64, f64)) -> Vec<f64> {
    let levels = (start / end).log2().ceil().max(0.0) as usize + 1;
    (0..levels)
        .map(|level| (start / 2f64.powi(level as i32)).max(end))
        .collect()
}

/// Each view's τ (m) for `px` pixels' footprint at the spoon's distance.
pub fn taus(views: &[View], pose: &Pose, px: f64) -> Vec<f64> {
    views
        .iter()
        .map(|v| px * (pose.translation - v.camera.position).length() / v.camera.fx)
        .collect()
}

/// Levenberg–Marquardt's damping and stopping, shared by the tracker and the shape fit: λ
/// starts at 1e-3, falls by 0.3 (to 1e-9) after an accepted step and rises tenfold after a
/// refused one; a level stops when an accepted step lowers the loss by less than a part in 10⁶
/// (converged) or λ passes 1e8 (no step lowers it).
pub struct Damping {
    pub lambda: f64,
}

impl Default for Damping {
    fn default() -> Damping {
        Damping { lambda: 1e-3 }
    }
}

impl Damping {
    /// For a step that takes the loss from `before` to `after`: whether to take it, and
    /// whether to go on.
    pub fn judge(&mut self, before: f64, after: f64) -> (bool, bool) {
        if after < before {
            self.lambda = (self.lambda * 0.3).max(1e-9);
            (true, before - after >= 1e-6 * before)
        } else {
            self.lambda *= 10.0;
            (false, self.lambda <= 1e8)
        }
    }
}

/// A Levenberg–Marquardt step: `δ = −(A + λ·diag A)⁻¹ g`, solved through the damped matrix's
/// eigen-decomposition (it is symmetric positive semi-definite; null directions take no step).
pub fn damped_step<const N: usize>(mut a: Vec<Vec<f64>>, g: &[f64], lambda: f64) -> [f64; N] {
    for (k, row) in a.iter_mut().enumerate() {
        row[k] += lambda * row[k].max(1e-12);
    }
    let (values, vectors) = symmetric_eigen(&a);
    let mut delta = [0.0; N];
    for (lv, v) in values.iter().zip(&vectors) {
        if *lv <= 0.0 {
            continue;
        }
        let c: f64 = v.iter().zip(g).map(|(x, y)| x * y).sum::<f64>() / lv;
        for k in 0..N {
            delta[k] -= c * v[k];
        }
    }
    delta
}

/// The silhouette loss `Σ (o − mask)²` of the spoon at `pose` over `views`, at τ of `px`
/// pixels' footprint.
pub fn silhouette_loss(views: &[View], spoon: &Spoon, pose: &Pose, px: f64) -> f64 {
    views
        .iter()
        .zip(taus(views, pose, px))
        .map(|(v, t)| {
            silhouette(v.camera, spoon, pose, t)
                .occupancy
                .iter()
                .zip(v.mask)
                .filter(|(_, m)| !m.is_nan())
                .map(|(o, m)| (o - m) * (o - m))
                .sum::<f64>()
        })
        .sum()
}

/// The prior's term: `w·‖θ − θ_prior‖²` with the pose difference as a translation and a
/// rotation vector (scaled by `scale`).
fn prior_term(pose: &Pose, prior: &Pose, scale: f64) -> [f64; 6] {
    let dt = pose.translation - prior.translation;
    let dr = (pose.rotation * prior.rotation.inverse()).to_scaled_axis() * scale;
    [dt.x, dt.y, dt.z, dr.x, dr.y, dr.z]
}

/// Fits the spoon's pose to the masks of `views`, from `start`; `prior` (with the options'
/// weight) pulls towards a pose.
pub fn fit_pose(
    views: &[View],
    spoon: &Spoon,
    start: Pose,
    prior: Option<&Pose>,
    opts: &TrackOptions,
) -> Track {
    let scale = spoon.bounding_radius();
    let mut pose = start;
    let mut steps = 0;
    let mut loss = f64::INFINITY;
    for px in tau_levels(opts.tau_px) {
        let taus = taus(views, &pose, px);
        let total = |p: &Pose, l: f64| -> f64 {
            let pr = prior.map_or(0.0, |q| {
                prior_term(p, q, scale).iter().map(|x| x * x).sum::<f64>()
            });
            l + opts.prior_weight * pr
        };
        let (mut l, mut jtj, mut jtr) = gauss_newton(views, spoon, &pose, &taus, scale);
        let mut damping = Damping::default();
        for _ in 0..opts.iterations {
            let mut a: Vec<Vec<f64>> = jtj.iter().map(|r| r.to_vec()).collect();
            let mut g = jtr.to_vec();
            if let Some(q) = prior {
                let d = prior_term(&pose, q, scale);
                for k in 0..6 {
                    a[k][k] += opts.prior_weight;
                    g[k] += opts.prior_weight * d[k];
                }
            }
            let delta = damped_step::<6>(a, &g, damping.lambda);
            let trial = perturbed(
                &pose,
                DVec3::new(delta[0], delta[1], delta[2]),
                DVec3::new(delta[3], delta[4], delta[5]) / scale,
            );
            let (lt, jt, rt) = gauss_newton(views, spoon, &trial, &taus, scale);
            let (before, after) = (total(&pose, l), total(&trial, lt));
            let (accept, go_on) = damping.judge(before, after);
            if accept {
                (pose, l, jtj, jtr) = (trial, lt, jt, rt);
                steps += 1;
            }
            if !go_on {
                break;
            }
        }
        loss = l;
    }
    Track { pose, loss, steps }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::lab::render::camera::CameraSpec;
    use crate::lab::render::silhouette::tests::spoon;
    use crate::math::pose::quat_from_rotation_vector;

    /// A 64×48 test camera at `position`, looking at the spoon's neighbourhood.
    pub(crate) fn camera(name: &str, position: [f64; 3]) -> Camera {
        Camera::from_spec(&CameraSpec {
            name: name.into(),
            width: 64,
            height: 48,
            fx: 70.0,
            fy: 70.0,
            cx: None,
            cy: None,
            position,
            look_at: Some([0.0, 0.02, 0.0]),
            up: None,
            rotation: None,
        })
        .unwrap()
    }

    /// A mask of `s` as a segmenter gives it: the silhouette at a fifth of a pixel's τ,
    /// thresholded.
    pub(crate) fn mask_of(cam: &Camera, s: &Spoon, pose: &Pose) -> Vec<f64> {
        let tau = 0.2 * (pose.translation - cam.position).length() / cam.fx;
        silhouette(cam, s, pose, tau)
            .occupancy
            .iter()
            .map(|&o| if o > 0.5 { 1.0 } else { 0.0 })
            .collect()
    }

    fn mask(cam: &Camera, pose: &Pose) -> Vec<f64> {
        mask_of(cam, &spoon(), pose)
    }

    fn errors(fit: &Pose, truth: &Pose, cam: &Camera) -> (f64, f64, f64) {
        let d = fit.translation - truth.translation;
        let axis = (truth.translation - cam.position).normalize();
        let lateral = (d - d.dot(axis) * axis).length();
        let deg = (fit.rotation * truth.rotation.inverse())
            .to_scaled_axis()
            .length()
            .to_degrees();
        (lateral, d.dot(axis).abs(), deg)
    }

    #[test]
    fn recovers_a_known_pose_from_tiny_images() {
        let truth = Pose {
            translation: DVec3::new(0.004, 0.01, -0.003),
            rotation: quat_from_rotation_vector(DVec3::new(0.2, -1.3, 0.15)),
        };
        let front = camera("front", [0.06, 0.1, 0.14]);
        let side = camera("side", [0.16, 0.07, -0.02]);
        let (mf, ms) = (mask(&front, &truth), mask(&side, &truth));
        assert!(mf.iter().sum::<f64>() > 40.0, "the spoon covers the image");
        // Start 4 mm and 8° away.
        let start = perturbed(
            &truth,
            DVec3::new(0.003, -0.002, 0.002),
            DVec3::new(0.08, 0.1, -0.05),
        );
        let one = [View {
            camera: &front,
            mask: &mf,
        }];
        let two = [
            View {
                camera: &front,
                mask: &mf,
            },
            View {
                camera: &side,
                mask: &ms,
            },
        ];
        let opts = TrackOptions::default();
        let px = (truth.translation - front.position).length() / front.fx;
        // One view fixes the pose across the line of sight to a fraction of a pixel; along it,
        // only the silhouette's size tells the depth, a pixel's change in size being a few mm.
        let fit = fit_pose(&one, &spoon(), start, None, &opts);
        let (lateral, depth, deg) = errors(&fit.pose, &truth, &front);
        assert!(fit.steps > 0);
        assert!(
            lateral < 0.5 * px && deg < 3.0,
            "one view: {lateral:e} m across, {deg:.2}°"
        );
        assert!(
            depth < 4.0 * px,
            "one view: {depth:e} m along the line of sight"
        );
        // A second view fixes the depth too.
        let fit = fit_pose(&two, &spoon(), start, None, &opts);
        let (lateral, depth, deg) = errors(&fit.pose, &truth, &front);
        assert!(
            lateral.hypot(depth) < 0.5 * px && deg < 2.0,
            "two views: {lateral:e} m across, {depth:e} m along, {deg:.2}°"
        );
    }
}
