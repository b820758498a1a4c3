//! The checks a scene needs its derived data for, and that data: the particle fills, each
//! collider's control sequence, the memory they take and the stable substep.
//!
//! [`Scene::prepare`] refuses a scene before anything large is allocated (the grid and every
//! fill's lattice are measured against the available memory first), and returns a
//! [`Prepared`] scene that the simulation builds its world from. A rollout for new controls
//! ([`Prepared::with_controls`]) keeps the fills and redoes only the checks the controls enter.
//!
//! **Stability guard.** `Δt_sub ≤ C·dx/(c + v)` with the elastic wave speed
//! `c = √((λ+2μ)/ρ)` and the largest speed `v` of a tool point or initial particle;
//! `stability: Auto` raises the substeps, `Strict` refuses.

use super::fill::{fill_lattice, fill_points};
use super::*;
use crate::components::ColliderKind;
use crate::error::{FieldError, SceneError};
use crate::materials::MaterialSpec;
use crate::math::pose::Pose;
use glam::{DMat3, DVec3};
use std::sync::Arc;

/// The most substeps per step `stability: Auto` takes to meet the CFL bound. Beyond it a scene
/// is refused: at 1e6 substeps a step of even the smallest scene runs for minutes, and the cause
/// is a stiffness or speed far outside what the scene means (a typo in `youngs_modulus`).
pub const MAX_AUTO_SUBSTEPS: usize = 1_000_000;

/// What the stability guard found and chose.
#[derive(Clone, Debug, PartialEq)]
pub struct StabilityReport {
    /// Largest elastic wave speed `√((λ+2μ)/ρ)` over the bodies (m/s).
    pub wave_speed: f64,
    /// Largest speed of a tool point or initial particle (m/s).
    pub max_speed: f64,
    /// Largest stable substep `C·dx/(c + v)` (s).
    pub dt_max: f64,
    pub substeps_requested: usize,
    pub substeps: usize,
}

impl StabilityReport {
    pub fn raised(&self) -> bool {
        self.substeps > self.substeps_requested
    }
}

/// A collider of a prepared scene: its start pose and its control per global step.
#[derive(Clone, Debug)]
pub struct PreparedCollider {
    pub kind: ColliderKind,
    pub pose: Pose,
    /// Displacement per global step (translation, rotation vector); empty for a static one.
    pub controls: Vec<[f64; 6]>,
    /// Largest speed of a point of the collider along its controls (m/s).
    pub max_speed: f64,
}

/// A particle body of a prepared scene.
#[derive(Clone, Debug)]
pub struct PreparedBody {
    /// Particle positions: the fill, jittered and cleared of the colliders.
    pub x: Vec<DVec3>,
    /// The material, with what it derives from its parameters computed once.
    pub material: MaterialSpec,
    pub particle_mass: f64,
    pub particle_volume: f64,
    /// Lamé parameters (μ, λ).
    pub lame: (f64, f64),
    pub velocity: DVec3,
    /// A state to start from instead of the fill at rest (velocities, APIC `C` and `F`, one per
    /// particle of `x`): a snapshot of an earlier rollout, set by
    /// [`Build::with_start`](crate::sim::Build::with_start).
    pub start: Option<Arc<StartColumns>>,
}

/// The per-particle state a body starts from besides its positions.
#[derive(Clone, Debug, PartialEq)]
pub struct StartColumns {
    pub v: Vec<DVec3>,
    pub c: Vec<DMat3>,
    pub f: Vec<DMat3>,
    /// The largest of `|v|`, for the stability guard.
    pub max_speed: f64,
}

impl PreparedBody {
    /// The fastest particle at the start (m/s), which the stability guard adds to the wave
    /// speed.
    pub fn speed(&self) -> f64 {
        self.start
            .as_ref()
            .map_or(self.velocity.length(), |s| s.max_speed)
    }
}

/// A scene that passed every check, with what the checks derived.
#[derive(Clone, Debug)]
pub struct Prepared {
    /// Colliders in scene order.
    pub colliders: Vec<PreparedCollider>,
    /// Bodies in scene order (shared between the rollouts of new controls).
    pub bodies: Arc<Vec<PreparedBody>>,
    /// Each material plug-in the bodies use, once, in first-use order.
    pub materials_used: Vec<MaterialSpec>,
    /// Lightest particle over the bodies (kg); infinite without particles.
    pub min_particle_mass: f64,
    pub stability: StabilityReport,
    /// Global steps of the scene's horizon.
    pub horizon: usize,
}

