//! Fitting the spoon's shape with the poses (seed B's shape step): Levenberg–Marquardt on the
//! silhouette loss of every frame at once, over the bowl radius, the bowl depth and the handle
//! length ([`PARAMS`](crate::lab::render::silhouette::PARAMS)' last three) *and* every frame's pose.
//! The thickness, the handle's radius and its rise stay the scene's: at a pixel's footprint of
//! a few tenths of a millimetre they change a silhouette by less than a pixel.
//!
//! **Jointly, not in turn.** Seed B alternates: poses with the shape fixed, then the shape with
//! the poses fixed. Here that stalled: a spoon 10–15 % off leaves poses that make up for it
//! (a smaller bowl sits lower), and with them fixed the shape cannot move. On a synthetic
//! demonstration four rounds lowered the silhouette loss only from 590 to 534 and moved the
//! bowl radius away from the truth (docs/design.md). The joint step sees both at once. Its
//! normal equations are a 6×6 block per frame tied by the 3 shape parameters, and the Schur
//! complement solves them in O(frames): `S = Σ C_i − B_iᵀA_i⁻¹B_i`, `δs = −S⁻¹(Σ g_si −
//! B_iᵀA_i⁻¹g_pi)`, `δp_i = −A_i⁻¹(g_pi + B_i·δs)`.

use super::track::{tau_levels, taus, Damping, View};
use crate::lab::render::silhouette::{perturbed, reshaped, silhouette};
use crate::math::eigen::symmetric_eigen;
use crate::math::pose::Pose;
use crate::math::sdf::Spoon;
use glam::DVec3;

/// What [`refine`] gives.
#[derive(Clone, Debug)]
pub struct Refined {
    pub spoon: Spoon,
    pub poses: Vec<Pose>,
    /// Each frame's silhouette loss `Σ (o − mask)²` over its views at the end.
    pub losses: Vec<f64>,
    /// Levenberg–Marquardt steps accepted.
    pub steps: usize,
}

/// The spoon's three fitted dimensions: bowl radius, bowl depth, handle length (m).
pub fn dimensions(s: &Spoon) -> [f64; 3] {
    [s.bowl_radius, s.bowl_depth, s.handle_length]
}

/// One frame's Gauss–Newton terms: loss, `A = J_pᵀJ_p`, `B = J_pᵀJ_s`, `C = J_sᵀJ_s`,
/// `g_p = J_pᵀr`, `g_s = J_sᵀr` (rotations scaled by `scale`, as the tracker does).
struct Terms {
    loss: f64,
    a: [[f64; 6]; 6],
    b: [[f64; 3]; 6],
    c: [[f64; 3]; 3],
    gp: [f64; 6],
    gs: [f64; 3],
}

fn terms(views: &[View], spoon: &Spoon, pose: &Pose, px: f64, scale: f64) -> Terms {
    let mut t = Terms {
        loss: 0.0,
        a: [[0.0; 6]; 6],
        b: [[0.0; 3]; 6],
        c: [[0.0; 3]; 3],
        gp: [0.0; 6],
        gs: [0.0; 3],
    };
    for (v, tau) in views.iter().zip(taus(views, pose, px)) {
        let s = silhouette(v.camera, spoon, pose, tau);
        for ((o, ray), m) in s.occupancy.iter().zip(&s.rays).zip(v.mask) {
            if m.is_nan() {
                continue;
            }
            let r = o - m;
            t.loss += r * r;
            if let Some((_, dm)) = ray {
                let f = -o * (1.0 - o) / tau;
                let jp: [f64; 6] =
                    std::array::from_fn(|k| f * dm[k] * if k >= 3 { 1.0 / scale } else { 1.0 });
                let js = [f * dm[6], f * dm[7], f * dm[8]];
                for (i, pi) in jp.iter().enumerate() {
                    t.gp[i] += pi * r;
                    for (a, pj) in t.a[i].iter_mut().zip(&jp) {
                        *a += pi * pj;
                    }
                    for (b, sj) in t.b[i].iter_mut().zip(&js) {
                        *b += pi * sj;
                    }
                }
                for (i, si) in js.iter().enumerate() {
                    t.gs[i] += si * r;
                    for (c, sj) in t.c[i].iter_mut().zip(&js) {
                        *c += si * sj;
                    }
                }
            }
        }
    }
    t
}

