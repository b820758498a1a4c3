//! Scene files: RON, `deny_unknown_fields`, every error located by file, line, column and field.
//!
//! A scene declares the simulation settings, named materials (a plug-in name with parameters),
//! particle bodies, rigid colliders (tools and containers) with their controls, the transport
//! task (for metrics), and the recording options. See `scenes/README.md` for every field and
//! its default.

use crate::adjoint::loss::CupRegion;
use crate::components::ContactMode;
use crate::error::{FieldError, SceneError};
use crate::materials::MaterialSpec;
use crate::math::pose::Pose;
use crate::math::sdf::Shape;
use crate::skills::SkillSpec;
use glam::{DQuat, DVec3};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The most worker threads a scene or `--threads` may ask for. More is a typo, not a machine:
/// every rayon thread is an OS thread with its own stack, and `bench --threads 100000` on a
/// 4,096-particle scene had started 15,589 threads after 14 minutes on 2 cores, without finishing
/// its one step.
pub const MAX_THREADS: usize = 1024;

/// What to do when the scene's substep is above the stable one.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
pub enum Stability {
    /// Raise the number of substeps and say so.
    #[default]
    Auto,
    /// Refuse the scene with the numbers.
    Strict,
}

/// Domain walls.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct WallSpec {
    /// Node layers acting as wall on each face. Default 3.
    #[serde(default = "default_wall_cells")]
    pub cells: usize,
    /// Default `Separate`.
    #[serde(default)]
    pub contact: ContactMode,
    /// Coulomb friction. Default 0.
    #[serde(default)]
    pub friction: f64,
}

fn default_wall_cells() -> usize {
    3
}

impl Default for WallSpec {
    fn default() -> Self {
        Self {
            cells: 3,
            contact: ContactMode::Separate,
            friction: 0.0,
        }
    }
}

/// Simulation settings.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SimulationSpec {
    /// Position of grid node (0, 0, 0) (m). Default (0, 0, 0).
    #[serde(default)]
    pub domain_min: (f64, f64, f64),
    /// Grid nodes along x, y, z.
    pub cells: (usize, usize, usize),
    /// Cell size (m).
    pub dx: f64,
    /// Global step Δt (s). Default 0.01.
    #[serde(default = "default_dt")]
    pub dt: f64,
    /// Substeps per global step before the stability guard. Default 20.
    #[serde(default = "default_substeps")]
    pub substeps: usize,
    /// Global steps to run; `None` runs until the tool controls end. Default `None`.
    #[serde(default)]
    pub steps: Option<usize>,
    /// Default `Auto`.
    #[serde(default)]
    pub stability: Stability,
    /// CFL number `C` in `Δt_sub ≤ C·dx/c`, in (0, 1]. Default 0.5.
    #[serde(default = "default_cfl")]
    pub cfl: f64,
    /// Worker threads; 0 uses all cores. Default 0. At most [`MAX_THREADS`].
    #[serde(default)]
    pub threads: usize,
    /// Seed of the particle jitter. Default 0.
    #[serde(default)]
    pub seed: u64,
    /// Gravity (m/s²). Default (0, −9.81, 0).
    #[serde(default = "default_gravity")]
    pub gravity: (f64, f64, f64),
    #[serde(default)]
    pub walls: WallSpec,
    /// Nodes lighter than this fraction of the lightest particle are empty (velocity 0, no
    /// gravity, no contact). Default 0: only massless nodes are empty. The Taichi reference uses
    /// 1e-6 to keep its f32 adjoint of `v = mv/m` from underflowing; in f64 nothing underflows,
    /// and a threshold is a jump the adjoint cannot see: a node whose mass crosses it drops its
    /// velocity from the particles' gather, which made the 2.5 mm transport scene's rollouts
    /// jump under a 1e-9 change of Θ (`examples/rollout_divergence`). `sand_box` keeps 1e-6
    /// to match the reference bit for bit.
    #[serde(default = "default_empty_node_ratio")]
    pub empty_node_ratio: f64,
}

