//! `powderlab study error-vs-time`: what accuracy each second of run time buys.
//!
//! Two cases, each swept along three knobs separately:
//! - **column collapse** (the validation case): a planar column of aspect ratio
//!   [`COLLAPSE_ASPECT`] and length 5 cm collapses to rest; the quantity is the run-out ΔL/L₀,
//!   which also has a published law (Lube et al. 2005, `ΔL/L₀ ≈ 1.2a`);
//! - **powder transport** (the task case): the shipped `powder_transport` scene at its own skill
//!   Θ; the quantities are the powder in the target cup at the end (g), the loss per particle
//!   (the mean distance to the target, m) and, on the resolution sweep, the gradient `∂L/∂Θ`
//!   per particle.
//!
//! The knobs are the grid resolution (the cell size, with the CFL number and every length in
//! metres held fixed), the particles per cell, and the substeps per step. Each configuration
//! runs in a child process of its own, so that its peak memory is its own.
//!
//! Errors are relative, against the finest resolution of the same case (the case's
//! *reference*), against the finest configuration of the same sweep, and against the published
//! law where there is one; the gradient is also compared with a central difference along a fixed
//! direction of Θ at the same resolution. The Pareto front marks the configurations that no other
//! configuration beats on both run time and error.

pub mod growth;
pub mod plot;

use crate::adjoint::tape::Loss;
use crate::optim::problem::Problem;
use crate::scene::Scene;
use crate::util::{peak_rss_bytes, write_atomic, SplitMix64};
use crate::validate::{deposit_front, lube_runout, run_collapse, Collapse, COLLAPSE_SLAB_CELLS};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Aspect ratio of the study's column (the middle of the published small-a band).
pub const COLLAPSE_ASPECT: f64 = 1.0;
/// Length L₀ of the study's column (m), as in `validate column_collapse`.
pub const COLLAPSE_LENGTH: f64 = 0.05;
/// Step of the central difference along Θ: small enough that no phase's step count changes (as
/// in `gradcheck --params skill`), large enough to stay far above the round-off of the loss.
pub const FD_EPS: f64 = 1e-7;
/// Deposit height, as a fraction of H₀, that the fixed-height front counts: 1 % of H₀ (0.5 mm
/// for the study's column). `validate`'s front counts a layer an eighth of a cell high, which
/// thins with the grid; this one is the same physical layer at every resolution. (It was meant
/// as 2 % over a slab two cells deep; the slab is now four, and the particle count per bin, which
/// is what the study measured, is unchanged: 1 % over four cells.)
pub const FRONT_HEIGHT_FRACTION: f64 = 0.01;
/// Memory budget of one backward pass's tape (bytes): the finest transport level's full tape
/// would be about 4.5 GB, so it checkpoints, and its time includes the recomputation.
pub const TAPE_BUDGET: usize = 2048 << 20;

/// Which case a configuration runs.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[serde(rename_all = "snake_case")]
pub enum Case {
    ColumnCollapse,
    PowderTransport,
}

impl Case {
    pub fn name(self) -> &'static str {
        match self {
            Case::ColumnCollapse => "column_collapse",
            Case::PowderTransport => "powder_transport",
        }
    }
}

/// Which knob a configuration varies.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[serde(rename_all = "snake_case")]
pub enum Sweep {
    Resolution,
    ParticlesPerCell,
    Substeps,
}

impl Sweep {
    pub fn name(self) -> &'static str {
        match self {
            Sweep::Resolution => "resolution",
            Sweep::ParticlesPerCell => "particles_per_cell",
            Sweep::Substeps => "substeps",
        }
    }
}

/// One configuration of the study.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Config {
    pub case: Case,
    pub sweep: Sweep,
    /// Cell size (m).
    pub dx: f64,
    pub particles_per_cell: usize,
    /// Collapse: the CFL number, from which the stability guard sets the substeps.
    pub cfl: Option<f64>,
    /// Transport: substeps per step (the guard may only raise them).
    pub substeps: Option<usize>,
    /// Transport: also compute `∂L/∂Θ` and its central difference.
    pub gradient: bool,
    /// Transport: global steps (default: the scene's horizon).
    pub steps: Option<usize>,
    /// Transport: the scene file.
    pub scene: Option<PathBuf>,
    pub threads: Option<usize>,
}

impl Config {
    /// A short label for progress and plots.
    pub fn label(&self) -> String {
        let knob = match self.sweep {
            Sweep::Resolution => format!("dx {:.3} mm", self.dx * 1e3),
            Sweep::ParticlesPerCell => format!("{} ppc", self.particles_per_cell),
            Sweep::Substeps => match (self.cfl, self.substeps) {
                (Some(c), _) => format!("CFL {c}"),
                (_, Some(n)) => format!("{n} substeps"),
                _ => "default substeps".into(),
            },
        };
        format!("{} {}: {knob}", self.case.name(), self.sweep.name())
    }