/// The pseudo-inverse of a symmetric positive semi-definite matrix.
fn pinv(a: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let n = a.len();
    let (values, vectors) = symmetric_eigen(a);
    let mut out = vec![vec![0.0; n]; n];
    for (lv, v) in values.iter().zip(&vectors) {
        if *lv <= 0.0 {
            continue;
        }
        for i in 0..n {
            for j in 0..n {
                out[i][j] += v[i] * v[j] / lv;
            }
        }
    }
    out
}

/// The damped step of every pose and of the shape, by the Schur complement.
fn joint_step(t: &[Terms], lambda: f64) -> (Vec<[f64; 6]>, [f64; 3]) {
    let damp = |m: &mut Vec<Vec<f64>>| {
        for (k, row) in m.iter_mut().enumerate() {
            row[k] += lambda * row[k].max(1e-12);
        }
    };
    let mut s: Vec<Vec<f64>> = vec![vec![0.0; 3]; 3];
    let mut rhs = [0.0; 3];
    let mut inverses = Vec::with_capacity(t.len());
    for f in t {
        let mut a: Vec<Vec<f64>> = f.a.iter().map(|r| r.to_vec()).collect();
        damp(&mut a);
        let ai = pinv(&a);
        // A⁻¹B (6×3) and A⁻¹g_p (6).
        let aib: Vec<[f64; 3]> = (0..6)
            .map(|i| std::array::from_fn(|j| (0..6).map(|k| ai[i][k] * f.b[k][j]).sum()))
            .collect();
        let aig: Vec<f64> = (0..6)
            .map(|i| (0..6).map(|k| ai[i][k] * f.gp[k]).sum())
            .collect();
        for i in 0..3 {
            rhs[i] += f.gs[i] - (0..6).map(|k| f.b[k][i] * aig[k]).sum::<f64>();
            for j in 0..3 {
                s[i][j] += f.c[i][j] - (0..6).map(|k| f.b[k][i] * aib[k][j]).sum::<f64>();
            }
        }
        inverses.push((aib, aig));
    }
    damp(&mut s);
    let si = pinv(&s);
    let ds: [f64; 3] = std::array::from_fn(|i| -(0..3).map(|j| si[i][j] * rhs[j]).sum::<f64>());
    let dp = inverses
        .iter()
        .map(|(aib, aig)| {
            std::array::from_fn(|i| -(aig[i] + (0..3).map(|j| aib[i][j] * ds[j]).sum::<f64>()))
        })
        .collect();
    (dp, ds)
}

