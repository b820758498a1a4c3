//! The fixed–free vibrating elastic bar (after Bardenhagen 2002, JCP 180:383).
//!
//! A bar of length `L` along x, fixed at x = 0 and free at x = L, in its first mode: the initial
//! velocity is `v(x) = v₀·sin(πx/2L)`. Its period is `T₁ = 4L/c` with the bar velocity
//! `c = √(E/ρ)`, so `ω₁ = (π/2L)·√(E/ρ)`. The fixed end is three layers of sticky grid nodes
//! (the domain wall at x ≤ 2dx), the bar starting on the last of them, as in Bardenhagen's set-up.
//! The mean x-displacement of the bar is `(2/π)(v₀/ω₁)·sin ω₁t`: the period is read from its
//! zero crossings (linearly interpolated between steps) over ten periods.
//!
//! Stress-update order: the deformation gradient is updated with the velocity gradient `C` that
//! G2P gathers from the grid velocities after the grid update, i.e. "update stress last" (USL);
//! MLS-MPM evaluates that stress at the start of the next substep. The energy (kinetic +
//! Hencky elastic) is sampled at every step, and its drift over the ten periods reported.
//!
//! With ν = 0.3 the bar is a 3-D body with free lateral faces: Rayleigh's lateral-inertia
//! correction to the period is `½ν²k²r²` ≈ 1e-4 here (k = π/2L, r² = a²/6 of the square
//! section of side a = 2dx), far below the 1 % tolerance.

use super::{build, mean_x, set_velocity, Check};
use crate::metrics::frame_metrics;
use crate::sim::Simulation;
use glam::DVec3;
use serde::Serialize;

/// Tolerance on the period (granular.md: within 1 % at 16 or more cells along the bar).
pub const BAR_PERIOD_REL_TOL: f64 = 0.01;
/// Tolerance on the energy drift over ten periods (granular.md: "within a few %").
pub const BAR_ENERGY_DRIFT_TOL: f64 = 0.03;

/// Settings of one bar run.
#[derive(Clone, Copy, Debug)]
pub struct Bar {
    /// Cells along the bar.
    pub cells: usize,
    /// Bar length (m).
    pub length: f64,
    pub youngs: f64,
    pub poisson: f64,
    pub density: f64,
    /// Peak strain of the mode (sets v₀ = strain·c).
    pub strain: f64,
    /// Periods simulated.
    pub periods: usize,
}

impl Bar {
    pub fn new(cells: usize) -> Bar {
        Bar {
            cells,
            length: 0.32,
            youngs: 1e6,
            poisson: 0.3,
            density: 1000.0,
            strain: 1e-3,
            periods: 10,
        }
    }

    /// `T₁ = 4L/√(E/ρ)`.
    pub fn exact_period(&self) -> f64 {
        4.0 * self.length / (self.youngs / self.density).sqrt()
    }
}

/// Outcome of one bar run.
#[derive(Clone, Debug, Serialize)]
pub struct BarResult {
    pub cells: usize,
    pub period: f64,
    pub exact_period: f64,
    /// (E(end) − E(0))/E(0), kinetic + elastic.
    pub energy_drift: f64,
    /// Largest |E(t) − E(0)|/E(0) over the run.
    pub energy_max_deviation: f64,
    pub particles: usize,
    pub substeps: u64,
    pub wall_s: f64,
}

/// The RON scene of the bar: sticky domain walls, no gravity.
pub fn bar_scene(b: &Bar) -> String {
    let dx = b.length / b.cells as f64;
    let section = 2.0;
    // Nodes 0..=2 are the low wall; the far wall must stay clear of the bar's stencil.
    let nx = b.cells + 9;
    let nyz = 12;
    let x0 = 2.0 * dx;
    let y0 = 5.0 * dx;
    let dt = b.exact_period() / 40.0;
    format!(
        r#"Scene(
    simulation: (cells: ({nx}, {nyz}, {nyz}), dx: {dx}, dt: {dt}, substeps: 1, stability: Auto,
                 gravity: (0.0, 0.0, 0.0), empty_node_ratio: 0.0,
                 walls: (cells: 3, contact: Sticky, friction: 0.0)),
    materials: {{ "bar": Elastic((density: {rho}, youngs_modulus: {e}, poisson_ratio: {nu})) }},
    bodies: [(name: "bar", material: "bar",
              fill: Box(min: ({x0}, {y0}, {y0}), max: ({x1}, {y1}, {y1})))],
)"#,
        rho = b.density,
        e = b.youngs,
        nu = b.poisson,
        x1 = x0 + b.length,
        y1 = y0 + section * dx,
    )
}