fn default_dt() -> f64 {
    0.01
}
fn default_substeps() -> usize {
    20
}
fn default_cfl() -> f64 {
    0.5
}
fn default_gravity() -> (f64, f64, f64) {
    (0.0, -9.81, 0.0)
}
fn default_empty_node_ratio() -> f64 {
    0.0
}

/// Region a body fills with particles.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub enum Fill {
    /// Axis-aligned box (m).
    Box {
        min: (f64, f64, f64),
        max: (f64, f64, f64),
    },
    /// Vertical cylinder standing on `base` (m).
    Cylinder {
        base: (f64, f64, f64),
        radius: f64,
        height: f64,
    },
    /// The cavity of a cup collider, from its floor up to `height` (m) above the floor.
    InsideContainer { container: String, height: f64 },
    /// A column of length `length` along x, height `aspect·length` and depth `depth` along z,
    /// with its lower corner at `base` (m): the aspect ratio is a scene setting.
    Column {
        base: (f64, f64, f64),
        length: f64,
        aspect: f64,
        depth: f64,
    },
}

/// Particle placement within a cell.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Default)]
pub enum Lattice {
    /// A regular lattice, first particle half a spacing from the region's corner.
    #[default]
    Regular,
    /// A regular lattice displaced by a seeded uniform jitter of this fraction of the spacing.
    Jittered(f64),
}

/// A body of particles.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BodySpec {
    pub name: String,
    /// Key in `materials`.
    pub material: String,
    pub fill: Fill,
    /// Particles per grid cell, a cube number (1, 8, 27, 64). Default 8.
    #[serde(default = "default_ppc")]
    pub particles_per_cell: usize,
    #[serde(default)]
    pub lattice: Lattice,
    /// Initial velocity (m/s). Default 0.
    #[serde(default)]
    pub velocity: (f64, f64, f64),
}

fn default_ppc() -> usize {
    8
}

/// Whether a collider moves.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
pub enum ColliderKindSpec {
    Tool,
    Container,
}

/// How a tool moves.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub enum ControlSpec {
    /// Constant rigid velocity for `steps` global steps (m/s, rad/s).
    Constant {
        linear: (f64, f64, f64),
        #[serde(default)]
        angular: (f64, f64, f64),
        steps: usize,
    },
    /// One 6-D displacement per global step (m, rad).
    Actions(Vec<[f64; 6]>),
    /// The skill mapping Θ → controls (DESIGN §4).
    Skill(SkillSpec),
}

/// A rigid collider.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ColliderSpec {
    pub name: String,
    pub kind: ColliderKindSpec,
    pub shape: Shape,
    /// Pose origin (m).
    pub position: (f64, f64, f64),
    /// XYZ Euler angles (degrees). Default 0.
    #[serde(default)]
    pub rotation_deg: (f64, f64, f64),
    /// Coulomb friction coefficient, ≥ 0. Default 0.3.
    #[serde(default = "default_friction")]
    pub friction: f64,
    /// Default `Separate`.
    #[serde(default)]
    pub contact: ContactMode,
    /// Contact band in grid cells for grid contact. Default 1.
    #[serde(default = "default_band")]
    pub band_cells: f64,
    /// Blend the grid contact in linearly across the band (continuous in the collider's pose,
    /// so gradients through a moving tool see no jumps) instead of all or nothing. Default false.
    #[serde(default)]
    pub soft_band: bool,
    /// Project particles against this collider (thin walls). Default true.
    #[serde(default = "default_true")]
    pub particle_contact: bool,
    /// Tools only.
    #[serde(default)]
    pub control: Option<ControlSpec>,
}

fn default_friction() -> f64 {
    0.3
}
fn default_band() -> f64 {
    1.0
}
fn default_true() -> bool {
    true
}

/// The transport task: which container is the target, and the target amount.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TaskSpec {
    /// Name of the target container.
    pub target: String,
    /// Target amount for the indicator metric.
    pub target_value: TargetValue,
}

/// An amount of powder.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
pub enum TargetValue {
    Particles(f64),
    Grams(f64),
}

