//! The self-weight column (CB-Geo MPM verification).
//!
//! An elastic column of height `H` between slip walls (no lateral displacement, so the state is
//! one-dimensional) on a slip floor, under gravity. At rest the vertical stress is
//! `σ_yy = −ρ₀·g·(H − Y)`, with `Y` the particle's initial height above the floor: the weight of
//! the material above a point does not change as the column compresses, and the walls keep the
//! cross-section fixed.
//!
//! The model has no damping, so a column released under full gravity would ring about its rest
//! state with the full static amplitude. Gravity is instead ramped in smoothly
//! ([`smooth_ramp`]) over four periods of the fundamental mode, `T₁ = 4H/c` with c the confined
//! wave speed `√((λ+2μ)/ρ)`, and the stress of the bottom particle layer is then averaged over
//! every substep of four more periods, which also averages out what ringing is left. The error
//! is that average against the exact value at the layer, over `ρ₀gH`. Three resolutions give
//! the observed convergence order.

use super::{build, smooth_ramp, Check};
use crate::components::{Body, DeformationGradient, SimParams};
use crate::math::return_map::{hencky, kirchhoff_principal};
use crate::math::svd::svd3;
use bevy_ecs::world::World;
use glam::DVec3;
use serde::Serialize;

/// Observed convergence order of the base stress required (granular.md: ≥ 0.8).
pub const COLUMN_MIN_ORDER: f64 = 0.8;

/// Settings of one self-weight column.
#[derive(Clone, Copy, Debug)]
pub struct Column {
    /// Cells along the height.
    pub cells: usize,
    pub height: f64,
    pub youngs: f64,
    pub poisson: f64,
    pub density: f64,
    /// Periods of the fundamental mode averaged over.
    pub periods: usize,
    /// A cube number.
    pub particles_per_cell: usize,
}

impl Column {
    pub fn new(cells: usize, particles_per_cell: usize) -> Column {
        Column {
            cells,
            height: 0.32,
            youngs: 3e6,
            poisson: 0.3,
            density: 1000.0,
            periods: 4,
            particles_per_cell,
        }
    }

    /// Confined (P-wave) speed √((λ+2μ)/ρ).
    pub fn wave_speed(&self) -> f64 {
        let (mu, lambda) = crate::math::return_map::lame(self.youngs, self.poisson);
        ((lambda + 2.0 * mu) / self.density).sqrt()
    }

    /// Period of the fundamental mode of the fixed–free column, `T₁ = 4H/c`.
    pub fn period(&self) -> f64 {
        4.0 * self.height / self.wave_speed()
    }
}

/// Outcome of one column.
#[derive(Clone, Debug, Serialize)]
pub struct ColumnResult {
    pub cells: usize,
    pub ppc: usize,
    /// Time-averaged σ_yy of the bottom particle layer (Pa).
    pub base_stress: f64,
    /// The exact σ_yy at that layer (Pa).
    pub exact: f64,
    /// |base_stress − exact| / (ρ₀gH).
    pub error: f64,
    /// RMS over the particle layers of the stress error, over ρ₀gH.
    pub rms_error: f64,
    /// Per particle layer: initial height above the floor, averaged σ_yy, exact σ_yy.
    #[serde(skip)]
    pub profile: Vec<(f64, f64, f64)>,
    pub particles: usize,
    pub substeps: u64,
    pub wall_s: f64,
}

/// The RON scene: slip walls on every face; the column fills the cross-section between the
/// wall planes (nodes 0..=2 and n−3..n−1 are walls) and stands on the floor plane y = 2dx.
pub fn column_scene(c: &Column) -> String {
    let dx = c.height / c.cells as f64;
    let width = 4usize;
    let n_lat = width + 5;
    let ny = c.cells + 9;
    let lo = 2.0 * dx;
    let dt = c.period() / 8.0;
    // Stable substeps at CFL 0.5, fixed here so that a step is exactly T₁/8.
    let substeps = (dt / (0.5 * dx / c.wave_speed())).ceil() as usize;
    format!(
        r#"Scene(
    simulation: (cells: ({n_lat}, {ny}, {n_lat}), dx: {dx}, dt: {dt}, substeps: {substeps},
                 stability: Strict, empty_node_ratio: 0.0,
                 walls: (cells: 3, contact: Slip, friction: 0.0)),
    materials: {{ "column": Elastic((density: {rho}, youngs_modulus: {e}, poisson_ratio: {nu})) }},
    bodies: [(name: "column", material: "column",
              fill: Box(min: ({lo}, {lo}, {lo}), max: ({hi}, {top}, {hi})), particles_per_cell: {ppc})],
)"#,
        rho = c.density,
        e = c.youngs,
        nu = c.poisson,
        hi = lo + width as f64 * dx,
        top = lo + c.height,
        ppc = c.particles_per_cell,
    )
}

/// The Cauchy stress of a particle of StVK-Hencky material with deformation gradient `f`:
/// `σ = U diag(τ) Uᵀ / J` with `τ` the principal Kirchhoff stresses.
pub fn cauchy(f: glam::DMat3, mu: f64, lambda: f64) -> glam::DMat3 {
    let d = svd3(f);
    let tau = kirchhoff_principal(hencky(d.s), mu, lambda);
    d.u * glam::DMat3::from_diagonal(tau) * d.u.transpose() / (d.s.x * d.s.y * d.s.z)
}