/// Times of the upward and downward zero crossings of a sampled signal, linearly interpolated.
pub fn zero_crossings(t: &[f64], u: &[f64]) -> Vec<f64> {
    let mut out = Vec::new();
    for k in 1..u.len() {
        let (a, b) = (u[k - 1], u[k]);
        if a != 0.0 && ((a < 0.0) != (b < 0.0) || b == 0.0) {
            out.push(t[k - 1] + (t[k] - t[k - 1]) * a / (a - b));
        }
    }
    out
}

/// Runs the bar for `b.periods` periods.
pub fn run_bar(b: &Bar, threads: Option<usize>) -> anyhow::Result<BarResult> {
    let start = std::time::Instant::now();
    let (scene, mut sim) = build(&bar_scene(b), &format!("bar_{}", b.cells), threads)?;
    let dx = scene.simulation.dx;
    let x_fixed = 2.0 * dx;
    let c = (b.youngs / b.density).sqrt();
    let v0 = b.strain * c;
    let k = std::f64::consts::PI / (2.0 * b.length);
    set_velocity(&mut sim, |x| {
        DVec3::new(v0 * (k * (x.x - x_fixed)).sin(), 0.0, 0.0)
    });
    let x_ref: f64 = mean_x(&mut sim);
    let dt = scene.simulation.dt;
    let steps = (b.periods as f64 * b.exact_period() / dt).round() as usize + 2;
    let e0 = energy(&mut sim);
    let (mut ts, mut us) = (vec![0.0], vec![0.0]);
    let mut max_dev: f64 = 0.0;
    let mut e_end = e0;
    for s in 1..=steps {
        sim.step()?;
        ts.push(s as f64 * dt);
        us.push(mean_x(&mut sim) - x_ref);
        e_end = energy(&mut sim);
        max_dev = max_dev.max((e_end - e0).abs() / e0);
    }
    // The signal starts at a zero crossing (t = 0, rising): the crossings after it are at
    // multiples of T/2.
    let zc = zero_crossings(&ts[1..], &us[1..]);
    anyhow::ensure!(
        zc.len() >= 3,
        "the bar did not oscillate: {} zero crossings in {} steps",
        zc.len(),
        steps
    );
    let period = 2.0 * (zc[zc.len() - 1] - zc[0]) / (zc.len() - 1) as f64;
    Ok(BarResult {
        cells: b.cells,
        period,
        exact_period: b.exact_period(),
        energy_drift: (e_end - e0) / e0,
        energy_max_deviation: max_dev,
        particles: sim.particle_count(),
        substeps: sim.clock().total_substeps,
        wall_s: start.elapsed().as_secs_f64(),
    })
}

fn energy(sim: &mut Simulation) -> f64 {
    let m = frame_metrics(&mut sim.world, None);
    m.kinetic_energy + m.elastic_energy
}

/// The checks of one bar run.
pub fn bar_checks(r: &BarResult) -> Vec<Check> {
    let note = format!(
        "{} cells along the bar, {} particles, {} substeps, {:.1} s; USL stress update",
        r.cells, r.particles, r.substeps, r.wall_s
    );
    vec![
        Check::relative(
            "bar",
            format!("period (s), {} cells", r.cells),
            r.period,
            r.exact_period,
            BAR_PERIOD_REL_TOL,
        )
        .with_note(note),
        Check::at_most(
            "bar",
            format!("energy drift over 10 periods, {} cells", r.cells),
            r.energy_drift,
            0.0,
            BAR_ENERGY_DRIFT_TOL,
        )
        .with_note(format!(
            "largest |E(t) − E(0)|/E(0) {:.2e}",
            r.energy_max_deviation
        )),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zero_crossings_of_a_sine() {
        let t: Vec<f64> = (0..400).map(|k| k as f64 * 0.01).collect();
        let u: Vec<f64> = t.iter().map(|t| (2.0 * t + 0.3).sin()).collect();
        let zc = zero_crossings(&t, &u);
        let pi = std::f64::consts::PI;
        assert_eq!(zc.len(), 2);
        for (k, z) in zc.iter().enumerate() {
            let exact = ((k + 1) as f64 * pi - 0.3) / 2.0;
            assert!((z - exact).abs() < 1e-5, "{z} vs {exact}");
        }
    }
}
