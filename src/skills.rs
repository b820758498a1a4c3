//! Skills: Θ = (θ_d, θ_s, θ_l, θ_t, θ_p) ∈ [−1, 1]⁵ → a 6-D control per global step
//! (docs/design.md §4).
//!
//! Each θ maps linearly to a physical range from the scene, `value = min + (θ+1)/2·(max − min)`,
//! and drives one phase: descend (scoop depth below the powder surface), scoop (rotation about
//! the lateral axis while moving a fixed stroke), lift, transport, pour (rotation about the
//! pour axis), settle. A phase of displacement `D` at speed `s` takes
//! `n = max(1, round(|D|/(s·Δt)))` steps of `D/n` each, so the total displacement is exactly
//! linear in θ while the step count is piecewise constant (straight-through rounding).

use crate::error::FieldError;
use glam::DVec3;
use serde::{Deserialize, Serialize};

/// The skill parameters Θ = (θ_d, θ_s, θ_l, θ_t, θ_p) ∈ [−1, 1]⁵: scoop depth, scoop angle,
/// lift height, transport distance, pour angle, each mapped linearly into its range of
/// [`SkillRanges`]. A type of its own, so that a Θ is never taken for a gradient or another
/// five numbers; it reads and writes as the five numbers (scene files, journals, JSON), and
/// indexes and iterates as them.
#[derive(Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Theta(pub [f64; 5]);

impl Theta {
    /// Each component's bits: what a journal keys a rollout by (a resumed run must meet
    /// bitwise the same Θ).
    pub fn bits(&self) -> [u64; 5] {
        self.0.map(f64::to_bits)
    }
}

/// Prints as the five numbers, so that messages read `Θ = [0.1, …]`.
impl std::fmt::Debug for Theta {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.0.fmt(f)
    }
}

impl std::ops::Deref for Theta {
    type Target = [f64; 5];
    fn deref(&self) -> &[f64; 5] {
        &self.0
    }
}

impl std::ops::DerefMut for Theta {
    fn deref_mut(&mut self) -> &mut [f64; 5] {
        &mut self.0
    }
}

impl<'a> IntoIterator for &'a Theta {
    type Item = &'a f64;
    type IntoIter = std::slice::Iter<'a, f64>;
    fn into_iter(self) -> Self::IntoIter {
        self.0.iter()
    }
}

impl IntoIterator for Theta {
    type Item = f64;
    type IntoIter = std::array::IntoIter<f64, 5>;
    fn into_iter(self) -> Self::IntoIter {
        self.0.into_iter()
    }
}

impl From<[f64; 5]> for Theta {
    fn from(t: [f64; 5]) -> Theta {
        Theta(t)
    }
}

impl From<Theta> for [f64; 5] {
    fn from(t: Theta) -> [f64; 5] {
        t.0
    }
}

/// Physical ranges of the five skill parameters.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SkillRanges {
    /// Depth of the bowl bottom below the powder surface (m).
    pub scoop_depth: (f64, f64),
    /// Rotation about the lateral axis during the scoop (degrees).
    pub scoop_angle_deg: (f64, f64),
    /// Height gained in the lift (m).
    pub lift_height: (f64, f64),
    /// Horizontal travel towards the target (m).
    pub transport_distance: (f64, f64),
    /// Rotation about the pour axis (degrees).
    pub pour_angle_deg: (f64, f64),
}

/// A skill: parameters, their ranges and the fixed motion settings.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SkillSpec {
    /// Θ ∈ [−1, 1]⁵: depth, scoop angle, lift, transport, pour.
    pub theta: Theta,
    pub ranges: SkillRanges,
    /// Linear tool speed (m/s).
    pub linear_speed: f64,
    /// Angular tool speed (degrees/s).
    pub angular_speed_deg: f64,
    /// Stroke travelled during the scoop (m).
    pub scoop_stroke: f64,
    /// Height of the powder surface the descent is measured from (m).
    pub surface_height: f64,
    /// Steps to hold still after pouring. Default 20.
    #[serde(default = "default_settle")]
    pub settle_steps: usize,
    /// Direction of the scoop stroke. Default (0, 0, −1).
    #[serde(default = "default_stroke_dir")]
    pub stroke_direction: (f64, f64, f64),
    /// Axis of the scoop rotation. Default (1, 0, 0).
    #[serde(default = "default_lateral")]
    pub lateral_axis: (f64, f64, f64),
    /// Direction of transport. Default (1, 0, 0).
    #[serde(default = "default_transport_dir")]
    pub transport_direction: (f64, f64, f64),
    /// Axis of the pour rotation. Default (0, 0, 1).
    #[serde(default = "default_pour_axis")]
    pub pour_axis: (f64, f64, f64),
}

