//! The stability suite: stiff and extreme cases, each of which must end stable or refused with
//! a message, never in a NaN.
//!
//! Outcomes:
//! - `stable`: the run finished, every particle value is finite and (without a driven tool) the
//!   total energy never rose above its lowest value by more than
//!   [`crate::metrics::ENERGY_GAIN_TOL`] of the energy in play; the substeps used are recorded;
//! - `refused`: the scene was refused before it ran, with the message the user sees;
//! - `unstable`: finite but with a spurious energy gain (a defect);
//! - `failed`: a non-finite value stopped the run, or a state is non-finite (a defect).
//!
//! `powderlab validate stability` prints the table; the test `stability_suite` runs it.

use super::build;
use crate::components::DeformationGradient;
use crate::metrics::{frame_metrics, EnergyMonitor};
use crate::sim::Simulation;
use glam::{DMat3, DVec3};
use serde::Serialize;

/// What a case ended in.
#[derive(Clone, Debug, Serialize, PartialEq)]
#[serde(tag = "outcome", rename_all = "snake_case")]
pub enum Outcome {
    Stable {
        /// Substeps per step used, and what the scene asked for.
        substeps: usize,
        requested: usize,
        steps: usize,
        /// Largest particle speed at the end (m/s).
        max_speed: f64,
        /// Largest rise of the total energy over the energy in play.
        energy_gain: f64,
    },
    Refused {
        message: String,
    },
    Unstable {
        message: String,
    },
    Failed {
        message: String,
    },
}

impl Outcome {
    /// Stable or refused: what the suite accepts.
    pub fn acceptable(&self) -> bool {
        matches!(self, Outcome::Stable { .. } | Outcome::Refused { .. })
    }

    pub fn label(&self) -> &'static str {
        match self {
            Outcome::Stable { .. } => "stable",
            Outcome::Refused { .. } => "refused",
            Outcome::Unstable { .. } => "unstable",
            Outcome::Failed { .. } => "failed",
        }
    }
}

/// A change to the state before a case runs.
pub type Prepare = fn(&mut Simulation);

/// One case of the suite.
pub struct Case {
    pub name: String,
    pub scene: String,
    pub steps: usize,
    /// Applied to the state before the run (e.g. a singular deformation gradient).
    pub prepare: Option<Prepare>,
}

#[derive(Clone, Debug, Serialize)]
pub struct CaseResult {
    pub name: String,
    #[serde(flatten)]
    pub outcome: Outcome,
    pub particles: usize,
    pub wall_s: f64,
}

/// A sand block dropped 1 cm onto a rough floor in a 24³ grid, dx = 1 cm, 10 substeps per
/// 0.01 s step.
fn sand(material: &str, fill: &str, extra: &str, sim_extra: &str, stability: &str) -> String {
    format!(
        r#"Scene(
    simulation: (cells: (24, 24, 24), dx: 0.01, dt: 0.01, substeps: 10, stability: {stability}{sim_extra}),
    materials: {{ "sand": {material} }},
    bodies: [(name: "sand", material: "sand", fill: {fill}{extra})],
    colliders: [(name: "floor", kind: Container, shape: Plane(normal: (0.0, 1.0, 0.0)),
                 position: (0.0, 0.03, 0.0), friction: 0.5, particle_contact: false)],
)"#
    )
}

const BLOCK: &str = "Box(min: (0.07, 0.04, 0.07), max: (0.15, 0.10, 0.15))";

fn dp(e: f64, nu: f64, phi: f64) -> String {
    format!("DruckerPrager((youngs_modulus: {e}, poisson_ratio: {nu}, friction_deg: {phi}))")
}

fn set_f(sim: &mut Simulation, f: DMat3) {
    let mut q = sim.world.query::<&mut DeformationGradient>();
    for mut fg in q.iter_mut(&mut sim.world) {
        for (i, x) in fg.0.iter_mut().enumerate() {
            if i % 3 == 0 {
                *x = f;
            }
        }
    }
}

/// A paddle in a sand bed at `speed` m/s along x.
fn paddle(speed: f64, stability: &str) -> String {
    format!(
        r#"Scene(
    simulation: (cells: (24, 24, 24), dx: 0.01, dt: 0.01, substeps: 10, stability: {stability}),
    materials: {{ "sand": DruckerPrager((youngs_modulus: 2e4, friction_deg: 30.0)) }},
    bodies: [(name: "sand", material: "sand", fill: Box(min: (0.06, 0.03, 0.06), max: (0.18, 0.10, 0.18)))],
    colliders: [(name: "paddle", kind: Tool, shape: Box(half_extents: (0.01, 0.03, 0.05)),
                 position: (0.045, 0.07, 0.12), control: Constant(linear: ({speed}, 0.0, 0.0), steps: 1))],
)"#
    )
}

