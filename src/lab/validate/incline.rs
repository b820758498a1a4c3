//! A block on an incline with Coulomb friction μ.
//!
//! The incline is the floor plane with gravity tilted by θ: `g = 9.81·(sin θ, −cos θ, 0)`. A
//! rigid block sticks if `tan θ ≤ μ` and otherwise slides with `a = g·(sin θ − μ·cos θ)`. The
//! block here is a stiff elastic one (E = 2e6 Pa, its elastic deflection under its own weight is
//! under 1e-5 m), loaded by gravity ramped in over [`INCLINE_RAMP`]. Checks (granular.md): at
//! `tan θ = 0.95μ` the block moves less than 1e-3 of its length in the ramp and the 1 s after
//! it; at `tan θ = 1.05μ` the acceleration fitted to its centre of mass over that second, from
//! 0.1 s after the ramp, is within 5 % of the law. At 1.05μ the law's acceleration is only 5 % of the
//! friction deceleration, so a 5 % error in it is a 0.25 % error in the friction force.

use super::{build, mean_x, smooth_ramp, Check};
use crate::components::SimParams;
use serde::Serialize;

/// Gravity is ramped in over this time (s) with [`smooth_ramp`], about 60 periods of the block's
/// vertical elastic mode: dropped under full gravity, the block would ring with a normal force
/// swinging between 0 and twice its weight, and slip whenever it dips below tan θ/μ of it.
pub const INCLINE_RAMP: f64 = 0.2;

/// Largest displacement of the sticking block, as a fraction of its length.
pub const INCLINE_STICK_TOL: f64 = 1e-3;
/// Tolerance on the sliding acceleration (granular.md: within 3–5 %).
pub const INCLINE_ACCEL_REL_TOL: f64 = 0.05;

#[derive(Clone, Copy, Debug)]
pub struct Incline {
    pub friction: f64,
    /// tan θ / μ.
    pub ratio: f64,
    /// Cells along the block.
    pub cells: usize,
    pub duration: f64,
}

impl Incline {
    pub fn new(ratio: f64) -> Incline {
        Incline {
            friction: 0.5,
            ratio,
            cells: 10,
            duration: 1.0,
        }
    }

    pub fn angle(&self) -> f64 {
        (self.ratio * self.friction).atan()
    }

