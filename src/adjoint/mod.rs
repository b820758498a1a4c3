//! Adjoint systems: one file per forward stage, mirroring `src/systems` name for name
//! (`systems/p2g.rs::p2g` ↔ `adjoint/p2g.rs::p2g_adjoint`). They run in the `SubstepAdjoint`
//! schedule, whose sets are the forward [`Stage`] sets chained in exactly the reverse order.
//!
//! The adjoint of a gather is a scatter-add and the adjoint of a scatter is a gather: G2P's
//! adjoint scatters into the grid with the same race-free slab schedule as P2G, and P2G's
//! adjoint gathers per particle, so gradients are bitwise identical for any thread count.
//!
//! Every adjoint system reads the forward values of its substep: the backward driver
//! ([`tape`], with [`checkpoint`] and [`replay`]) restores the substep's start state, re-runs the forward stages up to G2P (which
//! refills the scratch: SVD factors, affine term, grid) and keeps the start state in
//! [`SubstepStart`](crate::components::SubstepStart) for the stages whose inputs were
//! overwritten in place.
//!
//! Not yet differentiated, and refused loudly by the backward driver: Klár hardening (the
//! friction angle's dependence on the plastic strain).

pub mod advect;
pub mod checkpoint;
pub mod constitutive;
pub mod deformation_update;
pub mod g2p;
pub mod gravity;
pub mod grid_collision;
pub mod grid_reset;
pub mod loss;
pub mod p2g;
pub mod particle_collision;
pub mod replay;
pub mod svd;
pub mod tape;
pub mod tool_move;

use crate::systems::FiniteWatch;
use crate::systems::{new_schedule, Stage, SubstepPlan};
use bevy_ecs::prelude::*;
use bevy_ecs::schedule::ScheduleLabel;

/// Raised by an adjoint stage that has just written a non-finite value into one of the particle
/// fields the backward driver checks after it (`replay.rs`, `written_by`). The stages test the
/// values they write while they hold them, so the driver scans those fields (to name the
/// particle) only after a stage that raised it, instead of reading every field after every
/// stage. Where the resource is absent (an adjoint system run alone), nothing is raised.
#[derive(Resource, Debug, Default)]
pub struct NonFiniteSeen(FiniteWatch);

impl NonFiniteSeen {
    /// Raises the flag if `finite` is false.
    #[inline(always)]
    pub fn check(seen: Option<&Self>, finite: bool) {
        if let Some(s) = seen {
            s.0.check(finite);
        }
    }

    /// Whether the flag was raised since the last call; lowers it.
    pub fn take(&self) -> bool {
        self.0.take()
    }
}

/// The adjoint substep schedule.
#[derive(ScheduleLabel, Debug, Clone, PartialEq, Eq, Hash)]
pub struct SubstepAdjoint;

/// Adds the adjoint systems of one stage. Returns whether any was added.
pub fn add_adjoint_stage(schedule: &mut Schedule, stage: Stage, plan: &SubstepPlan) -> bool {
    if !stage.runs(plan) {
        return false;
    }
    match stage {
        // Nothing to do (see `grid_reset`'s module docs).
        Stage::GridReset => return false,
        Stage::DeformationUpdate => {
            schedule.add_systems(deformation_update::deformation_update_adjoint.in_set(stage));
        }
        Stage::Svd => {
            schedule.add_systems(svd::svd_adjoint.in_set(stage));
        }
        Stage::Constitutive => {
            for (i, m) in plan.materials.iter().enumerate() {
                schedule.add_systems(
                    m.constitutive_adjoint_system()
                        .in_set(stage)
                        .in_set(crate::systems::MaterialSlot(i)),
                );
                if i > 0 {
                    // Reverse order of the forward material systems.
                    schedule.configure_sets(
                        crate::systems::MaterialSlot(i).before(crate::systems::MaterialSlot(i - 1)),
                    );
                }
            }
        }
        Stage::P2g => {
            schedule.add_systems(p2g::p2g_adjoint.in_set(stage));
        }
        Stage::Gravity => {
            schedule.add_systems(gravity::gravity_adjoint.in_set(stage));
        }
        Stage::GridCollision => {
            if plan.has_colliders {
                // Reverse of the forward chain (colliders, then walls).
                schedule.add_systems(
                    (
                        grid_collision::domain_walls_adjoint,
                        grid_collision::collider_contact_adjoint,
                    )
                        .chain()
                        .in_set(stage),
                );
            } else {
                schedule.add_systems(grid_collision::domain_walls_adjoint.in_set(stage));
            }
        }
        Stage::G2p => {
            schedule.add_systems(g2p::g2p_adjoint.in_set(stage));
        }
        Stage::Advect => {
            schedule.add_systems(advect::advect_adjoint.in_set(stage));
        }
        Stage::ToolMove => {
            schedule.add_systems(tool_move::tool_move_adjoint.in_set(stage));
        }
        Stage::ParticleCollision => {
            schedule.add_systems(particle_collision::particle_collision_adjoint.in_set(stage));
        }
    }
    true
}

/// The adjoint substep: the forward stage sets chained in reverse.
pub fn build_substep_adjoint_schedule(plan: &SubstepPlan) -> Schedule {
    let mut s = new_schedule();
    crate::systems::chain_stages(&mut s, false);
    for stage in Stage::ALL.iter().rev() {
        add_adjoint_stage(&mut s, *stage, plan);
    }
    s
}