    /// Orders the configurations of one sweep from coarsest to finest.
    fn fineness(&self) -> f64 {
        match self.sweep {
            Sweep::Resolution => -self.dx,
            Sweep::ParticlesPerCell => self.particles_per_cell as f64,
            Sweep::Substeps => self.substeps.unwrap_or(0) as f64 + 1.0 / self.cfl.unwrap_or(1.0),
        }
    }
}

/// `∂L/∂Θ` of one transport configuration, per particle.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct GradientResult {
    /// `∂L/∂Θ` over the particle count.
    pub per_particle: [f64; 5],
    /// Forward and backward pass, recomputation included (s).
    pub wall_s: f64,
    /// Peak resident memory of the child after the backward pass (bytes).
    pub peak_rss_bytes: u64,
    /// Unit direction of the central difference.
    pub direction: [f64; 5],
    /// `∂L/∂Θ · u` over the particle count, from the adjoint.
    pub directional_adjoint: f64,
    /// `(L(Θ + εu) − L(Θ − εu))/2ε` over the particle count.
    pub directional_fd: f64,
    pub fd_eps: f64,
}

/// What one configuration measured.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct ConfigResult {
    pub config: Config,
    pub particles: usize,
    /// Substeps per global step, as the stability guard set them.
    pub substeps_per_step: usize,
    pub steps: usize,
    /// Wall time of the forward run, scene set-up included (s).
    pub wall_s: f64,
    /// Peak resident memory of the child process after the forward run (bytes).
    pub peak_rss_bytes: u64,
    /// Measured quantities by name (see [`quantities`]).
    pub values: BTreeMap<String, f64>,
    pub gradient: Option<GradientResult>,
    /// Why the configuration failed, if it did; it is left out of the analysis.
    pub failed: Option<String>,
}

/// The quantities a case measures:
/// - `runout_ratio`: ΔL/L₀ with `validate`'s front (the furthest one-cell bin holding a layer an
///   eighth of a cell high);
/// - `runout_fixed_height_ratio`: ΔL/L₀ with the front of a layer [`FRONT_HEIGHT_FRACTION`]·H₀
///   high;
/// - `runout_p99_ratio`: ΔL/L₀ with the 99th percentile of the particles' distance from the
///   back wall as the front (granular.md's example), which a thin tip hardly moves;
/// - `transported_g`: the powder in the target cup at the end (g);
/// - `mean_distance_m`: the eq. 5 loss over the particle count (m);
/// - `gradient`: `∂L/∂Θ` over the particle count.
pub fn quantities(case: Case) -> &'static [&'static str] {
    match case {
        Case::ColumnCollapse => &[
            "runout_ratio",
            "runout_fixed_height_ratio",
            "runout_p99_ratio",
        ],
        Case::PowderTransport => &["transported_g", "mean_distance_m", "gradient"],
    }
}

/// Substeps per step that keep a scene's CFL number at cell size `dx`: its own substeps scaled
/// by its cell size over `dx`, rounded up.
pub fn substeps_at(scene: &Scene, dx: f64) -> usize {
    ((scene.simulation.substeps as f64 * scene.simulation.dx / dx) - 1e-9).ceil() as usize
}

/// `θ + s·u`: a point on the line through `θ` along `u`.
pub fn along(theta: [f64; 5], u: &[f64; 5], s: f64) -> [f64; 5] {
    let mut t = theta;
    t.iter_mut().zip(u).for_each(|(t, u)| *t += s * u);
    t
}

/// The first `n` random Θ at which the diagnostic examples take secants: uniform in
/// [−0.8, 0.8]⁵ from a fixed generator, so that `gradient_at_scale`'s point `k` and
/// `gradient_by_region`'s `randK` are the same Θ.
pub fn secant_thetas(n: usize) -> Vec<[f64; 5]> {
    let mut rng = SplitMix64(1234);
    (0..n)
        .map(|_| std::array::from_fn(|_| rng.uniform_in(-0.8, 0.8)))
        .collect()
}

/// Θ from the command line of the diagnostic examples: five comma-separated values.
pub fn parse_theta(s: &str) -> anyhow::Result<[f64; 5]> {
    let v = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| anyhow::anyhow!("THETA {s:?}: {e}; give five comma-separated numbers"))?;
    v.try_into()
        .map_err(|v: Vec<f64>| anyhow::anyhow!("THETA {s:?} has {} values; give five", v.len()))
}