/// A loss on the final particle positions (what `gradcheck` and `bench --backward`
/// differentiate).
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
pub enum LossSpec {
    /// `mean_p Σ_d |x_p,d − t_d|` (the Taichi reference benchmark's loss).
    MeanL1((f64, f64, f64)),
    /// `Σ_p ‖x_p − t‖` (seed paper eq. 5).
    SumDistance((f64, f64, f64)),
    /// Dosing: `((M − m*)/m*)²`, with `M` the soft mass inside the task's target cup
    /// (`crate::adjoint::loss`). Needs a `task`.
    Dosing {
        /// Target mass m* (g), > 0.
        grams: f64,
        /// Width of the soft indicator's ramps (m), > 0. Default: the particle spacing.
        #[serde(default)]
        width: Option<f64>,
    },
}

/// Recording options.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RecordSpec {
    /// Record every this many global steps. Default 1.
    #[serde(default = "default_every")]
    pub every: usize,
    /// Point radius (m); default half the particle spacing.
    #[serde(default)]
    pub point_radius: Option<f64>,
}

fn default_every() -> usize {
    1
}

/// A scene file.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    pub simulation: SimulationSpec,
    #[serde(default)]
    pub materials: BTreeMap<String, MaterialSpec>,
    #[serde(default)]
    pub bodies: Vec<BodySpec>,
    #[serde(default)]
    pub colliders: Vec<ColliderSpec>,
    #[serde(default)]
    pub task: Option<TaskSpec>,
    #[serde(default)]
    pub record: Option<RecordSpec>,
    /// Default: `SumDistance` to the task's target-cup bottom centre, or to the centre of the
    /// domain floor.
    #[serde(default)]
    pub loss: Option<LossSpec>,
    /// Where the scene came from (for messages).
    #[serde(skip)]
    pub path: PathBuf,
    #[serde(skip)]
    pub source: String,
}

impl Scene {
    /// Reads, parses and validates a scene file.
    pub fn load(path: impl AsRef<Path>) -> Result<Scene, SceneError> {
        let path = path.as_ref();
        let src = std::fs::read_to_string(path).map_err(|cause| SceneError::Io {
            file: path.to_path_buf(),
            cause,
        })?;
        Self::parse(&src, path)
    }

    /// Parses and validates scene text; `path` is used in messages.
    pub fn parse(src: &str, path: &Path) -> Result<Scene, SceneError> {
        let mut scene: Scene = ron::Options::default()
            .with_default_extension(ron::extensions::Extensions::IMPLICIT_SOME)
            .from_str(src)
            .map_err(|e| {
                let (line, col) = (e.span.start.line, e.span.start.col);
                let code = e.code.to_string();
                SceneError::Parse {
                    file: path.to_path_buf(),
                    line,
                    col,
                    // ron names the problem but not the field ("Integer is out of bounds").
                    message: match field_before(src, line, col) {
                        Some(f) if !code.contains(&f) => format!("field `{f}`: {code}"),
                        _ => code,
                    },
                }
            })?;
        scene.path = path.to_path_buf();
        scene.source = src.to_string();
        scene.validate()?;
        Ok(scene)
    }

    /// Turns a field error into a located scene error.
    pub fn field_error(&self, e: FieldError) -> SceneError {
        let (line, col) = locate(&self.source, &e.field);
        SceneError::Invalid {
            file: self.path.clone(),
            line,
            col,
            field: e.field,
            value: e.value,
            expected: e.expected,
        }
    }

    /// Checks every field (what [`Scene::parse`] does after parsing): for scenes edited in code.
    pub fn validate(&self) -> Result<(), SceneError> {
        self.validate_fields().map_err(|e| self.field_error(e))
    }

