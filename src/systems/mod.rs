//! Forward stages of one substep, one file per stage, each a bevy_ecs system.
//!
//! The stage order (`docs/design.md` §2) is [`Stage::ALL`], written once; the forward schedule
//! chains the stage sets in that order and the adjoint schedule (`crate::adjoint`) in reverse:
//! grid reset → deformation update → SVD → constitutive model → P2G → tool move → gravity →
//! grid collision → G2P → particle collision → advect.
//!
//! The schedule is assembled from a [`SubstepPlan`] derived from the scene: a stage whose work
//! the scene does not need is not added (no tool: no tool move; no collider: no collider
//! contact; no thin-walled collider: no particle collision; one constitutive system per
//! material plug-in the scene uses).
//!
//! [`slab_schedule`] is not a stage: it runs the race-free slab scatter that P2G and the G2P
//! adjoint share. [`balance`] is not a stage either: an instrument, run once per global step in
//! the [`Instruments`] schedule of a scene that has one; it writes only what no stage reads, so
//! it has no adjoint.

pub mod advect;
pub mod balance;
pub mod constitutive;
pub mod deformation_update;
pub mod g2p;
pub mod gravity;
pub mod grid_collision;
pub mod grid_reset;
pub mod p2g;
pub mod particle_collision;
pub mod slab_schedule;
pub mod svd;
pub mod tool_move;

use crate::materials::MaterialSpec;
use bevy_ecs::prelude::*;
use bevy_ecs::schedule::{ExecutorKind, LogLevel, ScheduleBuildSettings, ScheduleLabel};
use glam::{DMat3, DVec3};
use rayon::prelude::*;

/// The substep schedule.
#[derive(ScheduleLabel, Debug, Clone, PartialEq, Eq, Hash)]
pub struct Substep;

/// The schedule of the instruments, run once per global step after its substeps.
#[derive(ScheduleLabel, Debug, Clone, PartialEq, Eq, Hash)]
pub struct Instruments;

/// The instruments' schedule of a scene with a balance; `None` for a scene without any.
pub fn build_instrument_schedule(has_balance: bool) -> Option<Schedule> {
    has_balance.then(|| {
        let mut s = Schedule::new(Instruments);
        s.set_executor_kind(ExecutorKind::SingleThreaded);
        s.add_systems(balance::balance);
        s
    })
}

/// The stages of a substep, in run order.
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Stage {
    GridReset,
    DeformationUpdate,
    Svd,
    Constitutive,
    P2g,
    ToolMove,
    Gravity,
    GridCollision,
    G2p,
    ParticleCollision,
    Advect,
}

impl Stage {
    /// The stages in run order: the one list both schedules derive from.
    pub const ALL: [Stage; 11] = [
        Stage::GridReset,
        Stage::DeformationUpdate,
        Stage::Svd,
        Stage::Constitutive,
        Stage::P2g,
        Stage::ToolMove,
        Stage::Gravity,
        Stage::GridCollision,
        Stage::G2p,
        Stage::ParticleCollision,
        Stage::Advect,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Stage::GridReset => "grid_reset",
            Stage::DeformationUpdate => "deformation_update",
            Stage::Svd => "svd",
            Stage::Constitutive => "constitutive",
            Stage::P2g => "p2g",
            Stage::ToolMove => "tool_move",
            Stage::Gravity => "gravity",
            Stage::GridCollision => "grid_collision",
            Stage::G2p => "g2p",
            Stage::ParticleCollision => "particle_collision",
            Stage::Advect => "advect",
        }
    }

    /// Whether a scene with `plan` runs this stage (and so its adjoint).
    pub fn runs(self, plan: &SubstepPlan) -> bool {
        match self {
            Stage::Constitutive => !plan.materials.is_empty(),
            Stage::ToolMove => plan.has_tools,
            Stage::ParticleCollision => plan.particle_contact,
            _ => true,
        }
    }
}

