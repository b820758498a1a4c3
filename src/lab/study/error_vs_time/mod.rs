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

pub mod analysis;
mod command;
pub mod plot;

pub use command::ErrorVsTime;

pub use analysis::*;

use crate::adjoint::tape::Loss;
use crate::lab::optim::problem::Problem;
use crate::lab::validate::{deposit_front, run_collapse, Collapse, COLLAPSE_SLAB_CELLS};
use crate::scene::Scene;
use crate::skills::Theta;
use crate::util::{peak_rss_bytes, write_atomic};
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
pub fn along(theta: Theta, u: &[f64; 5], s: f64) -> Theta {
    let mut t = theta;
    t.iter_mut().zip(u).for_each(|(t, u)| *t += s * u);
    t
}

/// Θ from the command line of the diagnostic examples: five comma-separated values.
pub fn parse_theta(s: &str) -> anyhow::Result<Theta> {
    let v = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| anyhow::anyhow!("THETA {s:?}: {e}; give five comma-separated numbers"))?;
    <[f64; 5]>::try_from(v)
        .map(Theta)
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

/// The plans: `full` is the study of `docs/results/error_vs_time.md`; `quick` is a seconds-long version for tests.
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
    let per = match problem.loss() {
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
mod tests;