    fn validate_fields(&self) -> Result<(), FieldError> {
        let s = &self.simulation;
        let pos = |f: &str, v: f64, ok: bool, exp: &str| -> Result<(), FieldError> {
            if ok && v.is_finite() {
                Ok(())
            } else {
                Err(FieldError::new(f, v.to_string(), exp))
            }
        };
        pos("simulation.dx", s.dx, s.dx > 0.0, "> 0 m")?;
        pos("simulation.dt", s.dt, s.dt > 0.0, "> 0 s")?;
        pos(
            "simulation.cfl",
            s.cfl,
            s.cfl > 0.0 && s.cfl <= 1.0,
            "in (0, 1]",
        )?;
        pos(
            "simulation.empty_node_ratio",
            s.empty_node_ratio,
            s.empty_node_ratio >= 0.0 && s.empty_node_ratio < 1.0,
            "in [0, 1)",
        )?;
        if s.substeps == 0 {
            return Err(FieldError::new("simulation.substeps", "0", ">= 1"));
        }
        if s.threads > MAX_THREADS {
            return Err(FieldError::new(
                "simulation.threads",
                s.threads.to_string(),
                format!("<= {MAX_THREADS} (0 uses all cores)"),
            ));
        }
        let (nx, ny, nz) = s.cells;
        let min_cells = 2 * s.walls.cells.max(1) + 3;
        for (axis, n) in [("x", nx), ("y", ny), ("z", nz)] {
            if n < min_cells || n > 4096 {
                return Err(FieldError::new(
                    "simulation.cells",
                    format!("{n} along {axis}"),
                    format!("between {min_cells} (twice the wall cells plus 3) and 4096"),
                ));
            }
        }
        for (name, v) in [
            ("simulation.domain_min", s.domain_min),
            ("simulation.gravity", s.gravity),
        ] {
            if ![v.0, v.1, v.2].iter().all(|x| x.is_finite()) {
                return Err(FieldError::new(name, format!("{v:?}"), "finite numbers"));
            }
        }
        pos(
            "simulation.walls.friction",
            s.walls.friction,
            s.walls.friction >= 0.0,
            ">= 0",
        )?;
        for (name, m) in &self.materials {
            m.validate()
                .map_err(|e| e.within(&format!("materials.{name}")))?;
        }
        let mut names = std::collections::HashSet::new();
        for (i, c) in self.colliders.iter().enumerate() {
            let at = format!("colliders[{i}]");
            if !names.insert(c.name.clone()) {
                return Err(FieldError::new(
                    format!("{at}.name"),
                    &c.name,
                    "a unique name",
                ));
            }
            pos(
                &format!("{at}.friction"),
                c.friction,
                c.friction >= 0.0,
                ">= 0",
            )?;
            pos(
                &format!("{at}.band_cells"),
                c.band_cells,
                c.band_cells >= 0.0,
                ">= 0 cells",
            )?;
            validate_shape(&c.shape).map_err(|e| e.within(&format!("{at}.shape")))?;
            let p = c.position;
            if ![p.0, p.1, p.2].iter().all(|x| x.is_finite()) {
                return Err(FieldError::new(
                    format!("{at}.position"),
                    format!("{p:?}"),
                    "finite numbers",
                ));
            }
            match (c.kind, &c.control) {
                (ColliderKindSpec::Container, Some(_)) => {
                    return Err(FieldError::new(
                        format!("{at}.control"),
                        "Some(..)",
                        "no control: containers are static (use kind: Tool)",
                    ))
                }
                (_, Some(ControlSpec::Skill(sk))) => {
                    sk.validate()
                        .map_err(|e| e.within(&format!("{at}.control")))?;
                    skill_horizon(sk, c, s.dt).map_err(|e| e.within(&format!("{at}.control")))?;
                }
                (_, Some(ControlSpec::Constant { steps, .. }))
                    if *steps > crate::skills::MAX_CONTROL_STEPS =>
                {
                    return Err(FieldError::new(
                        format!("{at}.control.steps"),
                        steps.to_string(),
                        format!(
                            "at most {} steps (the per-step controls are held in memory)",
                            crate::skills::MAX_CONTROL_STEPS
                        ),
                    ));
                }
                (_, Some(ControlSpec::Actions(a))) => {
                    if let Some(k) = a.iter().position(|u| !u.iter().all(|x| x.is_finite())) {
                        return Err(FieldError::new(
                            format!("{at}.control"),
                            format!("action {k}"),
                            "finite numbers",
                        ));
                    }
                }
                _ => {}
            }
        }
        for (i, b) in self.bodies.iter().enumerate() {
            let at = format!("bodies[{i}]");
            if !self.materials.contains_key(&b.material) {
                return Err(FieldError::new(
                    format!("{at}.material"),
                    format!("\"{}\"", b.material),
                    format!(
                        "one of the names in `materials`: {:?}",
                        self.materials.keys().collect::<Vec<_>>()
                    ),
                ));
            }
            let ppa = (b.particles_per_cell as f64).cbrt().round() as usize;
            if ppa == 0 || ppa * ppa * ppa != b.particles_per_cell {
                return Err(FieldError::new(
                    format!("{at}.particles_per_cell"),
                    b.particles_per_cell.to_string(),
                    "a cube number: 1, 8, 27 or 64",
                ));
            }
            if let Lattice::Jittered(j) = b.lattice {
                pos(
                    &format!("{at}.lattice"),
                    j,
                    (0.0..=1.0).contains(&j),
                    "a jitter in [0, 1] of the spacing",
                )?;
            }
            match &b.fill {
                Fill::InsideContainer { container, height } => {
                    let c = self.colliders.iter().find(|c| &c.name == container);
                    if !matches!(c.map(|c| &c.shape), Some(Shape::Cup { .. })) {
                        return Err(FieldError::new(
                            format!("{at}.fill.container"),
                            format!("\"{container}\""),
                            "the name of a Cup collider",
                        ));
                    }
                    pos(
                        &format!("{at}.fill.height"),
                        *height,
                        *height > 0.0,
                        "> 0 m",
                    )?;
                }
                Fill::Box { min, max } => {
                    if !(min.0 < max.0 && min.1 < max.1 && min.2 < max.2) {
                        return Err(FieldError::new(
                            format!("{at}.fill.max"),
                            format!("{max:?}"),
                            format!("greater than min {min:?} on every axis"),
                        ));
                    }
                }
                Fill::Column {
                    length,
                    aspect,
                    depth,
                    ..
                } => {
                    pos(
                        &format!("{at}.fill.length"),
                        *length,
                        *length > 0.0,
                        "> 0 m",
                    )?;
                    pos(&format!("{at}.fill.aspect"), *aspect, *aspect > 0.0, "> 0")?;
                    pos(&format!("{at}.fill.depth"), *depth, *depth > 0.0, "> 0 m")?;
                }
                Fill::Cylinder { radius, height, .. } => {
                    pos(
                        &format!("{at}.fill.radius"),
                        *radius,
                        *radius > 0.0,
                        "> 0 m",
                    )?;
                    pos(
                        &format!("{at}.fill.height"),
                        *height,
                        *height > 0.0,
                        "> 0 m",
                    )?;
                }
            }
            let v = b.velocity;
            if ![v.0, v.1, v.2].iter().all(|x| x.is_finite()) {
                return Err(FieldError::new(
                    format!("{at}.velocity"),
                    format!("{v:?}"),
                    "finite numbers",
                ));
            }
        }
        if let Some(t) = &self.task {
            if !self
                .colliders
                .iter()
                .any(|c| c.name == t.target && matches!(c.shape, Shape::Cup { .. }))
            {
                return Err(FieldError::new(
                    "task.target",
                    format!("\"{}\"", t.target),
                    "the name of a Cup collider",
                ));
            }
            let (amount, unit) = match t.target_value {
                TargetValue::Particles(n) => (n, "particles"),
                TargetValue::Grams(g) => (g, "g"),
            };
            pos(
                "task.target_value",
                amount,
                amount >= 0.0,
                &format!(">= 0 {unit}, a finite amount of powder"),
            )?;
        }
        if let Some(LossSpec::Dosing { grams, width }) = self.loss {
            if self.task.is_none() {
                return Err(FieldError::new(
                    "loss",
                    "Dosing(..)",
                    "a scene with a `task` naming the target cup",
                ));
            }
            pos("loss.grams", grams, grams > 0.0, "> 0 g")?;
            if let Some(w) = width {
                pos("loss.width", w, w > 0.0, "> 0 m")?;
            }
        }
        if let Some(r) = &self.record {
            if r.every == 0 {
                return Err(FieldError::new("record.every", "0", ">= 1 step"));
            }
            if let Some(rad) = r.point_radius {
                pos("record.point_radius", rad, rad > 0.0, "> 0 m")?;
            }
        }
        // Behind the range checks above: any other field that is NaN or infinite (a rotation, a
        // loss target, a recording option) would reach the simulation as a silent NaN.
        if let Some((field, v)) = crate::nonfinite::first_nonfinite(self) {
            return Err(FieldError::new(field, v.to_string(), "a finite number"));
        }
        Ok(())
    }