/// A skill scene as the diagnostic examples take it: as loaded (`None` or `-`), or re-gridded
/// at the cell size `dx` (metres) as the error-vs-time study does.
pub fn regrid(scene: Scene, dx: Option<&str>) -> anyhow::Result<Scene> {
    match dx {
        None | Some("-") => Ok(scene),
        Some(dx) => {
            let dx: f64 = dx.parse().map_err(|e| {
                anyhow::anyhow!("DX_M {dx:?}: {e}; give a cell size in metres or -")
            })?;
            transport_scene(&transport_at(&scene, dx, true, None))
        }
    }
}

/// A transport configuration on the resolution sweep at cell size `dx`, with the substeps that
/// keep the scene's CFL number.
pub fn transport_at(scene: &Scene, dx: f64, gradient: bool, threads: Option<usize>) -> Config {
    Config {
        case: Case::PowderTransport,
        sweep: Sweep::Resolution,
        dx,
        particles_per_cell: scene.bodies.first().map_or(8, |b| b.particles_per_cell),
        cfl: None,
        substeps: Some(substeps_at(scene, dx)),
        gradient,
        steps: None,
        scene: Some(scene.path.clone()),
        threads,
    }
}

/// The plans: `full` is the study in the README; `quick` is a seconds-long version for tests.
/// The transport levels are multiples of the scene's own cell size (5 mm for the shipped scene),
/// and its particles per cell and substeps are the other sweeps' base.
pub fn plan(
    quick: bool,
    transport_scene: &Path,
    threads: Option<usize>,
) -> anyhow::Result<Vec<Config>> {
    let scene = Scene::load(transport_scene)?;
    let collapse = |sweep, cells: usize, ppc, cfl| Config {
        case: Case::ColumnCollapse,
        sweep,
        dx: COLLAPSE_LENGTH / cells as f64,
        particles_per_cell: ppc,
        cfl: Some(cfl),
        substeps: None,
        gradient: false,
        steps: None,
        scene: None,
        threads,
    };
    let dx0 = scene.simulation.dx;
    // Another sweep at cell size `dx`: the resolution sweep's configuration with one knob moved.
    let varied = |sweep, dx: f64, ppc: Option<usize>, substeps: Option<usize>| {
        let base = transport_at(&scene, dx, false, threads);
        Config {
            sweep,
            particles_per_cell: ppc.unwrap_or(base.particles_per_cell),
            substeps: substeps.or(base.substeps),
            ..base
        }
    };
    let mut out = Vec::new();
    if quick {
        for cells in [4, 6, 8] {
            out.push(collapse(Sweep::Resolution, cells, 8, 0.5));
        }
        out.push(collapse(Sweep::ParticlesPerCell, 6, 1, 0.5));
        out.push(collapse(Sweep::Substeps, 6, 8, 1.0));
        let dx = 1.5 * dx0;
        for k in [1.5, 1.25] {
            out.push(transport_at(&scene, k * dx0, true, threads));
        }
        out.push(varied(Sweep::ParticlesPerCell, dx, Some(1), None));
        out.push(varied(
            Sweep::Substeps,
            dx,
            None,
            Some(2 * substeps_at(&scene, dx)),
        ));
        for c in &mut out {
            if c.case == Case::PowderTransport {
                c.steps = Some(30);
            }
        }
        return Ok(out);
    }
    // Column collapse: the validation runs use 20 cells across L₀, 8 ppc and CFL 0.5.
    for cells in [5, 7, 10, 14, 20, 28, 40] {
        out.push(collapse(Sweep::Resolution, cells, 8, 0.5));
    }
    for ppc in [1, 27, 64] {
        out.push(collapse(Sweep::ParticlesPerCell, 20, ppc, 0.5));
    }
    for cfl in [1.0, 0.25, 0.125, 0.0625] {
        out.push(collapse(Sweep::Substeps, 20, 8, cfl));
    }
    for k in [1.5, 1.25, 1.0, 0.75, 0.5] {
        out.push(transport_at(&scene, k * dx0, true, threads));
    }
    for ppc in [1, 27, 64] {
        out.push(varied(Sweep::ParticlesPerCell, dx0, Some(ppc), None));
    }
    for k in [2, 4, 8] {
        out.push(varied(
            Sweep::Substeps,
            dx0,
            None,
            Some(k * scene.simulation.substeps),
        ));
    }
    Ok(out)
}

