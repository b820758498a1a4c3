//! A spatula's stroke for the push task: its five parameters Φ ∈ [−1, 1]⁵, the motion they
//! give (the start pose and the per-step controls), and the chain rule that takes a backward
//! pass's gradients with respect to the tool's start pose and controls back to Φ.
//!
//! The motion: the blade starts [`LIFT`] above its landing point, descends onto it, strokes
//! along `d = (s·cos ψ, 0, sin ψ)` (`s` the region's side, `ψ` the yaw) for the stroke's
//! length at the plan's speed, lifts and holds still for [`SETTLE_STEPS`]. The landing point is
//! `behind` short of the powder's trailing edge along x, `lateral` off the contact along z and
//! `height` above the plate. The blade's face normal lies along `d` and the handle leans about
//! the blade's width, against the stroke for a push and along it for a pull.
//!
//! The number of steps of the stroke is the length over the distance of one step, rounded: a
//! change of length within one rounding interval changes the per-step control only, which is
//! what [`phi_gradient`] differentiates; the count's jumps (one step in 10 mm at the default
//! speed) are left out.

use glam::{DQuat, DVec3};
use serde::{Deserialize, Serialize};

/// The physical range of each stroke parameter: landing distance behind the powder (m),
/// lateral offset (m), yaw (degrees), edge height above the plate (m), length (m).
pub const RANGES: [(f64, f64); 5] = [
    (0.003, 0.02),
    (-0.015, 0.015),
    (-30.0, 30.0),
    (0.0005, 0.005),
    (0.02, 0.12),
];

/// The height the blade descends from onto its landing point, and lifts by after the stroke
/// (m).
pub const LIFT: f64 = 0.02;
/// Steps the spatula holds still after lifting, for the powder to settle.
pub const SETTLE_STEPS: usize = 10;

/// A stroke in physical units.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
pub struct Stroke {
    pub behind: f64,
    pub lateral: f64,
    pub yaw_deg: f64,
    pub height: f64,
    pub length: f64,
}

impl Stroke {
    pub fn from_phi(phi: &[f64; 5]) -> Stroke {
        let m = |k: usize| RANGES[k].0 + 0.5 * (phi[k] + 1.0) * (RANGES[k].1 - RANGES[k].0);
        Stroke {
            behind: m(0),
            lateral: m(1),
            yaw_deg: m(2),
            height: m(3),
            length: m(4),
        }
    }
    /// Φ of a stroke, clamped into the box.
    pub fn to_phi(&self) -> [f64; 5] {
        let v = [
            self.behind,
            self.lateral,
            self.yaw_deg,
            self.height,
            self.length,
        ];
        std::array::from_fn(|k| {
            (2.0 * (v[k] - RANGES[k].0) / (RANGES[k].1 - RANGES[k].0) - 1.0).clamp(-1.0, 1.0)
        })
    }
}

/// What a stroke is measured from: the task's geometry at the node.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    /// The region's side along x (−1 or +1).
    pub side: f64,
    /// The x of the powder's far side from the region (m).
    pub trailing: f64,
    /// The contact's z (m).
    pub contact: f64,
    /// The plate's top (m).
    pub plate_top: f64,
    /// The handle's lean (radians), signed: along the stroke for a pull.
    pub lean: f64,
    /// The spatula's speed (m/s) and the global step (s).
    pub speed: f64,
    pub dt: f64,
}

/// A stroke's motion: the tool's start position and orientation, its per-step controls
/// (translation, rotation vector), and the steps of the stroke proper.
#[derive(Clone, Debug, PartialEq)]
pub struct Motion {
    pub start: DVec3,
    pub rotation: DQuat,
    pub controls: Vec<[f64; 6]>,
    pub stroke_steps: std::ops::Range<usize>,
}

impl Motion {
    /// Where the blade's edge lands.
    pub fn landing(&self) -> DVec3 {
        self.start - DVec3::new(0.0, LIFT, 0.0)
    }
}

fn steps(f: &Frame, dist: f64) -> usize {
    ((dist / (f.speed * f.dt)).round() as usize).max(1)
}

/// The motion of stroke `st` in frame `f`.
pub fn motion(f: &Frame, st: &Stroke) -> Motion {
    let s = f.side;
    let yaw = st.yaw_deg.to_radians();
    let d = DVec3::new(s * yaw.cos(), 0.0, yaw.sin());
    let landing = DVec3::new(
        f.trailing - s * st.behind,
        f.plate_top + st.height,
        f.contact + st.lateral,
    );
    // Local z (the blade's face normal) along the stroke, then the handle leaned about the
    // blade's width. Since the width is the face's x, the lean about it composes as
    // `face · R_x(lean)`: a change of yaw turns the whole pose about the world's y.
    let face = DQuat::from_rotation_y(d.x.atan2(d.z));
    let width = face * DVec3::X;
    let rotation = DQuat::from_axis_angle(width, f.lean) * face;
    let mut controls = Vec::new();
    let n1 = steps(f, LIFT);
    controls.extend(std::iter::repeat_n(
        [0.0, -LIFT / n1 as f64, 0.0, 0.0, 0.0, 0.0],
        n1,
    ));
    let n2 = steps(f, st.length);
    let step = d * st.length / n2 as f64;
    controls.extend(std::iter::repeat_n(
        [step.x, 0.0, step.z, 0.0, 0.0, 0.0],
        n2,
    ));
    controls.extend(std::iter::repeat_n(
        [0.0, LIFT / n1 as f64, 0.0, 0.0, 0.0, 0.0],
        n1,
    ));
    controls.extend(std::iter::repeat_n([0.0; 6], SETTLE_STEPS));
    Motion {
        start: landing + DVec3::new(0.0, LIFT, 0.0),
        rotation,
        controls,
        stroke_steps: n1..n1 + n2,
    }
}