    /// Rotation of a collider from its Euler angles.
    pub fn collider_rotation(c: &ColliderSpec) -> DQuat {
        let (a, b, g) = c.rotation_deg;
        DQuat::from_euler(
            glam::EulerRot::XYZ,
            a.to_radians(),
            b.to_radians(),
            g.to_radians(),
        )
    }

    /// A collider's start pose, as the scene places it.
    pub fn collider_pose(c: &ColliderSpec) -> Pose {
        Pose {
            translation: DVec3::from(c.position),
            rotation: Scene::collider_rotation(c),
        }
    }

    /// Height of a tool's lowest point at its start pose: where a skill's descent is measured
    /// from.
    pub fn tool_bottom(c: &ColliderSpec) -> f64 {
        Scene::collider_pose(c)
            .to_world(crate::sim::lowest_local_point(&c.shape))
            .y
    }

    /// Particle spacing of a body (m): `dx/∛ppc`.
    pub fn particle_spacing(&self, body: &BodySpec) -> f64 {
        let ppa = (body.particles_per_cell as f64).cbrt().round();
        self.simulation.dx / ppa
    }

    /// Mass of one particle of each body (kg), in scene order.
    pub fn particle_masses(&self) -> Vec<f64> {
        self.bodies
            .iter()
            .map(|b| self.materials[&b.material].density() * self.particle_spacing(b).powi(3))
            .collect()
    }