/// The transport scene at the configuration's resolution: every length in metres (domain,
/// cups, spoon, contact bands) is kept, and the grid, particles per cell and substeps change.
/// The domain walls stay 3 node layers, as in both shipped transport scenes.
pub fn transport_scene(cfg: &Config) -> anyhow::Result<Scene> {
    let path = cfg
        .scene
        .as_ref()
        .ok_or_else(|| anyhow::anyhow!("a transport configuration needs its scene"))?;
    let mut s = Scene::load(path)?;
    let dx0 = s.simulation.dx;
    let cells = |n: usize| ((n as f64 * dx0 / cfg.dx) - 1e-9).ceil() as usize;
    let (nx, ny, nz) = s.simulation.cells;
    s.simulation.cells = (cells(nx), cells(ny), cells(nz));
    s.simulation.dx = cfg.dx;
    if let Some(n) = cfg.substeps {
        s.simulation.substeps = n;
    }
    if cfg.steps.is_some() {
        s.simulation.steps = cfg.steps;
    }
    if let Some(t) = cfg.threads {
        s.simulation.threads = t;
    }
    for b in &mut s.bodies {
        b.particles_per_cell = cfg.particles_per_cell;
    }
    for c in &mut s.colliders {
        c.band_cells *= dx0 / cfg.dx;
    }
    s.record = None;
    s.validate()?;
    Ok(s)
}

fn run_collapse_config(cfg: &Config) -> anyhow::Result<ConfigResult> {
    let mut c = Collapse::new(COLLAPSE_ASPECT, (COLLAPSE_LENGTH / cfg.dx).round() as usize);
    c.length = COLLAPSE_LENGTH;
    c.particles_per_cell = cfg.particles_per_cell;
    c.cfl = cfg.cfl.unwrap_or(0.5);
    let r = run_collapse(&c, cfg.threads, |_| {})?;
    let mut values = BTreeMap::new();
    values.insert("runout_ratio".to_string(), r.runout_ratio);
    let l0 = c.length;
    let mut xs: Vec<f64> = r.deposit.iter().map(|p| p.x * l0).collect();
    // A one-cell bin of the slab holds COLLAPSE_SLAB_CELLS·ppc particles per cell of height, so
    // a layer h high is COLLAPSE_SLAB_CELLS·ppc·h/dx particles.
    let h = FRONT_HEIGHT_FRACTION * c.aspect * l0;
    let per_height = (COLLAPSE_SLAB_CELLS * c.particles_per_cell) as f64;
    let n_min = ((per_height * h / cfg.dx).ceil() as usize).max(1);
    values.insert(
        "runout_fixed_height_ratio".to_string(),
        (deposit_front(&xs, cfg.dx, n_min) - l0) / l0,
    );
    xs.sort_by(f64::total_cmp);
    let p99 = xs[((0.99 * (xs.len() - 1) as f64).round()) as usize];
    values.insert("runout_p99_ratio".to_string(), (p99 - l0) / l0);
    if let Some(t) = r.arrest_tc {
        values.insert("arrest_tc".to_string(), t);
    }
    if let Some(t) = r.front_arrest_tc {
        values.insert("front_arrest_tc".to_string(), t);
    }
    Ok(ConfigResult {
        config: cfg.clone(),
        particles: r.particles,
        substeps_per_step: r.substeps_per_step,
        steps: (r.substeps / r.substeps_per_step.max(1) as u64) as usize,
        wall_s: r.wall_s,
        peak_rss_bytes: peak_rss_bytes(),
        values,
        gradient: None,
        failed: None,
    })
}

fn run_transport_config(cfg: &Config) -> anyhow::Result<ConfigResult> {
    let problem = Problem::new(transport_scene(cfg)?, TAPE_BUDGET)?;
    let theta = problem.scene_theta();
    let fwd = problem.evaluate(theta, false, false)?;
    let rss = peak_rss_bytes();
    let particles = fwd.particles;
    // The eq. 5 loss sums over particles, whose number changes with the resolution: compare it
    // per particle (the mean distance to the target).
    let per = match problem.loss {
        Loss::SumDistance(_) => 1.0 / particles as f64,
        _ => 1.0,
    };
    let mut values = BTreeMap::new();
    values.insert("transported_g".to_string(), fwd.transported);
    values.insert("mean_distance_m".to_string(), fwd.loss * per);
    let gradient = if cfg.gradient {
        let g = problem.evaluate(theta, true, false)?;
        let rss = peak_rss_bytes();
        let grad = g.grad.expect("asked for the gradient");
        let u = [1.0 / 5f64.sqrt(); 5];
        let shifted = |s: f64| {
            problem
                .evaluate(along(theta, &u, s), false, false)
                .map(|o| o.loss)
        };
        let (lp, lm) = (shifted(FD_EPS)?, shifted(-FD_EPS)?);
        Some(GradientResult {
            per_particle: grad.map(|g| g * per),
            wall_s: g.wall_s,
            peak_rss_bytes: rss,
            direction: u,
            directional_adjoint: grad.iter().zip(&u).map(|(g, u)| g * u).sum::<f64>() * per,
            directional_fd: (lp - lm) / (2.0 * FD_EPS) * per,
            fd_eps: FD_EPS,
        })
    } else {
        None
    };
    Ok(ConfigResult {
        config: cfg.clone(),
        particles,
        substeps_per_step: fwd.substeps,
        steps: fwd.steps,
        wall_s: fwd.wall_s,
        peak_rss_bytes: rss,
        values,
        gradient,
        failed: None,
    })
}

