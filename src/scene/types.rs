//! What a scene file holds. Each type documents its fields' units and defaults;
//! `scenes/README.md` lists them all.

use crate::components::{ContactMode, Precision};
use crate::materials::MaterialSpec;
use crate::math::sdf::Shape;
use crate::skills::SkillSpec;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::PathBuf;

/// The most worker threads a scene or `--threads` may ask for. More is a typo, not a machine:
/// every rayon thread is an OS thread with its own stack, and `bench --threads 100000` on a
/// 4,096-particle scene had started 15,589 threads after 14 minutes on 2 cores, without finishing
/// its one step.
pub const MAX_THREADS: usize = 1024;

/// Parses `--threads`: 0 (all cores) up to [`MAX_THREADS`].
pub fn threads_arg(s: &str) -> Result<usize, String> {
    let max = MAX_THREADS;
    match s.parse::<usize>() {
        Ok(n) if n <= max => Ok(n),
        _ => Err(format!(
            "expected a whole number from 0 (all cores) to {max}, got '{s}'"
        )),
    }
}

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
    /// jump under a 1e-9 change of Θ (`diagnostics/rollout_divergence.rs`). `sand_box` keeps 1e-6
    /// to match the reference bit for bit.
    #[serde(default = "default_empty_node_ratio")]
    pub empty_node_ratio: f64,
    /// Precision of the SVD stage, `F64` or `F32`. Default `F64`. `F32` decomposes eight
    /// particles per AVX2 register and stops the Jacobi iteration at f32's round-off, the
    /// factors good to about 1e-7 of ‖F‖; every other quantity stays f64. It changes results at
    /// that level, so the finite-difference checks run in `F64` (`docs/results/performance.md`,
    /// "Precision"). Left out of the written scene at its default, so that the fingerprints of
    /// scenes from before the setting, which key kept journals, stay what they were.
    #[serde(default, skip_serializing_if = "Precision::is_f64")]
    pub svd: Precision,
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
    /// Vertical cylinder standing on `base` (m). With `quarter`, only its quarter at
    /// `x ≥ base.x`, `z ≥ base.z`: a run against two frictionless walls that stand for the
    /// cylinder's planes of symmetry, at a quarter of the particles (the axisymmetric collapse).
    Cylinder {
        base: (f64, f64, f64),
        radius: f64,
        height: f64,
        #[serde(default, skip_serializing_if = "std::ops::Not::not")]
        quarter: bool,
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
    /// The skill mapping Θ → controls (docs/design.md §4).
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
    /// Make that projection soft: C¹ where powder rests against the collider or slides along it,
    /// so that gradients there are derivatives rather than one branch of a kink; particles
    /// settle one clearance (a twentieth of a cell) farther out. Default false.
    #[serde(default)]
    pub soft_particle_contact: bool,
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

/// An analytical balance under a Cup container: it weighs the powder in the cup's cavity and
/// shows it through a first-order settling lag, with seeded noise, rounded to its readability.
/// The defaults are an analytical balance's figures: 0.1 mg readability and repeatability, and
/// a settling time constant of 0.5 s (within 1 % of a step in the load after 2.3 s, the 2–3 s
/// settling time such balances state).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BalanceSpec {
    /// Name of the Cup container on the balance (the weighing boat).
    pub container: String,
    /// The smallest step the display shows (mg). Default 0.1.
    #[serde(default = "default_resolution_mg")]
    pub resolution_mg: f64,
    /// Standard deviation of the reading's noise (mg), drawn afresh at every reading.
    /// Default 0.1.
    #[serde(default = "default_noise_mg")]
    pub noise_mg: f64,
    /// Time constant of the settling lag (s). Default 0.5.
    #[serde(default = "default_settle_s")]
    pub settle_s: f64,
    /// Seed of the noise. Default 0.
    #[serde(default)]
    pub seed: u64,
}

fn default_resolution_mg() -> f64 {
    0.1
}
fn default_noise_mg() -> f64 {
    0.1
}
fn default_settle_s() -> f64 {
    0.5
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
        /// Width of the soft indicator's ramps (m), > 0. Default: a quarter of the particle
        /// spacing (`crate::adjoint::loss::DOSING_WIDTH_PER_SPACING`).
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
    /// What `powderlab plan` searches for; other commands ignore it.
    #[serde(default)]
    pub plan: Option<super::plan::PlanSpec>,
    /// The ranges `powderlab policy` draws scenes from; other commands ignore it.
    #[serde(default)]
    pub randomize: Option<super::randomize::Randomization>,
    /// An analytical balance under a container (`powderlab weigh` closes its loop on it).
    #[serde(default)]
    pub balance: Option<BalanceSpec>,
    /// Where the scene came from (for messages).
    #[serde(skip)]
    pub path: PathBuf,
    #[serde(skip)]
    pub source: String,
}