    /// The cavity of the task's target cup, if the scene has a task.
    pub fn target_region(&self) -> Option<CupRegion> {
        self.cup_region(&self.task.as_ref()?.target)
    }

    /// The cavity of the collider named `name` at its start pose, if it is a cup.
    pub fn cup_region(&self, name: &str) -> Option<CupRegion> {
        let c = self.colliders.iter().find(|c| c.name == name)?;
        CupRegion::of(&c.shape, Scene::collider_pose(c))
    }

    /// Grid node (0,0,0) and the upper node corner.
    pub fn domain(&self) -> (DVec3, DVec3) {
        let s = &self.simulation;
        let lo = DVec3::from(s.domain_min);
        let n = s.cells;
        (
            lo,
            lo + DVec3::new((n.0 - 1) as f64, (n.1 - 1) as f64, (n.2 - 1) as f64) * s.dx,
        )
    }
}

/// Refuses a skill whose motion would take more than [`MAX_CONTROL_STEPS`] steps for some Θ,
/// naming the field that sets its longest phase.
fn skill_horizon(sk: &SkillSpec, c: &ColliderSpec, dt: f64) -> Result<(), FieldError> {
    use crate::skills::{StepsSetBy, MAX_CONTROL_STEPS, PHASES};
    let bound = sk.step_bound(dt, Scene::tool_bottom(c));
    let total: f64 = bound.iter().map(|b| b.0).sum();
    if total <= MAX_CONTROL_STEPS as f64 {
        return Ok(());
    }
    let (phase, &(n, by)) = bound
        .iter()
        .enumerate()
        .max_by(|a, b| a.1 .0.total_cmp(&b.1 .0))
        .expect("six phases");
    let (field, value, fix) = match by {
        StepsSetBy::LinearSpeed => (
            "linear_speed",
            format!("{} m/s", sk.linear_speed),
            "raise linear_speed or simulation.dt",
        ),
        StepsSetBy::AngularSpeed => (
            "angular_speed_deg",
            format!("{} deg/s", sk.angular_speed_deg),
            "raise angular_speed_deg or simulation.dt",
        ),
        StepsSetBy::SettleSteps => (
            "settle_steps",
            sk.settle_steps.to_string(),
            "lower settle_steps",
        ),
    };
    Err(FieldError::new(
        field,
        value,
        format!(
            "a skill of at most {MAX_CONTROL_STEPS} steps: with simulation.dt = {dt} s it takes up to {total:.3e}, the {} phase {n:.3e} of them; {fix}",
            PHASES[phase]
        ),
    ))
}