/// Runs one configuration in this process.
pub fn run_config(cfg: &Config) -> anyhow::Result<ConfigResult> {
    match cfg.case {
        Case::ColumnCollapse => run_collapse_config(cfg),
        Case::PowderTransport => run_transport_config(cfg),
    }
}

/// A configuration that failed, with its reason.
pub fn failed(cfg: &Config, why: String) -> ConfigResult {
    ConfigResult {
        config: cfg.clone(),
        particles: 0,
        substeps_per_step: 0,
        steps: 0,
        wall_s: 0.0,
        peak_rss_bytes: 0,
        values: BTreeMap::new(),
        gradient: None,
        failed: Some(why),
    }
}

/// One row of the analysis: one quantity of one configuration.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Row {
    pub case: Case,
    pub sweep: Sweep,
    pub label: String,
    pub dx_m: f64,
    pub particles_per_cell: usize,
    pub substeps_per_step: usize,
    pub particles: usize,
    pub quantity: String,
    /// The value (for the gradient: the norm of `∂L/∂Θ` per particle).
    pub value: f64,
    /// The case's reference value: its finest resolution.
    pub reference_value: Option<f64>,
    /// Relative error against the reference (for the gradient: `‖g − g_ref‖/‖g_ref‖`).
    pub error_vs_reference: Option<f64>,
    /// Relative error against the finest configuration of the same sweep.
    pub error_vs_sweep_finest: Option<f64>,
    pub law_value: Option<f64>,
    pub error_vs_law: Option<f64>,
    /// Gradient only: `|g·u − FD|/max(|g·u|, |FD|)` along the direction `u`.
    pub error_vs_fd: Option<f64>,
    /// Wall time of what produced the value (s): the forward run, or forward + backward.
    pub wall_s: f64,
    pub peak_rss_bytes: u64,
    /// This configuration is the case's reference.
    pub is_reference: bool,
    /// On the Pareto front of error against the reference versus wall time.
    pub pareto: bool,
    /// On the Pareto front of error against the law versus wall time.
    pub pareto_vs_law: bool,
}

/// `|a − b|/|b|`; against a reference of zero, 0 if `a` is zero too and ∞ otherwise (a run
/// that moved powder where the reference moved none has no finite relative error).
fn rel(a: f64, b: f64) -> f64 {
    if b == 0.0 {
        if a == 0.0 {
            0.0
        } else {
            f64::INFINITY
        }
    } else {
        (a - b).abs() / b.abs()
    }
}

/// Euclidean length.
pub fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// The cosine of the angle between `a` and `b` (NaN when either is zero).
pub fn cosine(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>() / (norm(a) * norm(b))
}

/// Relative distance between two gradients, `‖a − b‖/‖b‖`.
pub fn gradient_error(a: &[f64; 5], b: &[f64; 5]) -> f64 {
    let d: Vec<f64> = a.iter().zip(b).map(|(a, b)| a - b).collect();
    norm(&d) / norm(b).max(1e-300)
}

/// The finest result of each (case, sweep), and each case's reference (the finest resolution).
fn finest(results: &[ConfigResult], case: Case, sweep: Sweep) -> Option<&ConfigResult> {
    results
        .iter()
        .filter(|r| r.failed.is_none() && r.config.case == case && r.config.sweep == sweep)
        .max_by(|a, b| a.config.fineness().total_cmp(&b.config.fineness()))
}

fn value_of(r: &ConfigResult, q: &str) -> Option<f64> {
    if q == "gradient" {
        r.gradient.as_ref().map(|g| norm(&g.per_particle))
    } else {
        r.values.get(q).copied()
    }
}

fn error_of(r: &ConfigResult, reference: &ConfigResult, q: &str) -> Option<f64> {
    if q == "gradient" {
        Some(gradient_error(
            &r.gradient.as_ref()?.per_particle,
            &reference.gradient.as_ref()?.per_particle,
        ))
    } else {
        Some(rel(value_of(r, q)?, value_of(reference, q)?))
    }
}