/// A sand box from `lo` to `hi` with `ppc` particles per cell on a floor at `floor_y`, in a grid
/// of `cells` at `dx`.
fn grid_and_ppc(
    cells: (usize, usize, usize),
    dx: f64,
    (lo, hi): ([f64; 3], [f64; 3]),
    ppc: usize,
    floor_y: f64,
) -> String {
    let (nx, ny, nz) = cells;
    let fill_box = format!(
        "({}, {}, {}), max: ({}, {}, {})",
        lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]
    );
    format!(
        r#"Scene(
    simulation: (cells: ({nx}, {ny}, {nz}), dx: {dx}, dt: 0.01, substeps: 10, stability: Auto),
    materials: {{ "sand": {} }},
    bodies: [(name: "sand", material: "sand", fill: Box(min: {fill_box}),
              particles_per_cell: {ppc})],
    colliders: [(name: "floor", kind: Container, shape: Plane(normal: (0.0, 1.0, 0.0)),
                 position: (0.0, {floor_y}, 0.0), friction: 0.5, particle_contact: false)],
)"#,
        dp(2e4, 0.3, 30.0)
    )
}

/// The CFL speed of [`paddle`]'s scene at its requested substeps: C·dx/Δt_sub − c.
fn paddle_cfl_speed() -> f64 {
    let (mu, lambda) = crate::math::return_map::lame(2e4, 0.3);
    let c = ((lambda + 2.0 * mu) / 1500.0).sqrt();
    0.5 * 0.01 / 1e-3 - c
}

/// Every case of the suite.
pub fn cases() -> Vec<Case> {
    let mut out = Vec::new();
    let mut add = |name: String, scene: String, steps: usize| {
        out.push(Case {
            name,
            scene,
            steps,
            prepare: None,
        })
    };
    for e in [1e4, 1e5, 1e6, 1e7] {
        for st in ["Auto", "Strict"] {
            add(
                format!("E = {e:.0e} Pa, {st}"),
                sand(&dp(e, 0.3, 30.0), BLOCK, "", "", st),
                10,
            );
        }
    }
    for nu in [0.45, 0.49] {
        add(
            format!("ν = {nu}, E = 1e5 Pa, Auto"),
            sand(&dp(1e5, nu, 30.0), BLOCK, "", "", "Auto"),
            10,
        );
    }
    for phi in [0.0, 60.0] {
        add(
            format!("friction angle {phi}°"),
            sand(&dp(2e4, 0.3, phi), BLOCK, "", "", "Auto"),
            20,
        );
    }
    let vc = paddle_cfl_speed();
    for (label, k) in [("at", 1.0), ("4× beyond", 4.0)] {
        for st in ["Auto", "Strict"] {
            add(
                format!("tool {label} the CFL speed ({:.2} m/s), {st}", k * vc),
                paddle(k * vc, st),
                5,
            );
        }
    }
    add(
        "spoon driven into a cup wall".into(),
        r#"Scene(
    simulation: (cells: (30, 26, 30), dx: 0.005, dt: 0.01, substeps: 12, stability: Auto),
    materials: { "powder": DruckerPrager((youngs_modulus: 5e3, friction_deg: 30.0)) },
    bodies: [(name: "powder", material: "powder",
              fill: InsideContainer(container: "cup", height: 0.03))],
    colliders: [
        (name: "cup", kind: Container,
         shape: Cup(outer_radius: 0.03, height: 0.05, wall_thickness: 0.002, floor_thickness: 0.003),
         position: (0.075, 0.0075, 0.075), friction: 0.4),
        (name: "spoon", kind: Tool,
         shape: Spoon(bowl_radius: 0.015, bowl_depth: 0.009, thickness: 0.0015,
                      handle_length: 0.04, handle_radius: 0.0025, handle_rise: 0.08),
         position: (0.075, 0.03, 0.075), rotation_deg: (0.0, -90.0, 0.0), friction: 0.3,
         band_cells: 0.5, soft_band: true,
         control: Constant(linear: (0.3, 0.0, 0.0), steps: 15)),
    ],
)"#
        .into(),
        15,
    );
    add(
        "powder packed against the domain boundary".into(),
        sand(
            &dp(2e4, 0.3, 30.0),
            "Box(min: (0.01, 0.035, 0.01), max: (0.22, 0.14, 0.22))",
            "",
            "",
            "Auto",
        ),
        10,
    );
    add(
        "fine grid, 1 particle per cell (dx = 2.5 mm)".into(),
        grid_and_ppc(
            (64, 48, 64),
            0.0025,
            ([0.05, 0.02, 0.05], [0.11, 0.06, 0.11]),
            1,
            0.0125,
        ),
        10,
    );
    add(
        "coarse grid, 64 particles per cell (dx = 2 cm)".into(),
        grid_and_ppc(
            (14, 12, 14),
            0.02,
            ([0.08, 0.07, 0.08], [0.18, 0.13, 0.18]),
            64,
            0.06,
        ),
        10,
    );
    add(
        "a single particle".into(),
        sand(
            &dp(2e4, 0.3, 30.0),
            "Box(min: (0.10, 0.10, 0.10), max: (0.105, 0.105, 0.105))",
            "",
            "",
            "Auto",
        ),
        10,
    );
    add(
        "an empty body (no lattice point inside its box)".into(),
        sand(
            &dp(2e4, 0.3, 30.0),
            "Box(min: (0.10, 0.10, 0.10), max: (0.101, 0.101, 0.101))",
            "",
            "",
            "Auto",
        ),
        10,
    );
    let singular: [(&str, Prepare); 3] = [
        ("F near-singular (σ = 1, 1, 1e-9)", |s| {
            set_f(s, DMat3::from_diagonal(DVec3::new(1.0, 1.0, 1e-9)))
        }),
        ("F inverted (det F = −0.5)", |s| {
            set_f(s, DMat3::from_diagonal(DVec3::new(1.0, -0.5, 1.0)))
        }),
        ("F = 0", |s| set_f(s, DMat3::ZERO)),
    ];
    for (name, f) in singular {
        out.push(Case {
            name: format!("{name} on every third particle"),
            scene: sand(&dp(2e4, 0.3, 30.0), BLOCK, "", "", "Auto"),
            steps: 10,
            prepare: Some(f),
        });
    }
    out
}