fn validate_shape(s: &Shape) -> Result<(), FieldError> {
    let p = |f: &'static str, v: f64| -> Result<(), FieldError> {
        if v > 0.0 && v.is_finite() {
            Ok(())
        } else {
            Err(FieldError::new(f, v.to_string(), "> 0 m"))
        }
    };
    match *s {
        Shape::Plane { normal } => {
            let n = DVec3::from(normal);
            if n.length() <= 0.0 || !n.is_finite() {
                return Err(FieldError::new(
                    "normal",
                    format!("{normal:?}"),
                    "a non-zero vector",
                ));
            }
        }
        Shape::Box { half_extents } => {
            for h in half_extents {
                p("half_extents", h)?;
            }
        }
        Shape::Sphere { radius } => p("radius", radius)?,
        Shape::Capsule {
            half_length,
            radius,
        } => {
            p("half_length", half_length)?;
            p("radius", radius)?;
        }
        Shape::Cylinder {
            radius,
            half_height,
        } => {
            p("radius", radius)?;
            p("half_height", half_height)?;
        }
        Shape::Cup {
            outer_radius,
            height,
            wall_thickness,
            floor_thickness,
            fillet_radius,
        } => {
            p("outer_radius", outer_radius)?;
            p("height", height)?;
            p("wall_thickness", wall_thickness)?;
            p("floor_thickness", floor_thickness)?;
            if wall_thickness >= outer_radius {
                return Err(FieldError::new(
                    "wall_thickness",
                    wall_thickness.to_string(),
                    format!("< outer_radius {outer_radius} m"),
                ));
            }
            if floor_thickness >= height {
                return Err(FieldError::new(
                    "floor_thickness",
                    floor_thickness.to_string(),
                    format!("< height {height} m"),
                ));
            }
            let k = crate::math::sdf::cup_fillet(wall_thickness, fillet_radius);
            let room = (outer_radius - wall_thickness).min(height - floor_thickness);
            if !(k >= 0.0 && k < room) {
                return Err(FieldError::new(
                    "fillet_radius",
                    format!("{k}"),
                    format!(
                        "≥ 0 m and < {room} m (the cavity's radius and depth); leave it out for the wall thickness, or 0 for a sharp edge"
                    ),
                ));
            }
        }
        Shape::Spoon {
            bowl_radius,
            bowl_depth,
            thickness,
            handle_length,
            handle_radius,
            handle_rise,
        } => {
            p("bowl_radius", bowl_radius)?;
            p("bowl_depth", bowl_depth)?;
            p("thickness", thickness)?;
            p("handle_length", handle_length)?;
            p("handle_radius", handle_radius)?;
            if bowl_depth > 2.0 * bowl_radius {
                return Err(FieldError::new(
                    "bowl_depth",
                    bowl_depth.to_string(),
                    format!("<= 2·bowl_radius = {} m", 2.0 * bowl_radius),
                ));
            }
            if !handle_rise.is_finite() {
                return Err(FieldError::new(
                    "handle_rise",
                    handle_rise.to_string(),
                    "a finite number",
                ));
            }
        }
    }
    Ok(())
}

/// The field whose value starts the text at 1-based `line`, `col` of `src`: the name before
/// the last `:` on that line, when only the start of a plain value (a number, a sign, a word)
/// lies between that `:` and `col`. `None` inside a tuple, list or map, or off a value.
fn field_before(src: &str, line: usize, col: usize) -> Option<String> {
    let text = src.lines().nth(line.checked_sub(1)?)?;
    let prefix: String = text.chars().take(col.saturating_sub(1)).collect();
    let colon = prefix.rfind(':')?;
    let value = &prefix[colon + 1..];
    if value
        .chars()
        .any(|c| matches!(c, ',' | '(' | ')' | '[' | ']' | '{' | '}' | '"'))
    {
        return None;
    }
    let name: String = prefix[..colon]
        .trim_end()
        .chars()
        .rev()
        .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
        .collect::<Vec<_>>()
        .into_iter()
        .rev()
        .collect();
    (!name.is_empty() && !name.starts_with(|c: char| c.is_ascii_digit())).then_some(name)
}