/// The controls a collider's `control` gives, per global step.
fn collider_controls(c: &ColliderSpec, dt: f64) -> Vec<[f64; 6]> {
    match &c.control {
        None => Vec::new(),
        Some(ControlSpec::Actions(a)) => a.clone(),
        Some(ControlSpec::Constant {
            linear,
            angular,
            steps,
        }) => {
            let u = [
                linear.0, linear.1, linear.2, angular.0, angular.1, angular.2,
            ]
            .map(|x| x * dt);
            vec![u; *steps]
        }
        Some(ControlSpec::Skill(sk)) => sk.controls(dt, Scene::tool_bottom(c)).0,
    }
}

/// The largest speed of any point of a tool of bounding radius `r` under the step control `u`
/// (translation, rotation vector over a step of `dt`): what the stability guard bounds.
pub fn control_speed(u: [f64; 6], dt: f64, r: f64) -> f64 {
    let lin = DVec3::new(u[0], u[1], u[2]).length() / dt;
    let ang = DVec3::new(u[3], u[4], u[5]).length() / dt;
    lin + if r.is_finite() { ang * r } else { 0.0 }
}

/// A collider's entry: the reach check on its path, and its largest point speed.
fn prepare_collider(
    scene: &Scene,
    i: usize,
    controls: Vec<[f64; 6]>,
) -> Result<PreparedCollider, SceneError> {
    let c = &scene.colliders[i];
    let dt = scene.simulation.dt;
    let pose = Scene::collider_pose(c);
    let r = c.shape.bounding_radius();
    check_collider_reaches_grid(scene, i, pose.translation, r, &controls)?;
    let max_speed = controls
        .iter()
        .map(|u| control_speed(*u, dt, r))
        .fold(0.0, f64::max);
    Ok(PreparedCollider {
        kind: match c.kind {
            ColliderKindSpec::Tool => ColliderKind::Tool,
            ColliderKindSpec::Container => ColliderKind::Container,
        },
        pose,
        controls,
        max_speed,
    })
}

impl Scene {
    /// Checks what needs the scene's derived data and derives it: refuses a scene that does not
    /// fit in memory (before allocating it), a collider that never reaches the grid, a tool
    /// inside a container's wall, a particle outside the grid's safe region, and a substep
    /// above the stable one under `stability: Strict`.
    pub fn prepare(&self) -> Result<Prepared, SceneError> {
        self.prepare_within(None)
    }