/// Runs one case.
pub fn run_case(case: &Case, threads: Option<usize>) -> CaseResult {
    let start = std::time::Instant::now();
    let (outcome, particles) = match run_inner(case, threads) {
        Ok(r) => r,
        Err(e) => (Outcome::Refused { message: e }, 0),
    };
    CaseResult {
        name: case.name.clone(),
        outcome,
        particles,
        wall_s: start.elapsed().as_secs_f64(),
    }
}

fn run_inner(case: &Case, threads: Option<usize>) -> Result<(Outcome, usize), String> {
    let (scene, mut sim) = build(&case.scene, "stability", threads).map_err(|e| e.to_string())?;
    if let Some(p) = case.prepare {
        p(&mut sim);
    }
    let n = sim.particle_count();
    let driven = scene.colliders.iter().any(|c| c.control.is_some());
    let mut energy = EnergyMonitor::default();
    energy.observe(&frame_metrics(&mut sim.world, None));
    for _ in 0..case.steps {
        if let Err(e) = sim.step() {
            return Ok((
                Outcome::Failed {
                    message: e.to_string(),
                },
                n,
            ));
        }
        energy.observe(&frame_metrics(&mut sim.world, None));
    }
    let finite = sim.body_states().iter().all(|b| {
        b.x.iter().all(|x| x.is_finite())
            && b.v.iter().all(|v| v.is_finite())
            && b.c.iter().all(|c| c.is_finite())
            && b.f.iter().all(|f| f.is_finite())
    });
    if !finite {
        return Ok((
            Outcome::Failed {
                message: "a non-finite particle value after the run".into(),
            },
            n,
        ));
    }
    if !driven && energy.spurious_gain() {
        return Ok((
            Outcome::Unstable {
                message: format!(
                    "the total energy rose {:.3e} J ({:.2} % of the energy in play) above its lowest value",
                    energy.largest_gain,
                    100.0 * energy.gain_fraction()
                ),
            },
            n,
        ));
    }
    let m = frame_metrics(&mut sim.world, None);
    Ok((
        Outcome::Stable {
            substeps: sim.params().substeps,
            requested: sim.stability.substeps_requested,
            steps: case.steps,
            max_speed: m.max_speed,
            energy_gain: if driven {
                f64::NAN
            } else {
                energy.gain_fraction()
            },
        },
        n,
    ))
}

/// The suite as a Markdown table.
pub fn markdown(results: &[CaseResult]) -> String {
    let mut s = String::from(
        "| case | outcome | particles | substeps used (asked) | detail |\n|---|---|---|---|---|\n",
    );
    for r in results {
        let (subs, detail) = match &r.outcome {
            Outcome::Stable {
                substeps,
                requested,
                steps,
                max_speed,
                energy_gain,
            } => (
                format!("{substeps} ({requested})"),
                format!(
                    "{steps} steps; max speed {max_speed:.3} m/s; energy rise {}",
                    if energy_gain.is_nan() {
                        "not checked (a driven tool does work)".to_string()
                    } else {
                        // Two significant digits below 0.005 %, so that "0.00 %" is a true 0.
                        format!(
                            "{} of the energy in play",
                            crate::util::percent(*energy_gain)
                        )
                    }
                ),
            ),
            Outcome::Refused { message }
            | Outcome::Unstable { message }
            | Outcome::Failed { message } => ("–".into(), message.replace('|', "\\|")),
        };
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} |\n",
            r.name,
            r.outcome.label(),
            r.particles,
            subs,
            detail.replace('\n', " ")
        ));
    }
    s
}