fn default_settle() -> usize {
    20
}
fn default_stroke_dir() -> (f64, f64, f64) {
    (0.0, 0.0, -1.0)
}
fn default_lateral() -> (f64, f64, f64) {
    (1.0, 0.0, 0.0)
}
fn default_transport_dir() -> (f64, f64, f64) {
    (1.0, 0.0, 0.0)
}
fn default_pour_axis() -> (f64, f64, f64) {
    (0.0, 0.0, 1.0)
}

/// Maps θ ∈ [−1, 1] into `[lo, hi]`.
#[inline]
pub fn map_range(theta: f64, (lo, hi): (f64, f64)) -> f64 {
    lo + 0.5 * (theta + 1.0) * (hi - lo)
}

/// Number of steps for a displacement at a speed: `max(1, round(|d|/(s·Δt)))`.
#[inline]
pub fn phase_steps(distance: f64, speed: f64, dt: f64) -> usize {
    phase_steps_f64(distance, speed, dt) as usize
}

/// The six phases, in order.
pub const PHASES: [&str; 6] = ["descend", "scoop", "lift", "transport", "pour", "settle"];

/// The skill parameters' names, in Θ's order.
pub const PARAM_NAMES: [&str; 5] = ["θ_d", "θ_s", "θ_l", "θ_t", "θ_p"];

/// The most steps a tool's control (a skill's motion, a constant velocity) may take. A slow
/// speed or a tiny `dt` in a scene file would otherwise ask for an absurd horizon, whose
/// per-step controls alone (48 bytes a step) exhaust the memory before the first step; a
/// million steps is 10⁴ s at the scenes' `dt` of 0.01 s.
pub const MAX_CONTROL_STEPS: usize = 1_000_000;

/// Which scene field sets a phase's step count, for messages.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum StepsSetBy {
    LinearSpeed,
    AngularSpeed,
    SettleSteps,
}

/// [`phase_steps`] in f64, before the cast: a bound on an absurd count that neither saturates
/// nor allocates.
fn phase_steps_f64(distance: f64, speed: f64, dt: f64) -> f64 {
    (distance.abs() / (speed * dt)).round().max(1.0)
}