/// σ_yy (Cauchy) of a particle of StVK-Hencky material with deformation gradient `f`.
pub fn cauchy_yy(f: glam::DMat3, mu: f64, lambda: f64) -> f64 {
    cauchy(f, mu, lambda).y_axis.y
}

/// Runs one column and averages the base stress over whole periods.
pub fn run_column(c: &Column, threads: Option<usize>) -> anyhow::Result<ColumnResult> {
    let start = std::time::Instant::now();
    let (scene, mut sim) = build(
        &column_scene(c),
        &format!("self_weight_{}", c.cells),
        threads,
    )?;
    let dx = scene.simulation.dx;
    let floor = 2.0 * dx;
    let g = 9.81;
    // Particle layers by initial height above the floor (the lattice is regular).
    let y0: Vec<f64> = sim.body_states()[0].x.iter().map(|x| x.y - floor).collect();
    let h = dx / (c.particles_per_cell as f64).cbrt().round();
    let layer_of: Vec<usize> = y0.iter().map(|y| (y / h).floor() as usize).collect();
    let layers = layer_of.iter().max().map_or(0, |m| m + 1);
    let t_ramp = c.periods as f64 * c.period();
    let steps = 16 * c.periods;
    let mut sum = vec![0.0; y0.len()];
    let mut samples = 0usize;
    for _ in 0..steps {
        sim.step_with(|world, t| {
            world.resource_mut::<SimParams>().gravity =
                DVec3::new(0.0, -g * smooth_ramp(t, t_ramp), 0.0);
            if t >= t_ramp - 1e-12 {
                accumulate_stress(world, &mut sum);
                samples += 1;
            }
        })?;
    }
    let mut profile = vec![(0.0, 0.0, 0usize); layers];
    for (k, l) in layer_of.iter().enumerate() {
        profile[*l].0 += y0[k];
        profile[*l].1 += sum[k] / samples as f64;
        profile[*l].2 += 1;
    }
    let profile: Vec<(f64, f64, f64)> = profile
        .into_iter()
        .map(|(y, s, n)| {
            let (y, s) = (y / n as f64, s / n as f64);
            (y, s, -c.density * g * (c.height - y))
        })
        .collect();
    let scale = c.density * g * c.height;
    let rms =
        (profile.iter().map(|p| (p.1 - p.2).powi(2)).sum::<f64>() / layers as f64).sqrt() / scale;
    let (_, base, exact) = profile[0];
    Ok(ColumnResult {
        cells: c.cells,
        ppc: c.particles_per_cell,
        base_stress: base,
        exact,
        error: (base - exact).abs() / scale,
        rms_error: rms,
        profile,
        particles: sim.particle_count(),
        substeps: sim.clock().total_substeps,
        wall_s: start.elapsed().as_secs_f64(),
    })
}

/// Adds every particle's σ_yy to `sum`.
fn accumulate_stress(world: &mut World, sum: &mut [f64]) {
    let mut q = world.query::<(&Body, &DeformationGradient)>();
    let (b, f) = q.iter(world).next().expect("one body");
    let (mu, lambda) = b.lame;
    for (s, f) in sum.iter_mut().zip(&f.0) {
        *s += cauchy_yy(*f, mu, lambda);
    }
}

/// Checks of a resolution sweep: each error, and the observed order over the sweep.
pub fn column_checks(rs: &[ColumnResult]) -> Vec<Check> {
    let mut out = Vec::new();
    for r in rs {
        out.push(Check {
            case: "self_weight".into(),
            quantity: format!("base σ_yy (Pa), {} cells, {} ppc", r.cells, r.ppc),
            measured: r.base_stress,
            published: r.exact,
            tolerance: 0.0,
            kind: "reported",
            passed: r.base_stress.is_finite(),
            note: format!(
                "error {:.3e} of ρgH (RMS over the layers {:.3e}); {} particles, {} substeps, {:.1} s",
                r.error, r.rms_error, r.particles, r.substeps, r.wall_s
            ),
        });
    }
    if rs.len() >= 2 {
        let pts: Vec<(f64, f64)> = rs
            .iter()
            .map(|r| (1.0 / r.cells as f64, r.error.max(1e-300)))
            .collect();
        let order = super::loglog_slope(&pts);
        out.push(Check {
            case: "self_weight".into(),
            quantity: format!("observed order of the base-stress error, {} ppc", rs[0].ppc),
            measured: order,
            published: 1.0,
            tolerance: COLUMN_MIN_ORDER,
            kind: "m>=tol",
            passed: order >= COLUMN_MIN_ORDER,
            note: format!(
                "errors {:?} at {:?} cells",
                rs.iter()
                    .map(|r| format!("{:.2e}", r.error))
                    .collect::<Vec<_>>(),
                rs.iter().map(|r| r.cells).collect::<Vec<_>>()
            ),
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DMat3, DVec3};

    #[test]
    fn cauchy_yy_of_a_rotated_uniaxial_stretch() {
        let (mu, lambda) = crate::math::return_map::lame(1e6, 0.3);
        let s = DVec3::new(1.0, 0.98, 1.0);
        let r = DMat3::from_rotation_y(0.7);
        let f = r * DMat3::from_diagonal(s);
        // A rotation about y leaves the yy entry of σ = R diag(τ/J) Rᵀ unchanged.
        let tau = kirchhoff_principal(hencky(s), mu, lambda);
        let exact = tau.y / (s.x * s.y * s.z);
        let got = cauchy_yy(f, mu, lambda);
        assert!(
            (got - exact).abs() <= 1e-9 * exact.abs(),
            "{got} vs {exact}"
        );
    }
}