/// Marks the Pareto front: the points that no faster point matches or beats on error.
/// `points` are (wall time, error); the answer has one flag per point.
pub fn pareto_front(points: &[(f64, f64)]) -> Vec<bool> {
    let mut order: Vec<usize> = (0..points.len()).collect();
    order.sort_by(|&a, &b| {
        points[a]
            .0
            .total_cmp(&points[b].0)
            .then(points[a].1.total_cmp(&points[b].1))
    });
    let mut flags = vec![false; points.len()];
    let mut best = f64::INFINITY;
    for i in order {
        if points[i].1 < best {
            flags[i] = true;
            best = points[i].1;
        }
    }
    flags
}

/// The analysis: one row per configuration and quantity, errors and Pareto fronts.
pub fn analyse(results: &[ConfigResult]) -> Vec<Row> {
    let mut rows = Vec::new();
    for case in [Case::ColumnCollapse, Case::PowderTransport] {
        let reference = finest(results, case, Sweep::Resolution);
        for &q in quantities(case) {
            let start = rows.len();
            for r in results
                .iter()
                .filter(|r| r.failed.is_none() && r.config.case == case)
            {
                let Some(value) = value_of(r, q) else {
                    continue;
                };
                let is_reference = reference.is_some_and(|f| f.config == r.config);
                let sweep_finest = finest(results, case, r.config.sweep);
                // The published run-out is where the deposit ends: the fronts, not the percentile.
                let law = (case == Case::ColumnCollapse && q != "runout_p99_ratio")
                    .then(|| lube_runout(COLLAPSE_ASPECT));
                let g = if q == "gradient" {
                    r.gradient.as_ref()
                } else {
                    None
                };
                rows.push(Row {
                    case,
                    sweep: r.config.sweep,
                    label: r.config.label(),
                    dx_m: r.config.dx,
                    particles_per_cell: r.config.particles_per_cell,
                    substeps_per_step: r.substeps_per_step,
                    particles: r.particles,
                    quantity: q.to_string(),
                    value,
                    reference_value: reference.and_then(|f| value_of(f, q)),
                    error_vs_reference: reference.and_then(|f| error_of(r, f, q)),
                    error_vs_sweep_finest: sweep_finest.and_then(|f| error_of(r, f, q)),
                    law_value: law,
                    error_vs_law: law.map(|l| rel(value, l)),
                    error_vs_fd: g.map(|g| {
                        (g.directional_adjoint - g.directional_fd).abs()
                            / g.directional_adjoint
                                .abs()
                                .max(g.directional_fd.abs())
                                .max(1e-300)
                    }),
                    wall_s: g.map_or(r.wall_s, |g| g.wall_s),
                    peak_rss_bytes: g.map_or(r.peak_rss_bytes, |g| g.peak_rss_bytes),
                    is_reference,
                    pareto: false,
                    pareto_vs_law: false,
                });
            }
            let block = &mut rows[start..];
            for law in [false, true] {
                let error = |r: &Row| {
                    if law {
                        r.error_vs_law
                    } else {
                        r.error_vs_reference
                    }
                };
                // The reference's own error is zero by construction: it is not a point of the
                // trade-off against itself, but it is one against the law.
                let idx: Vec<usize> = (0..block.len())
                    .filter(|&i| law || !block[i].is_reference)
                    .filter(|&i| error(&block[i]).is_some_and(|e| e.is_finite() && e > 0.0))
                    .collect();
                let pts: Vec<(f64, f64)> = idx
                    .iter()
                    .map(|&i| (block[i].wall_s, error(&block[i]).unwrap_or(f64::NAN)))
                    .collect();
                for (k, on) in pareto_front(&pts).into_iter().enumerate() {
                    if law {
                        block[idx[k]].pareto_vs_law = on;
                    } else {
                        block[idx[k]].pareto = on;
                    }
                }
            }
        }
    }
    rows
}

fn opt(v: Option<f64>) -> String {
    v.map_or(String::new(), |v| format!("{v:.6e}"))
}

/// The analysis as CSV, one row per configuration and quantity.
pub fn csv(rows: &[Row]) -> String {
    let mut s = String::from(
        "case,sweep,dx_m,particles_per_cell,substeps_per_step,particles,quantity,value,\
         reference_value,error_vs_reference,error_vs_sweep_finest,law_value,error_vs_law,\
         error_vs_fd,wall_s,peak_rss_bytes,is_reference,pareto,pareto_vs_law\n",
    );
    for r in rows {
        s.push_str(&format!(
            "{},{},{},{},{},{},{},{:.6e},{},{},{},{},{},{},{:.3},{},{},{},{}\n",
            r.case.name(),
            r.sweep.name(),
            r.dx_m,
            r.particles_per_cell,
            r.substeps_per_step,
            r.particles,
            r.quantity,
            r.value,
            opt(r.reference_value),
            opt(r.error_vs_reference),
            opt(r.error_vs_sweep_finest),
            opt(r.law_value),
            opt(r.error_vs_law),
            opt(r.error_vs_fd),
            r.wall_s,
            r.peak_rss_bytes,
            r.is_reference,
            r.pareto,
            r.pareto_vs_law,
        ));
    }
    s
}