impl SkillSpec {
    pub fn validate(&self) -> Result<(), FieldError> {
        for (k, t) in self.theta.iter().enumerate() {
            if !(-1.0..=1.0).contains(t) {
                return Err(FieldError::new(
                    format!("theta[{k}]"),
                    t.to_string(),
                    "in [-1, 1]",
                ));
            }
        }
        let r = &self.ranges;
        for (name, (lo, hi)) in [
            ("ranges.scoop_depth", r.scoop_depth),
            ("ranges.scoop_angle_deg", r.scoop_angle_deg),
            ("ranges.lift_height", r.lift_height),
            ("ranges.transport_distance", r.transport_distance),
            ("ranges.pour_angle_deg", r.pour_angle_deg),
        ] {
            if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
                return Err(FieldError::new(
                    name,
                    format!("({lo}, {hi})"),
                    "(min, max) with min <= max, both finite",
                ));
            }
        }
        if r.scoop_depth.0 < 0.0 {
            return Err(FieldError::new(
                "ranges.scoop_depth",
                format!("{:?}", r.scoop_depth),
                "a non-negative depth range (m)",
            ));
        }
        for (name, v) in [
            ("linear_speed", self.linear_speed),
            ("angular_speed_deg", self.angular_speed_deg),
        ] {
            if !(v > 0.0 && v.is_finite()) {
                return Err(FieldError::new(name, v.to_string(), "> 0"));
            }
        }
        if !(self.scoop_stroke >= 0.0 && self.scoop_stroke.is_finite()) {
            return Err(FieldError::new(
                "scoop_stroke",
                self.scoop_stroke.to_string(),
                ">= 0 m",
            ));
        }
        for (name, a) in [
            ("stroke_direction", self.stroke_direction),
            ("lateral_axis", self.lateral_axis),
            ("transport_direction", self.transport_direction),
            ("pour_axis", self.pour_axis),
        ] {
            let v = DVec3::from(a);
            if !(v.length() > 0.0 && v.is_finite()) {
                return Err(FieldError::new(
                    name,
                    format!("{a:?}"),
                    "a non-zero finite vector",
                ));
            }
        }
        Ok(())
    }

    /// Physical values of the five parameters: depth (m), scoop angle (rad), lift (m),
    /// transport (m), pour angle (rad).
    pub fn values(&self) -> [f64; 5] {
        let r = &self.ranges;
        let t = self.theta;
        [
            map_range(t[0], r.scoop_depth),
            map_range(t[1], r.scoop_angle_deg).to_radians(),
            map_range(t[2], r.lift_height),
            map_range(t[3], r.transport_distance),
            map_range(t[4], r.pour_angle_deg).to_radians(),
        ]
    }

    /// Per-step controls for a spoon whose bowl bottom starts at height `bottom_y`, with the
    /// number of steps of each phase.
    pub fn controls(&self, dt: f64, bottom_y: f64) -> (Vec<[f64; 6]>, [usize; 6]) {
        let [depth, scoop, lift, transport, pour] = self.values();
        let v = self.linear_speed;
        let w = self.angular_speed_deg.to_radians();
        let unit = |a: (f64, f64, f64)| DVec3::from(a).normalize();
        let mut out = Vec::new();
        let mut counts = [0usize; 6];
        let mut push = |phase: usize, n: usize, t: DVec3, r: DVec3| {
            counts[phase] = n;
            let (t, r) = (t / n as f64, r / n as f64);
            out.extend(std::iter::repeat_n([t.x, t.y, t.z, r.x, r.y, r.z], n));
        };
        let descent = (bottom_y - self.surface_height) + depth;
        push(
            0,
            phase_steps(descent, v, dt),
            DVec3::new(0.0, -descent, 0.0),
            DVec3::ZERO,
        );
        let n = phase_steps(self.scoop_stroke, v, dt).max(phase_steps(scoop, w, dt));
        push(
            1,
            n,
            unit(self.stroke_direction) * self.scoop_stroke,
            unit(self.lateral_axis) * scoop,
        );
        push(
            2,
            phase_steps(lift, v, dt),
            DVec3::new(0.0, lift, 0.0),
            DVec3::ZERO,
        );
        push(
            3,
            phase_steps(transport, v, dt),
            unit(self.transport_direction) * transport,
            DVec3::ZERO,
        );
        push(
            4,
            phase_steps(pour, w, dt),
            DVec3::ZERO,
            unit(self.pour_axis) * pour,
        );
        counts[5] = self.settle_steps;
        out.extend(std::iter::repeat_n([0.0; 6], self.settle_steps));
        (out, counts)
    }
}

impl SkillSpec {
    /// The most steps each phase takes for any Θ in [−1, 1]⁵ (the counts are monotone in each
    /// phase's displacement, which is largest at an end of its range), with the field that
    /// sets it; in f64, so a scene asking for an absurd horizon is measured, not allocated.
    pub fn step_bound(&self, dt: f64, bottom_y: f64) -> [(f64, StepsSetBy); 6] {
        use StepsSetBy::*;
        let r = &self.ranges;
        let far = |(lo, hi): (f64, f64)| lo.abs().max(hi.abs());
        let (v, w) = (self.linear_speed, self.angular_speed_deg.to_radians());
        let descent = far((
            bottom_y - self.surface_height + r.scoop_depth.0,
            bottom_y - self.surface_height + r.scoop_depth.1,
        ));
        let stroke = phase_steps_f64(self.scoop_stroke, v, dt);
        let turn = phase_steps_f64(far(r.scoop_angle_deg).to_radians(), w, dt);
        [
            (phase_steps_f64(descent, v, dt), LinearSpeed),
            if stroke >= turn {
                (stroke, LinearSpeed)
            } else {
                (turn, AngularSpeed)
            },
            (phase_steps_f64(far(r.lift_height), v, dt), LinearSpeed),
            (
                phase_steps_f64(far(r.transport_distance), v, dt),
                LinearSpeed,
            ),
            (
                phase_steps_f64(far(r.pour_angle_deg).to_radians(), w, dt),
                AngularSpeed,
            ),
            (self.settle_steps as f64, SettleSteps),
        ]
    }