    /// [`Scene::prepare`] with the memory it may take capped at `limit` bytes as well as at
    /// what the machine has (tests and fuzzing check that refusals come before allocations).
    pub fn prepare_within(&self, limit: Option<u64>) -> Result<Prepared, SceneError> {
        let scene = self;
        let s = &scene.simulation;
        let dx = s.dx;
        let n = [s.cells.0, s.cells.1, s.cells.2];
        // Refuse a scene that cannot fit in memory before allocating it (an allocation that
        // fails aborts the process, and an over-committed one brings the OOM killer): the grid,
        // and the lattice every fill is cut from, at their largest.
        let available = match (crate::util::available_memory_bytes(), limit) {
            (Some(a), Some(l)) => Some(a.min(l)),
            (a, l) => a.or(l),
        };
        let nodes = (n[0] * n[1] * n[2]) as f64;
        let grid_bytes = nodes * GRID_BYTES_PER_NODE;
        let lattices: Vec<f64> = scene
            .bodies
            .iter()
            .map(|b| {
                let n = fill_lattice(scene, b).2;
                n.x * n.y * n.z
            })
            .collect();
        let candidates: f64 = lattices.iter().sum();
        // Blame what needs the most: the grid, or the body with the largest lattice.
        let largest = (0..lattices.len()).max_by(|&a, &b| lattices[a].total_cmp(&lattices[b]));
        check_memory(
            scene,
            available,
            grid_bytes + candidates * LATTICE_BYTES_PER_POINT,
            || {
                match largest {
                Some(i) if lattices[i] * LATTICE_BYTES_PER_POINT > grid_bytes => (
                    format!("bodies[{i}].particles_per_cell"),
                    scene.bodies[i].particles_per_cell.to_string(),
                    format!(
                        "the fill's lattice of {:.3e} points (at {} particles per cell) and a grid of {nodes:.3e} nodes",
                        lattices[i], scene.bodies[i].particles_per_cell
                    ),
                    format!("lower bodies[{i}].particles_per_cell or shrink bodies[{i}].fill (or its container)"),
                ),
                _ => (
                    "simulation.cells".into(),
                    format!("{:?}", s.cells),
                    format!(
                        "a grid of {nodes:.3e} nodes and fills of {candidates:.3e} lattice points"
                    ),
                    "raise simulation.dx or shrink simulation.cells".into(),
                ),
            }
            },
        )?;
        let (lo, hi) = scene.domain();
        let (safe_lo, safe_hi) = (lo + DVec3::splat(dx), hi - DVec3::splat(dx));

        // Colliders first: particle fills are cleared against them.
        let mut colliders = Vec::with_capacity(scene.colliders.len());
        for (i, c) in scene.colliders.iter().enumerate() {
            colliders.push(prepare_collider(scene, i, collider_controls(c, s.dt))?);
        }
        let poses: Vec<(&ColliderSpec, Pose)> = scene
            .colliders
            .iter()
            .zip(&colliders)
            .map(|(c, p)| (c, p.pose))
            .collect();
        check_tools_clear_of_containers(scene, &poses)?;

        // Bodies.
        let mut bodies = Vec::with_capacity(scene.bodies.len());
        let mut min_particle_mass = f64::INFINITY;
        let mut materials_used: Vec<MaterialSpec> = Vec::new();
        let mut rng = crate::util::SplitMix64(s.seed);
        let mut particles_so_far = 0.0f64;
        for (i, b) in scene.bodies.iter().enumerate() {
            let mat = scene.materials[&b.material].prepared();
            let h = scene.particle_spacing(b);
            let mut x: Vec<DVec3> = fill_points(scene, b);
            if let Lattice::Jittered(j) = b.lattice {
                for p in &mut x {
                    let d = DVec3::new(rng.uniform(), rng.uniform(), rng.uniform());
                    *p += (d - DVec3::splat(0.5)) * (j * h);
                }
            }
            // Keep particles clear of every collider by a quarter spacing.
            x.retain(|&p| {
                poses
                    .iter()
                    .all(|(c, pose)| c.shape.sdf(pose.to_local(p)).0 > 0.25 * h)
            });
            if let Some(p) = x
                .iter()
                .find(|p| !(p.cmpge(safe_lo).all() && p.cmple(safe_hi).all()))
            {
                return Err(scene.field_error(FieldError::new(
                    format!("bodies[{i}].fill"),
                    format!("a particle at ({:.4}, {:.4}, {:.4})", p.x, p.y, p.z),
                    format!(
                        "every particle inside the grid's safe region ({:.4}, {:.4}, {:.4})–({:.4}, {:.4}, {:.4}) m; shrink the fill or enlarge simulation.cells",
                        safe_lo.x, safe_lo.y, safe_lo.z, safe_hi.x, safe_hi.y, safe_hi.z
                    ),
                )));
            }
            particles_so_far += x.len() as f64;
            check_memory(
                scene,
                available,
                grid_bytes + particles_so_far * PARTICLE_BYTES,
                || {
                    (
                        format!("bodies[{i}].particles_per_cell"),
                        b.particles_per_cell.to_string(),
                        format!(
                            "{particles_so_far:.3e} particles (this body {}) on a grid of {nodes:.3e} nodes",
                            x.len()
                        ),
                        "lower particles_per_cell, shrink the fills or raise simulation.dx".into(),
                    )
                },
            )?;
            let volume = h * h * h;
            let mass = mat.density() * volume;
            min_particle_mass = min_particle_mass.min(mass);
            if !materials_used.iter().any(|m| m.plugin() == mat.plugin()) {
                materials_used.push(mat.clone());
            }
            bodies.push(PreparedBody {
                x,
                particle_mass: mass,
                particle_volume: volume,
                lame: mat.lame(),
                velocity: DVec3::from(b.velocity),
                material: mat,
                start: None,
            });
        }
        let mut prepared = Prepared {
            colliders,
            bodies: Arc::new(bodies),
            materials_used,
            min_particle_mass,
            stability: StabilityReport {
                wave_speed: 0.0,
                max_speed: 0.0,
                dt_max: f64::INFINITY,
                substeps_requested: s.substeps,
                substeps: s.substeps,
            },
            horizon: 1,
        };
        prepared.guard(scene)?;
        Ok(prepared)
    }
}

impl Prepared {
    /// The same scene with collider `i`'s controls replaced (a tool's skill at new Θ): the
    /// fills are shared, and the checks the controls enter (the collider reaches the grid, the
    /// stability guard, the horizon) run again.
    pub fn with_controls(
        &self,
        scene: &Scene,
        i: usize,
        controls: Vec<[f64; 6]>,
    ) -> Result<Prepared, SceneError> {
        let mut p = self.clone();
        p.colliders[i] = prepare_collider(scene, i, controls)?;
        p.guard(scene)?;
        Ok(p)
    }