/// A Markdown table of the analysis (for the README and the terminal).
pub fn markdown(rows: &[Row]) -> String {
    let pct = |v: Option<f64>| v.map_or(String::new(), crate::util::percent);
    let mut s = String::from(
        "| case | sweep | dx (mm) | ppc | substeps | particles | quantity | value | err vs finest | err vs law | err vs FD | wall (s) | peak RSS (MB) | Pareto |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        s.push_str(&format!(
            "| {} | {} | {:.3} | {} | {} | {} | {} | {:.4e} | {} | {} | {} | {:.1} | {:.0} | {} |\n",
            r.case.name(),
            r.sweep.name(),
            r.dx_m * 1e3,
            r.particles_per_cell,
            r.substeps_per_step,
            r.particles,
            r.quantity,
            r.value,
            if r.is_reference {
                "reference".to_string()
            } else {
                pct(r.error_vs_reference)
            },
            pct(r.error_vs_law),
            pct(r.error_vs_fd),
            r.wall_s,
            r.peak_rss_bytes as f64 / 1e6,
            if r.pareto { "●" } else { "" },
        ));
    }
    s
}

/// Where the study writes.
pub struct Outputs {
    pub results: PathBuf,
    pub csv: PathBuf,
    pub svg: PathBuf,
    pub markdown: PathBuf,
}

impl Outputs {
    pub fn in_dir(dir: &Path) -> Outputs {
        Outputs {
            results: dir.join("results.json"),
            csv: dir.join("error_vs_time.csv"),
            svg: dir.join("error_vs_time.svg"),
            markdown: dir.join("error_vs_time.md"),
        }
    }
}

/// Writes the analysis of the results so far (each file atomically).
pub fn write_outputs(out: &Outputs, results: &[ConfigResult]) -> anyhow::Result<Vec<Row>> {
    write_atomic(
        &out.results,
        serde_json::to_string_pretty(results)?.as_bytes(),
    )?;
    let rows = analyse(results);
    write_atomic(&out.csv, csv(&rows).as_bytes())?;
    write_atomic(&out.markdown, markdown(&rows).as_bytes())?;
    plot::error_vs_time_svg(&out.svg, &rows)?;
    Ok(rows)
}