    /// The rigid-block acceleration down the slope (0 when it sticks).
    pub fn law(&self) -> f64 {
        let th = self.angle();
        (9.81 * (th.sin() - self.friction * th.cos())).max(0.0)
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct InclineResult {
    pub ratio: f64,
    pub angle_deg: f64,
    /// Displacement of the centre of mass along the slope at the end (m).
    pub displacement: f64,
    pub length: f64,
    /// Acceleration fitted from 0.1 s after the ramp to the end (m/s²).
    pub acceleration: f64,
    pub law: f64,
    pub particles: usize,
    pub substeps: u64,
    pub wall_s: f64,
}

pub fn incline_scene(c: &Incline) -> String {
    let dx = 0.01;
    let length = c.cells as f64 * dx;
    let th = c.angle();
    let (gx, gy) = (9.81 * th.sin(), -9.81 * th.cos());
    // Room for the slide: ½·a·t² plus margins.
    let slide = 0.5 * c.law() * (c.duration + INCLINE_RAMP).powi(2);
    let nx = c.cells + (slide / dx).ceil() as usize + 14;
    let floor = 4.0 * dx;
    format!(
        r#"Scene(
    simulation: (cells: ({nx}, 14, 13), dx: {dx}, dt: 0.01, substeps: 1, stability: Auto,
                 gravity: ({gx}, {gy}, 0.0)),
    materials: {{ "block": Elastic((density: 1000.0, youngs_modulus: 2e6, poisson_ratio: 0.3)) }},
    bodies: [(name: "block", material: "block",
              fill: Box(min: (0.05, {floor}, 0.04), max: ({x1}, {top}, 0.08)))],
    colliders: [(name: "incline", kind: Container, shape: Plane(normal: (0.0, 1.0, 0.0)),
                 position: (0.0, {floor}, 0.0), friction: {mu}, particle_contact: false)],
)"#,
        x1 = 0.05 + length,
        top = floor + 0.04,
        mu = c.friction,
    )
}

/// Least-squares fit of `s = s₀ + v₀t + ½at²`; returns `a`.
pub fn fit_acceleration(t: &[f64], s: &[f64]) -> f64 {
    // Normal equations of the basis (1, t, t²/2).
    let mut m = [[0.0f64; 3]; 3];
    let mut r = [0.0f64; 3];
    for (&t, &s) in t.iter().zip(s) {
        let b = [1.0, t, 0.5 * t * t];
        for i in 0..3 {
            for j in 0..3 {
                m[i][j] += b[i] * b[j];
            }
            r[i] += b[i] * s;
        }
    }
    let a = glam::DMat3::from_cols_array_2d(&m).transpose();
    let x = a.inverse() * glam::DVec3::from(r);
    x.z
}

pub fn run_incline(c: &Incline, threads: Option<usize>) -> anyhow::Result<InclineResult> {
    let start = std::time::Instant::now();
    let (scene, mut sim) = build(&incline_scene(c), &format!("incline_{}", c.ratio), threads)?;
    let dt = scene.simulation.dt;
    let x0 = mean_x(&mut sim);
    let g_full = scene.simulation.gravity;
    let steps = ((INCLINE_RAMP + c.duration) / dt).round() as usize;
    let (mut ts, mut ss) = (Vec::new(), Vec::new());
    for k in 1..=steps {
        sim.step_with(|world, t| {
            world.resource_mut::<SimParams>().gravity =
                glam::DVec3::from(g_full) * smooth_ramp(t, INCLINE_RAMP);
        })?;
        let t = k as f64 * dt;
        if t >= INCLINE_RAMP + 0.1 - 1e-12 {
            ts.push(t);
            ss.push(mean_x(&mut sim) - x0);
        }
    }
    Ok(InclineResult {
        ratio: c.ratio,
        angle_deg: c.angle().to_degrees(),
        displacement: mean_x(&mut sim) - x0,
        length: c.cells as f64 * 0.01,
        acceleration: fit_acceleration(&ts, &ss),
        law: c.law(),
        particles: sim.particle_count(),
        substeps: sim.clock().total_substeps,
        wall_s: start.elapsed().as_secs_f64(),
    })
}

pub fn incline_checks(r: &InclineResult) -> Vec<Check> {
    let note = format!(
        "θ = {:.3}°, {} particles, {} substeps, {:.1} s",
        r.angle_deg, r.particles, r.substeps, r.wall_s
    );
    if r.law == 0.0 {
        vec![Check::at_most(
            "incline",
            format!("displacement / L in 1.2 s at tan θ = {}μ", r.ratio),
            r.displacement / r.length,
            0.0,
            INCLINE_STICK_TOL,
        )
        .with_note(note)]
    } else {
        vec![Check::relative(
            "incline",
            format!("acceleration (m/s²) at tan θ = {}μ", r.ratio),
            r.acceleration,
            r.law,
            INCLINE_ACCEL_REL_TOL,
        )
        .with_note(note)]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_fit_recovers_a_parabola() {
        let t: Vec<f64> = (20..100).map(|k| k as f64 * 0.01).collect();
        let s: Vec<f64> = t
            .iter()
            .map(|t| 0.3 - 0.1 * t + 0.5 * 0.217 * t * t)
            .collect();
        assert!((fit_acceleration(&t, &s) - 0.217).abs() < 1e-9);
    }

    #[test]
    fn the_law_sticks_below_the_friction_angle() {
        assert_eq!(Incline::new(0.95).law(), 0.0);
        let a = Incline::new(1.05).law();
        let th = (0.525f64).atan();
        assert!((a - 9.81 * (th.sin() - 0.5 * th.cos())).abs() < 1e-12);
    }
}