    /// The stability guard and the horizon, from the bodies and the colliders' controls.
    pub(crate) fn guard(&mut self, scene: &Scene) -> Result<(), SceneError> {
        let s = &scene.simulation;
        // The speeds, and the field that sets each (what a refusal points at).
        let (mut wave_speed, mut wave_field) = (0.0f64, String::from("materials"));
        let (mut max_speed, mut speed_field) = (0.0f64, String::from("simulation.dt"));
        for (i, c) in self.colliders.iter().enumerate() {
            if c.max_speed > max_speed {
                (max_speed, speed_field) = (c.max_speed, format!("colliders[{i}].control"));
            }
        }
        for (i, b) in self.bodies.iter().enumerate() {
            let (mu, lambda) = b.lame;
            let rho = b.material.density();
            let c = ((lambda + 2.0 * mu) / rho).sqrt();
            if c > wave_speed {
                (wave_speed, wave_field) = (c, format!("materials.{}", scene.bodies[i].material));
            }
            if b.speed() > max_speed {
                (max_speed, speed_field) = (b.speed(), format!("bodies[{i}].velocity"));
            }
        }
        let blame = if wave_speed >= max_speed {
            wave_field
        } else {
            speed_field
        };
        self.stability = stability_guard(scene, wave_speed, max_speed, blame)?;
        let from_controls = self.colliders.iter().map(|c| c.controls.len()).max();
        self.horizon = s.steps.unwrap_or(from_controls.unwrap_or(0).max(1));
        Ok(())
    }
}

/// `Δt_sub ≤ C·dx/(c + v)`: the substeps the scene runs at, or its refusal.
/// `blame` is the field that sets the larger of the two speeds, named when the substeps Auto
/// would need are too many; under `Strict` the refusal names `simulation.substeps`.
fn stability_guard(
    scene: &Scene,
    wave_speed: f64,
    max_speed: f64,
    blame: String,
) -> Result<StabilityReport, SceneError> {
    let s = &scene.simulation;
    let dx = s.dx;
    let dt_sub = s.dt / s.substeps as f64;
    let dt_max = s.cfl * dx / (wave_speed + max_speed);
    let mut substeps = s.substeps;
    if dt_sub > dt_max * (1.0 + 1e-12) {
        // In f64: for an absurd stiffness the count exceeds any integer (`as usize` would
        // saturate and print 18446744073709551615 as the advice).
        let needed = (s.dt / dt_max).ceil();
        let too_many = needed > MAX_AUTO_SUBSTEPS as f64;
        // Fixed-point below 1e6 m/s, as the stability table prints them; an absurd
        // stiffness in scientific notation rather than 150 digits.
        let speed = |v: f64| {
            if v < 1e6 {
                format!("{v:.3}")
            } else {
                format!("{v:.3e}")
            }
        };
        let reason = format!(
            "elastic wave speed {} m/s + largest speed {} m/s, dx {dx} m, CFL {}",
            speed(wave_speed),
            speed(max_speed),
            s.cfl
        );
        let refuse = move |field: String, advice: String| {
            let (line, col) = super::locate(&scene.source, &field);
            SceneError::Unstable {
                file: scene.path.clone(),
                line,
                col,
                field,
                dt_sub,
                dt_max,
                reason_and_advice: format!("{reason}); {advice}"),
            }
        };
        if too_many {
            return Err(refuse(blame, format!(
                "it would need {needed:.3e} substeps per step, more than the {MAX_AUTO_SUBSTEPS} even stability: Auto takes: lower the materials' youngs_modulus (the wave speed grows as its square root) or the tool speeds, or raise dx"
            )));
        }
        match s.stability {
            Stability::Strict => {
                return Err(refuse("simulation.substeps".into(), format!(
                    "with stability: Strict the scene is refused: raise simulation.substeps to at least {needed} or set stability: Auto"
                )))
            }
            Stability::Auto => substeps = needed as usize,
        }
    }
    Ok(StabilityReport {
        wave_speed,
        max_speed,
        dt_max,
        substeps_requested: s.substeps,
        substeps,
    })
}