/// Runs the plan, one configuration at a time through `exec`, writing every output after each
/// configuration, so an interrupted study keeps what it finished. With `resume`, configurations
/// already in `results.json` are not run again.
pub fn run_study(
    plan: &[Config],
    dir: &Path,
    resume: bool,
    mut exec: impl FnMut(&Config) -> ConfigResult,
    mut progress: impl FnMut(usize, &Config),
) -> anyhow::Result<(Vec<ConfigResult>, Vec<Row>)> {
    crate::util::create_output_dir(dir, "--out")?;
    let out = Outputs::in_dir(dir);
    let mut done: Vec<ConfigResult> = if resume && out.results.exists() {
        let text = std::fs::read_to_string(&out.results)?;
        serde_json::from_str(&text).map_err(|e| {
            anyhow::anyhow!(
                "{}: not a study's results ({e}); delete it or run without --resume",
                out.results.display()
            )
        })?
    } else {
        Vec::new()
    };
    // Keep only what this plan asks for and what succeeded; the rest runs (again).
    done.retain(|r| r.failed.is_none() && plan.contains(&r.config));
    let mut results = Vec::new();
    for (i, cfg) in plan.iter().enumerate() {
        progress(i, cfg);
        if let Some(r) = done.iter().find(|r| &r.config == cfg) {
            results.push(r.clone());
            continue;
        }
        results.push(exec(cfg));
        write_outputs(&out, &results)?;
    }
    let rows = write_outputs(&out, &results)?;
    Ok((results, rows))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pareto_front_keeps_the_undominated_points() {
        let pts = [
            (1.0, 0.5),
            (2.0, 0.6),
            (3.0, 0.1),
            (0.5, 0.9),
            (4.0, 0.1),
            (5.0, 0.01),
        ];
        assert_eq!(
            pareto_front(&pts),
            vec![true, false, true, true, false, true]
        );
    }

    #[test]
    fn theta_takes_exactly_five_numbers() {
        assert_eq!(
            parse_theta("0.3, 0.2,0,-1,1").unwrap(),
            [0.3, 0.2, 0.0, -1.0, 1.0]
        );
        assert!(parse_theta("0.3,0.2,0,-1")
            .unwrap_err()
            .to_string()
            .contains("has 4 values"));
        assert!(parse_theta("0.3,x,0,-1,1").is_err());
    }

    fn collapse_result(
        sweep: Sweep,
        cells: usize,
        cfl: f64,
        runout: f64,
        wall_s: f64,
    ) -> ConfigResult {
        let cfg = Config {
            case: Case::ColumnCollapse,
            sweep,
            dx: COLLAPSE_LENGTH / cells as f64,
            particles_per_cell: 8,
            cfl: Some(cfl),
            substeps: None,
            gradient: false,
            steps: None,
            scene: None,
            threads: None,
        };
        ConfigResult {
            config: cfg,
            particles: 100,
            substeps_per_step: 1,
            steps: 1,
            wall_s,
            peak_rss_bytes: 1,
            values: [("runout_ratio".to_string(), runout)].into(),
            gradient: None,
            failed: None,
        }
    }

    #[test]
    fn analysis_measures_errors_against_the_finest_grid_the_sweep_and_the_law() {
        let results = vec![
            collapse_result(Sweep::Resolution, 5, 0.5, 2.0, 1.0),
            collapse_result(Sweep::Resolution, 10, 0.5, 1.6, 4.0),
            collapse_result(Sweep::Resolution, 20, 0.5, 1.5, 16.0),
            collapse_result(Sweep::Substeps, 10, 0.25, 1.8, 8.0),
            collapse_result(Sweep::Substeps, 10, 0.125, 1.65, 12.0),
            failed(
                &collapse_result(Sweep::Resolution, 40, 0.5, 0.0, 0.0).config,
                "out of memory".into(),
            ),
        ];
        let rows = analyse(&results);
        // The failed configuration is left out; the reference is the finest that succeeded.
        assert_eq!(rows.len(), 5);
        let by = |cells: usize, cfl: f64| {
            rows.iter()
                .find(|r| {
                    (r.dx_m - COLLAPSE_LENGTH / cells as f64).abs() < 1e-15
                        && (r.sweep == Sweep::Resolution) == (cfl == 0.5)
                        && (cfl == 0.5 || r.label.contains(&format!("CFL {cfl}")))
                })
                .unwrap()
        };
        let r5 = by(5, 0.5);
        assert!((r5.error_vs_reference.unwrap() - 0.5 / 1.5).abs() < 1e-12);
        assert!((r5.error_vs_law.unwrap() - 0.8 / 1.2).abs() < 1e-12);
        assert!(by(20, 0.5).is_reference);
        assert_eq!(by(20, 0.5).error_vs_reference, Some(0.0));
        // Within the substep sweep the finest is CFL 0.125.
        let s = by(10, 0.25);
        assert!((s.error_vs_sweep_finest.unwrap() - 0.15 / 1.65).abs() < 1e-12);
        assert!((s.error_vs_reference.unwrap() - 0.3 / 1.5).abs() < 1e-12);
        // Fronts: against the reference 5 cells (fastest), then 10 cells (0.067 at 4 s) …
        // CFL 0.25 (0.2 at 8 s) and CFL 0.125 (0.1 at 12 s) are beaten by 10 cells.
        let front: Vec<bool> = [(5, 0.5), (10, 0.5), (10, 0.25), (10, 0.125)]
            .iter()
            .map(|&(c, f)| by(c, f).pareto)
            .collect();
        assert_eq!(front, vec![true, true, false, false]);
        assert!(
            !by(20, 0.5).pareto,
            "the reference is not a point against itself"
        );
        // … and against the law the reference may be on the front (it is the closest here).
        assert!(by(20, 0.5).pareto_vs_law);
    }

    #[test]
    fn gradient_error_is_relative_to_the_reference() {
        let a = [1.0, 0.0, 0.0, 0.0, 0.0];
        let b = [2.0, 0.0, 0.0, 0.0, 0.0];
        assert_eq!(gradient_error(&a, &b), 0.5);
    }

    #[test]
    fn the_full_plan_sweeps_four_resolutions_or_more_per_case() {
        let p = plan(false, Path::new("scenes/powder_transport.ron"), None).unwrap();
        for case in [Case::ColumnCollapse, Case::PowderTransport] {
            let n = p
                .iter()
                .filter(|c| c.case == case && c.sweep == Sweep::Resolution)
                .count();
            assert!(n >= 4, "{case:?}: {n} resolutions");
        }
        // Substeps scale with 1/dx: the CFL number of the shipped scene at every level.
        let sub: Vec<usize> = p
            .iter()
            .filter(|c| c.case == Case::PowderTransport && c.sweep == Sweep::Resolution)
            .map(|c| c.substeps.unwrap())
            .collect();
        assert_eq!(sub, vec![8, 10, 12, 16, 24]);
    }
}