/// Orders the stage sets of `schedule` as [`Stage::ALL`] (`forward`) or in reverse.
pub fn chain_stages(schedule: &mut Schedule, forward: bool) {
    for w in Stage::ALL.windows(2) {
        let (a, b) = if forward { (w[0], w[1]) } else { (w[1], w[0]) };
        schedule.configure_sets(a.before(b));
    }
}

/// Orders the constitutive systems of several materials within their stage.
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct MaterialSlot(pub usize);

/// What a scene needs from the substep.
#[derive(Clone, Debug, Default)]
pub struct SubstepPlan {
    /// One spec per distinct material plug-in used by the scene's bodies.
    pub materials: Vec<MaterialSpec>,
    /// At least one kinematic tool.
    pub has_tools: bool,
    /// At least one tool or container.
    pub has_colliders: bool,
    /// At least one collider with particle contact (thin walls).
    pub particle_contact: bool,
}

/// Adds the systems of one stage to `schedule`, in the stage's set. Returns whether any was added.
pub fn add_stage(schedule: &mut Schedule, stage: Stage, plan: &SubstepPlan) -> bool {
    if !stage.runs(plan) {
        return false;
    }
    match stage {
        Stage::GridReset => {
            schedule.add_systems(grid_reset::grid_reset.in_set(stage));
        }
        Stage::DeformationUpdate => {
            schedule.add_systems(deformation_update::deformation_update.in_set(stage));
        }
        Stage::Svd => {
            schedule.add_systems(svd::svd.in_set(stage));
        }
        Stage::Constitutive => {
            // Materials touch disjoint bodies, but the ECS cannot know that: order them.
            for (i, m) in plan.materials.iter().enumerate() {
                schedule.add_systems(
                    m.constitutive_system()
                        .in_set(stage)
                        .in_set(MaterialSlot(i)),
                );
                if i > 0 {
                    schedule.configure_sets(MaterialSlot(i - 1).before(MaterialSlot(i)));
                }
            }
        }
        Stage::P2g => {
            schedule.add_systems(p2g::p2g.in_set(stage));
        }
        Stage::ToolMove => {
            schedule.add_systems(tool_move::tool_move.in_set(stage));
        }
        Stage::Gravity => {
            schedule.add_systems(gravity::gravity.in_set(stage));
        }
        Stage::GridCollision => {
            if plan.has_colliders {
                schedule.add_systems(
                    (
                        grid_collision::collider_contact,
                        grid_collision::domain_walls,
                    )
                        .chain()
                        .in_set(stage),
                );
            } else {
                schedule.add_systems(grid_collision::domain_walls.in_set(stage));
            }
        }
        Stage::G2p => {
            schedule.add_systems(g2p::g2p.in_set(stage));
        }
        Stage::ParticleCollision => {
            schedule.add_systems(particle_collision::particle_collision.in_set(stage));
        }
        Stage::Advect => {
            schedule.add_systems(advect::advect.in_set(stage));
        }
    }
    true
}

/// A new single-threaded schedule (parallelism is inside systems, over particles) with
/// ambiguity detection as an error, so two unordered systems writing the same data fail to build.
pub fn new_schedule() -> Schedule {
    let mut s = Schedule::new(Substep);
    s.set_executor_kind(ExecutorKind::SingleThreaded);
    s.set_build_settings(ScheduleBuildSettings {
        ambiguity_detection: LogLevel::Error,
        ..Default::default()
    });
    s
}

/// The whole substep as one schedule with chained stage sets.
pub fn build_substep_schedule(plan: &SubstepPlan) -> Schedule {
    let mut s = new_schedule();
    chain_stages(&mut s, true);
    for stage in Stage::ALL {
        add_stage(&mut s, stage, plan);
    }
    s
}