/// Fits the spoon's dimensions and every frame's pose (`frames`: each frame's views) from
/// `spoon` and `poses`, with τ halved from `tau_px.0` to `tau_px.1` pixels' footprint (as the
/// tracker does) and at most `iterations` steps at each τ. A step that would make the spoon
/// invalid (a dimension ≤ 0, a bowl deeper than its diameter) is refused like one that raises
/// the loss.
pub fn refine(
    frames: &[Vec<View>],
    spoon: Spoon,
    poses: &[Pose],
    tau_px: (f64, f64),
    iterations: usize,
) -> Refined {
    let scale = spoon.bounding_radius();
    let (mut spoon, mut poses) = (spoon, poses.to_vec());
    let all = |spoon: &Spoon, poses: &[Pose], px: f64| -> Vec<Terms> {
        frames
            .iter()
            .zip(poses)
            .map(|(v, p)| terms(v, spoon, p, px, scale))
            .collect()
    };
    let total = |t: &[Terms]| t.iter().map(|f| f.loss).sum::<f64>();
    let mut steps = 0;
    let mut losses = Vec::new();
    for px in tau_levels(tau_px) {
        let mut t = all(&spoon, &poses, px);
        let mut damping = Damping::default();
        for _ in 0..iterations {
            let (dp, ds) = joint_step(&t, damping.lambda);
            let trial_spoon = reshaped(&spoon, ds);
            let trial_poses: Vec<Pose> = poses
                .iter()
                .zip(&dp)
                .map(|(p, d)| {
                    perturbed(
                        p,
                        DVec3::new(d[0], d[1], d[2]),
                        DVec3::new(d[3], d[4], d[5]) / scale,
                    )
                })
                .collect();
            let tried = trial_spoon
                .validate()
                .is_ok()
                .then(|| all(&trial_spoon, &trial_poses, px));
            let (before, after) = (total(&t), tried.as_deref().map_or(f64::INFINITY, total));
            let (accept, go_on) = damping.judge(before, after);
            if accept {
                (spoon, poses, t) = (trial_spoon, trial_poses, tried.expect("a finite loss"));
                steps += 1;
            }
            if !go_on {
                break;
            }
        }
        losses = t.iter().map(|f| f.loss).collect();
    }
    Refined {
        spoon,
        poses,
        losses,
        steps,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lab::demo::track::tests::{camera, mask_of};
    use crate::lab::render::silhouette::tests::spoon;
    use crate::math::pose::quat_from_rotation_vector;
    use glam::DVec3;

    /// Recovering a spoon 10–15 % off in each dimension (1.5, 1 and 4 mm), and three poses, two
    /// views each, the masks thresholded at a fifth of a pixel's τ. What a silhouette shows
    /// well comes back within a sixth of a pixel's footprint (0.3 mm here): the handle's length
    /// and the rim's width `√(2rd − d²)`. The bowl's radius and depth trade off along rims of
    /// that width, seen only side-on, and come back within a third of a pixel (the loss's
    /// optimum on binary masks lies there: more iterations do not close it).
    #[test]
    fn recovers_a_known_shape_and_its_poses() {
        let truth = reshaped(&spoon(), [0.0015, -0.001, 0.004]);
        let cams = [
            camera("front", [0.06, 0.1, 0.14]),
            camera("side", [0.16, 0.07, -0.02]),
        ];
        let poses: Vec<Pose> = [
            (DVec3::new(0.004, 0.01, -0.003), DVec3::new(0.2, -1.3, 0.15)),
            (DVec3::new(-0.002, 0.015, 0.002), DVec3::new(-0.4, 0.3, 0.5)),
            (DVec3::new(0.0, 0.02, 0.0), DVec3::new(0.9, 0.1, -0.2)),
        ]
        .iter()
        .map(|&(t, r)| Pose {
            translation: t,
            rotation: quat_from_rotation_vector(r),
        })
        .collect();
        let masks: Vec<Vec<Vec<f64>>> = poses
            .iter()
            .map(|p| cams.iter().map(|c| mask_of(c, &truth, p)).collect())
            .collect();
        let frames: Vec<Vec<View>> = masks
            .iter()
            .map(|m| {
                cams.iter()
                    .zip(m)
                    .map(|(camera, mask)| View { camera, mask })
                    .collect()
            })
            .collect();
        // The poses start a millimetre and a few degrees off, as a tracker with the wrong
        // spoon leaves them.
        let starts: Vec<Pose> = poses
            .iter()
            .map(|p| {
                perturbed(
                    p,
                    DVec3::new(0.001, -0.001, 0.0005),
                    DVec3::new(0.03, -0.02, 0.04),
                )
            })
            .collect();
        let fit = refine(&frames, spoon(), &starts, (1.0, 0.25), 25);
        let px = 0.14 / 70.0;
        assert!(fit.steps > 0);
        let rim = |s: &Spoon| (2.0 * s.bowl_radius * s.bowl_depth - s.bowl_depth.powi(2)).sqrt();
        let (f, t) = (&fit.spoon, &truth);
        for (what, a, b, tol) in [
            ("rim width", rim(f), rim(t), 0.15),
            ("handle length", f.handle_length, t.handle_length, 0.15),
            ("bowl radius", f.bowl_radius, t.bowl_radius, 0.33),
            ("bowl depth", f.bowl_depth, t.bowl_depth, 0.33),
        ] {
            assert!(
                (a - b).abs() < tol * px,
                "{what}: fitted {a} against {b} (a pixel is {px} m)"
            );
        }
    }
}