/// `∂L/∂Φ` from a backward pass's gradients with respect to the tool's start position
/// (`g_start`), its start orientation as a world-frame rotation vector (`g_rotation`) and its
/// per-step controls (`g_controls`), for stroke `st` in frame `f`.
///
/// - `start = (trailing − s·behind, top + height + LIFT, contact + lateral)`;
/// - the yaw turns the pose about the world's y by `dα = −s·dψ` (`α = atan2(s·cos ψ, sin ψ)`,
///   whose derivative in ψ is `−s`), and each stroke step's control `d·length/n₂` by
///   `(−s·sin ψ, 0, cos ψ)·length/n₂·dψ`;
/// - the length scales each stroke step's control by `d/n₂`.
pub fn phi_gradient(
    f: &Frame,
    st: &Stroke,
    g_start: DVec3,
    g_rotation: DVec3,
    g_controls: &[[f64; 6]],
) -> [f64; 5] {
    let s = f.side;
    let m = motion(f, st);
    let yaw = st.yaw_deg.to_radians();
    let d = DVec3::new(s * yaw.cos(), 0.0, yaw.sin());
    let d_yaw = DVec3::new(-s * yaw.sin(), 0.0, yaw.cos());
    let n2 = m.stroke_steps.len() as f64;
    let mut g_u = DVec3::ZERO;
    for k in m.stroke_steps.clone() {
        let g = g_controls.get(k).copied().unwrap_or([0.0; 6]);
        g_u += DVec3::new(g[0], g[1], g[2]);
    }
    let physical = [
        -s * g_start.x,
        g_start.z,
        (-s * g_rotation.y + g_u.dot(d_yaw) * st.length / n2) * std::f64::consts::PI / 180.0,
        g_start.y,
        g_u.dot(d) / n2,
    ];
    std::array::from_fn(|k| physical[k] * 0.5 * (RANGES[k].1 - RANGES[k].0))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(side: f64) -> Frame {
        Frame {
            side,
            trailing: 0.11,
            contact: 0.06,
            plate_top: 0.02,
            lean: -0.35,
            speed: 0.1,
            dt: 0.01,
        }
    }

    /// A linear functional of the motion, `L = a·start + b·θ + Σ_k c_k·u_k` with `θ` the
    /// rotation vector from a reference pose, differentiated by [`phi_gradient`] and by central
    /// differences on Φ. Exact up to round-off and the rotation vector's curvature (the
    /// composition `exp(δθ)·R` is linear in δθ to first order), so a step of 1e-6 in Φ and a
    /// tolerance of 1e-6 of the gradient's scale.
    #[test]
    fn the_chain_rule_matches_central_differences() {
        for side in [-1.0, 1.0] {
            let f = frame(side);
            // A length of 80 steps exactly, so the differences keep the step count.
            let phi = [0.1, -0.3, 0.4, -0.5, 0.2];
            let st = Stroke::from_phi(&phi);
            let m0 = motion(&f, &st);
            let a = DVec3::new(0.3, -1.1, 0.7);
            let b = DVec3::new(0.2, 0.9, -0.4);
            let c: Vec<[f64; 6]> = (0..m0.controls.len())
                .map(|k| {
                    let t = k as f64;
                    [t.sin(), 0.5, (0.3 * t).cos(), 0.0, 0.0, 0.0]
                })
                .collect();
            let value = |phi: &[f64; 5]| {
                let m = motion(&f, &Stroke::from_phi(phi));
                assert_eq!(m.controls.len(), c.len(), "the step count stays");
                let theta = (m.rotation * m0.rotation.inverse()).to_scaled_axis();
                a.dot(m.start)
                    + b.dot(theta)
                    + m.controls
                        .iter()
                        .zip(&c)
                        .map(|(u, w)| (0..6).map(|i| u[i] * w[i]).sum::<f64>())
                        .sum::<f64>()
            };
            let g = phi_gradient(&f, &st, a, b, &c);
            let h = 1e-6;
            for k in 0..5 {
                let (mut p, mut q) = (phi, phi);
                p[k] += h;
                q[k] -= h;
                let fd = (value(&p) - value(&q)) / (2.0 * h);
                assert!(
                    (fd - g[k]).abs() < 1e-6 * (1.0 + fd.abs()),
                    "side {side}, Φ{k}: {} against {fd}",
                    g[k]
                );
            }
        }
    }

    #[test]
    fn phi_round_trips() {
        let phi = [0.1, -0.3, 0.4, -0.5, 0.23];
        let back = Stroke::from_phi(&phi).to_phi();
        for k in 0..5 {
            assert!((back[k] - phi[k]).abs() < 1e-12);
        }
    }
}