/// One schedule per stage, for per-stage timing (`powderlab bench`). Same systems, same order.
pub fn build_stage_schedules(plan: &SubstepPlan) -> Vec<(&'static str, Schedule)> {
    Stage::ALL
        .iter()
        .filter_map(|&stage| {
            let mut s = new_schedule();
            add_stage(&mut s, stage, plan).then_some((stage.name(), s))
        })
        .collect()
}

/// Raised by a stage's parallel loop when a value it wrote is not finite. The stage tests each
/// value while it holds it and scans the field (to name the first bad particle or node, the
/// same one for any thread count) only when the watch was raised, instead of reading the whole
/// field again after every substep. The forward stages keep one per call; the backward pass
/// shares one between its stages and driver (`crate::adjoint::NonFiniteSeen`).
#[derive(Debug, Default)]
pub struct FiniteWatch(std::sync::atomic::AtomicBool);

impl FiniteWatch {
    /// Raises the watch if `finite` is false.
    #[inline(always)]
    pub fn check(&self, finite: bool) {
        if !finite {
            self.0.store(true, std::sync::atomic::Ordering::Relaxed);
        }
    }

    /// Whether any check failed.
    pub fn raised(&self) -> bool {
        self.0.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Whether any check failed since the last call; lowers the watch.
    pub fn take(&self) -> bool {
        self.0.swap(false, std::sync::atomic::Ordering::Relaxed)
    }

    /// [`first_nonfinite_vec`] of `xs` if the watch was raised, else `None` without a scan.
    pub fn first_nonfinite_vec(&self, xs: &[DVec3]) -> Option<usize> {
        self.raised().then(|| first_nonfinite_vec(xs)).flatten()
    }

    /// [`first_nonfinite_mat`] of `xs` if the watch was raised, else `None` without a scan.
    pub fn first_nonfinite_mat(&self, xs: &[DMat3]) -> Option<usize> {
        self.raised().then(|| first_nonfinite_mat(xs)).flatten()
    }
}

/// Whether every value is finite: `Σ 0·x` is 0 when all are and NaN otherwise (`0·±∞` is NaN)
/// and never overflows. Eight independent partial sums let the loop vectorise, so the common
/// case costs one streaming pass.
#[inline]
fn all_finite(values: &[f64]) -> bool {
    let mut acc = [0.0f64; 8];
    let chunks = values.chunks_exact(8);
    let rest = chunks.remainder();
    for c in chunks {
        for k in 0..8 {
            acc[k] += 0.0 * c[k];
        }
    }
    acc.iter().all(|a| *a == 0.0) && rest.iter().all(|x| x.is_finite())
}

/// Index of the first non-finite vector. Checks in fixed chunks in parallel; only a chunk that
/// fails is searched, so the answer is the same for any thread count.
pub fn first_nonfinite_vec(xs: &[DVec3]) -> Option<usize> {
    first_nonfinite(xs, |c: &[DVec3]| all_finite(bytemuck::cast_slice(c)))
        .and_then(|s| xs[s..].iter().position(|v| !v.is_finite()).map(|i| s + i))
}

/// Index of the first non-finite matrix.
pub fn first_nonfinite_mat(xs: &[DMat3]) -> Option<usize> {
    first_nonfinite(xs, |c: &[DMat3]| all_finite(bytemuck::cast_slice(c)))
        .and_then(|s| xs[s..].iter().position(|m| !m.is_finite()).map(|i| s + i))
}

/// Items per chunk of the finiteness check.
const CHECK_CHUNK: usize = 8192;

/// Start of the first chunk that fails `ok`.
fn first_nonfinite<T: Sync>(xs: &[T], ok: impl Fn(&[T]) -> bool + Sync) -> Option<usize> {
    if xs.len() <= CHECK_CHUNK {
        return (!ok(xs)).then_some(0);
    }
    xs.par_chunks(CHECK_CHUNK)
        .position_first(|c| !ok(c))
        .map(|c| c * CHECK_CHUNK)
}