/// Line and column (1-based) of a dotted field path such as `colliders[1].shape.radius` in RON
/// text: each key is searched after the previous one; `name[i]` skips to the i-th item of the
/// list that follows `name`. Falls back to the deepest key found.
pub fn locate(src: &str, path: &str) -> (usize, usize) {
    let mut offset = 0usize;
    for part in path.split('.') {
        let (key, index) = match part.find('[') {
            Some(b) => (
                &part[..b],
                part[b + 1..part.len() - 1].parse::<usize>().ok(),
            ),
            None => (part, None),
        };
        if let Some(p) = find_key(src, offset, key) {
            offset = p;
            if let Some(i) = index {
                if let Some(p) = nth_list_item(src, offset, i) {
                    offset = p;
                }
            }
        }
    }
    let before = &src[..offset];
    let line = before.matches('\n').count() + 1;
    let col = before.len() - before.rfind('\n').map_or(0, |p| p + 1) + 1;
    (line, col)
}

/// Offset of `key` used as a field name (`key:`) or map key (`"key":`) at or after `from`,
/// skipping comments.
fn find_key(src: &str, from: usize, key: &str) -> Option<usize> {
    let bytes = src.as_bytes();
    let mut i = from;
    while i < src.len() {
        if src[i..].starts_with("//") {
            i += src[i..].find('\n').unwrap_or(src.len() - i);
            continue;
        }
        let quoted = src[i..].starts_with('"')
            && src[i + 1..].starts_with(key)
            && src[i + 1 + key.len()..].starts_with('"');
        let bare = src[i..].starts_with(key)
            && (i == 0 || !(bytes[i - 1].is_ascii_alphanumeric() || bytes[i - 1] == b'_'));
        if quoted || bare {
            let end = i + key.len() + if quoted { 2 } else { 0 };
            let rest = src[end..].trim_start();
            if rest.starts_with(':') {
                return Some(i);
            }
        }
        i += src[i..].chars().next().map_or(1, |c| c.len_utf8());
    }
    None
}

/// Offset of the i-th top-level item of the `[...]` list starting after `from`.
fn nth_list_item(src: &str, from: usize, n: usize) -> Option<usize> {
    // The list (or tuple) opens right after the key's colon, or the path is not about it.
    let after = from + src[from..].find(':')? + 1;
    let open = after + src[after..].find(|c: char| !c.is_whitespace())?;
    if !src[open..].starts_with(['[', '(']) {
        return None;
    }
    let start = open + 1;
    let mut depth = 0i32;
    let mut item = 0usize;
    let mut at_item_start = true;
    for (k, ch) in src[start..].char_indices() {
        let p = start + k;
        if at_item_start && !ch.is_whitespace() {
            if item == n {
                return Some(p);
            }
            at_item_start = false;
        }
        match ch {
            '(' | '[' | '{' => depth += 1,
            '}' => depth -= 1,
            ']' | ')' => {
                if depth == 0 {
                    return None;
                }
                depth -= 1;
            }
            ',' if depth == 0 => {
                item += 1;
                at_item_start = true;
            }
            _ => {}
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn locate_nested_fields() {
        let src = "Scene(\n  simulation: (dx: 0.1),\n  bodies: [\n    (name: \"a\", x: 1),\n    (name: \"b\", x: 2),\n  ],\n)";
        assert_eq!(locate(src, "simulation.dx"), (2, 16));
        assert_eq!(locate(src, "bodies[1].x"), (5, 17));
        assert_eq!(locate(src, "bodies[0].name"), (4, 6));
    }

    #[test]
    fn locate_tuple_items() {
        let src = "Scene(\n  colliders: [\n    (name: \"a\", rotation_deg: (0.0, NaN, 0.0)),\n  ],\n  b: [1],\n)";
        // The item inside the tuple, not a later list's.
        assert_eq!(locate(src, "colliders[0].rotation_deg[1]"), (3, 37));
        assert_eq!(locate(src, "colliders[0].rotation_deg[2]"), (3, 42));
    }
}