    /// Adjoint of [`SkillSpec::controls`]: `∂L/∂u` per step → `∂L/∂Θ`. The step counts are
    /// held fixed (straight-through rounding: a surrogate at the points where a count changes,
    /// exact between them), so each step's `u = D/n` passes `ū/n` to its phase displacement `D`,
    /// which is linear in the phase's physical value, itself `min + (θ+1)/2·(max − min)`.
    pub fn controls_adj(&self, dt: f64, bottom_y: f64, g_u: &[[f64; 6]]) -> [f64; 5] {
        let (_, counts) = self.controls(dt, bottom_y);
        let unit = |a: (f64, f64, f64)| DVec3::from(a).normalize();
        let mut start = 0;
        let mut phase_sum = [[0.0f64; 6]; 6];
        for (p, &n) in counts.iter().enumerate() {
            for u in g_u.iter().skip(start).take(n) {
                for k in 0..6 {
                    phase_sum[p][k] += u[k] / n as f64;
                }
            }
            start += n;
        }
        let t = |p: usize| DVec3::new(phase_sum[p][0], phase_sum[p][1], phase_sum[p][2]);
        let r = |p: usize| DVec3::new(phase_sum[p][3], phase_sum[p][4], phase_sum[p][5]);
        let deg = std::f64::consts::PI / 180.0;
        let half = |(lo, hi): (f64, f64)| 0.5 * (hi - lo);
        let rg = &self.ranges;
        [
            -t(0).y * half(rg.scoop_depth),
            unit(self.lateral_axis).dot(r(1)) * half(rg.scoop_angle_deg) * deg,
            t(2).y * half(rg.lift_height),
            unit(self.transport_direction).dot(t(3)) * half(rg.transport_distance),
            unit(self.pour_axis).dot(r(4)) * half(rg.pour_angle_deg) * deg,
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec() -> SkillSpec {
        SkillSpec {
            theta: Theta([0.0, 0.5, -0.5, 1.0, -1.0]),
            ranges: SkillRanges {
                scoop_depth: (0.005, 0.02),
                scoop_angle_deg: (10.0, 60.0),
                lift_height: (0.03, 0.08),
                transport_distance: (0.08, 0.16),
                pour_angle_deg: (60.0, 150.0),
            },
            linear_speed: 0.1,
            angular_speed_deg: 90.0,
            scoop_stroke: 0.02,
            surface_height: 0.03,
            settle_steps: 5,
            stroke_direction: default_stroke_dir(),
            lateral_axis: default_lateral(),
            transport_direction: default_transport_dir(),
            pour_axis: default_pour_axis(),
        }
    }

    /// The skill mapping is differentiable: `controls_adj` against central differences of
    /// `Σ w·u(Θ)` in f64, with a step small enough that no step count changes.
    #[test]
    fn controls_adjoint_matches_central_differences() {
        const EPS: f64 = 1e-7;
        const TOL: f64 = 1e-7;
        let mut s = spec();
        // Away from the points where a step count rounds differently (θ_d = 0 gives a descent
        // of exactly 32.5 steps here).
        s.theta = Theta([0.1, 0.5, -0.2, 0.7, -0.6]);
        let (dt, bottom) = (0.01, 0.05);
        let (u0, _) = s.controls(dt, bottom);
        let w: Vec<[f64; 6]> = (0..u0.len())
            .map(|i| std::array::from_fn(|k| ((i * 7 + k * 3) % 11) as f64 - 5.0))
            .collect();
        let g = s.controls_adj(dt, bottom, &w);
        let f = |theta: Theta| {
            let mut t = s.clone();
            t.theta = theta;
            let (u, _) = t.controls(dt, bottom);
            assert_eq!(
                u.len(),
                u0.len(),
                "a step count changed: pick another point"
            );
            u.iter()
                .zip(&w)
                .map(|(u, w)| u.iter().zip(w).map(|(a, b)| a * b).sum::<f64>())
                .sum::<f64>()
        };
        for k in 0..5 {
            let (mut p, mut m) = (s.theta, s.theta);
            p[k] += EPS;
            m[k] -= EPS;
            let fd = (f(p) - f(m)) / (2.0 * EPS);
            assert!(
                (fd - g[k]).abs() <= TOL * fd.abs().max(g[k].abs()).max(1.0),
                "θ[{k}]: fd {fd} adjoint {}",
                g[k]
            );
        }
    }

    #[test]
    fn total_displacement_is_exact() {
        let s = spec();
        let (u, counts) = s.controls(0.01, 0.05);
        assert_eq!(u.len(), counts.iter().sum::<usize>());
        let total: DVec3 = u.iter().map(|c| DVec3::new(c[0], c[1], c[2])).sum();
        let [depth, _, lift, transport, _] = s.values();
        let expect = DVec3::new(transport, -(0.05 - 0.03 + depth) + lift, -0.02);
        assert!((total - expect).length() < 1e-14, "{total} vs {expect}");
        assert!((s.values()[3] - 0.16).abs() < 1e-15);
    }
}