/// Bytes a forward simulation holds per grid node: mass, momentum and velocity in f64
/// (`study growth`'s grid series measured 56 bytes per node of peak RSS).
const GRID_BYTES_PER_NODE: f64 = 56.0;
/// Bytes a forward simulation holds per particle: x, v, C, F, F_tmp, the SVD factors, the P2G
/// affine term and the scatter order in f64, plus the material's state (`study growth`'s
/// particle series measured about 516 bytes per particle of peak RSS at 1M particles).
const PARTICLE_BYTES: f64 = 520.0;
/// Bytes per lattice point while a fill is generated (a position in f64).
const LATTICE_BYTES_PER_POINT: f64 = 24.0;

/// Refuses the scene, naming the field that `what` describes (field, value, what needs the
/// memory, how to fix it), when `need` bytes exceed the memory available; passes where the
/// available memory is unknown.
fn check_memory(
    scene: &Scene,
    available: Option<u64>,
    need: f64,
    what: impl FnOnce() -> (String, String, String, String),
) -> Result<(), SceneError> {
    let Some(avail) = available else {
        return Ok(());
    };
    if need <= avail as f64 {
        return Ok(());
    }
    let (field, value, needs, fix) = what();
    Err(scene.field_error(FieldError::new(
        field,
        value,
        format!(
            "a scene that fits in memory: {needs} need about {} GB, and {:.1} GB are available; {fix}",
            if need < 1e15 {
                format!("{:.1}", need / 1e9)
            } else {
                format!("{:.3e}", need / 1e9)
            },
            avail as f64 / 1e9
        ),
    )))
}

/// Refuses a collider that never touches the grid: its bounding sphere (radius `r` about the
/// pose origin) lies outside the domain at the start and at every step of its controls. Such a
/// collider does nothing, and the usual cause is a position in the wrong units (millimetres
/// for metres) or a slip of sign, which would otherwise run silently with no container or tool.
fn check_collider_reaches_grid(
    scene: &Scene,
    i: usize,
    start: DVec3,
    r: f64,
    controls: &[[f64; 6]],
) -> Result<(), SceneError> {
    if !r.is_finite() {
        return Ok(());
    }
    let (lo, hi) = scene.domain();
    let reaches = |p: DVec3| (p.clamp(lo, hi) - p).length() <= r;
    let mut p = start;
    if reaches(p) {
        return Ok(());
    }
    for u in controls {
        p += DVec3::new(u[0], u[1], u[2]);
        if reaches(p) {
            return Ok(());
        }
    }
    let c = &scene.colliders[i];
    Err(scene.field_error(FieldError::new(
        format!("colliders[{i}].position"),
        format!("{:?}", c.position),
        format!(
            "a collider that reaches the simulation domain ({:.4}, {:.4}, {:.4})–({:.4}, {:.4}, {:.4}) m at some step ('{}' stays outside it{}); positions are in metres",
            lo.x,
            lo.y,
            lo.z,
            hi.x,
            hi.y,
            hi.z,
            c.name,
            if controls.is_empty() { "" } else { " over its whole trajectory" }
        ),
    )))
}

/// Refuses a tool that starts inside a container's wall: samples points of the tool's solid on
/// a 16³ lattice over its bounding box and tests them against every container.
fn check_tools_clear_of_containers(
    scene: &Scene,
    poses: &[(&ColliderSpec, Pose)],
) -> Result<(), SceneError> {
    for (ti, (tool, tpose)) in poses.iter().enumerate() {
        if tool.kind != ColliderKindSpec::Tool {
            continue;
        }
        let r = tool.shape.bounding_radius();
        if !r.is_finite() {
            continue;
        }
        const N: usize = 16;
        for a in 0..N {
            for b in 0..N {
                for c in 0..N {
                    let local = (DVec3::new(a as f64, b as f64, c as f64) / (N - 1) as f64 * 2.0
                        - DVec3::ONE)
                        * r;
                    if tool.shape.sdf(local).0 >= 0.0 {
                        continue;
                    }
                    let p = tpose.to_world(local);
                    for (cont, cpose) in poses {
                        if cont.kind != ColliderKindSpec::Container {
                            continue;
                        }
                        if cont.shape.sdf(cpose.to_local(p)).0 < 0.0 {
                            return Err(scene.field_error(FieldError::new(
                                format!("colliders[{ti}].position"),
                                format!("{:?}", tool.position),
                                format!(
                                    "a start pose clear of container '{}' (the tool overlaps its wall at ({:.4}, {:.4}, {:.4}))",
                                    cont.name, p.x, p.y, p.z
                                ),
                            )));
                        }
                    }
                }
            }
        }
    }
    Ok(())
}
