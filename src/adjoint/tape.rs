//! The backward pass: checkpoints, recomputation and the reverse sweep.
//!
//! The forward pass stores the particle state every `k` global steps (a checkpoint,
//! [`checkpoint`](super::checkpoint)). The backward pass walks the segments between checkpoints
//! from last to first: it restores the segment's checkpoint, recomputes the segment's
//! step-start states, and for each step in reverse recomputes its substeps once, recording
//! each, then reverses them through the adjoint stages ([`replay`](super::replay)).
//!
//! Memory: `O(T/k·N + k·N)` particle states of `(x, v, C, F, V_svd)` plus `N_sub` substep
//! records; `k` comes from a memory budget ([`checkpoint_interval`]). The SVD's warm-start `V`
//! is part of the stored state, so a recomputed substep is bitwise the original one and the
//! gradient does not depend on `k` or on the thread count.
//!
//! The result ([`Gradients`]) is with respect to the initial state, the material parameters,
//! collider friction, gravity, and each tool's start pose and per-step controls. What the
//! controls come from (a skill's parameters Θ, say) is the caller's: the adjoint knows
//! nothing of skills.

use super::checkpoint::{checkpoint_interval, restore, snapshot};
pub use super::checkpoint::{Snapshot, Tape};
use super::gravity::GravityAdj;
use super::grid_collision::ColliderAdj;
pub use super::loss::{Carry, CarryGrad, Loss, Term};
use super::particle_collision::ParticleCollisionInput;
use super::replay::{Replay, SubstepRecord, Timing};
use super::tool_move::ControlAdj;
use super::NonFiniteSeen;
use crate::components::*;
use crate::error::AdjointError;
use crate::materials::Param;
use crate::sim::Simulation;
use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3};
use std::time::Instant;

/// (scene index, name, ∂L/∂t(0), ∂L/∂u per step, ∂L/∂θ(0)) of one tool.
type ToolGrad = (usize, String, DVec3, Vec<[f64; 6]>, DVec3);

/// Gradients of a loss on the final state.
#[derive(Clone, Debug)]
pub struct Gradients {
    pub loss: f64,
    /// `∂L/∂x(0)` per body.
    pub x0: Vec<Vec<DVec3>>,
    /// `∂L/∂v(0)` per body.
    pub v0: Vec<Vec<DVec3>>,
    /// Material-parameter gradients per body, in the order of its material's
    /// `Material::PARAMS` (see [`Gradients::material_gradient`]).
    pub material: Vec<MaterialAdj>,
    /// The differentiable parameters of each body's material.
    pub material_params: Vec<&'static [Param]>,
    /// `∂L/∂g`.
    pub gravity: DVec3,
    /// `∂L/∂μ` per collider (name, gradient), in scene order.
    pub friction: Vec<(String, f64)>,
    /// `∂L/∂t(0)`: the gradient with respect to each tool's start position.
    pub tool_start: Vec<(String, DVec3)>,
    /// `∂L/∂θ(0)`: with respect to each tool's start orientation (world-frame rotation vector).
    pub tool_start_rotation: Vec<(String, DVec3)>,
    /// `∂L/∂u` per global step of each tool's control sequence (translation, rotation vector).
    pub controls: Vec<(String, Vec<[f64; 6]>)>,
    /// Checkpoint interval used, in global steps.
    pub checkpoint_every: usize,
    /// Bytes of particle state held at the peak (checkpoints + one segment + one step).
    pub tape_bytes: usize,
    /// Wall seconds per part of the pass: the taped forward, the recomputations, each stage's
    /// forward re-run and adjoint, in first-run order.
    pub timing: Vec<(String, f64)>,
}

impl Gradients {
    /// `∂L/∂p` for parameter `name` of body `body`'s material, if it declares one.
    pub fn material_gradient(&self, body: usize, name: &str) -> Option<f64> {
        let k = self.material_params[body]
            .iter()
            .position(|p| p.name == name)?;
        Some(self.material[body].0[k])
    }

    /// `∂L/∂u` per global step of the tool named `tool`, if it has controls.
    pub fn tool_controls(&self, tool: &str) -> Option<&[[f64; 6]]> {
        self.controls
            .iter()
            .find(|(n, _)| n == tool)
            .map(|(_, g)| g.as_slice())
    }
}

/// Runs `steps` global steps from the simulation's current state and returns the gradients of
/// `loss` on the final positions. The simulation is left at the final state.
///
/// The whole pass runs on one of the simulation's own workers (or, for a simulation in the
/// caller's pool, on a worker of that pool): each stage's parallel loops then
/// start from inside the pool, instead of the calling thread handing the world to the pool and
/// sleeping until it is done, two thread switches per stage and about twenty stages per substep
/// (forward recomputation, adjoint and finiteness checks). The numbers do not change: every
/// parallel loop splits its work in fixed chunks.
pub fn gradient(
    sim: &mut Simulation,
    steps: usize,
    loss: &Loss,
    tape: Tape,
) -> Result<Gradients, AdjointError> {
    gradient_with(sim, steps, loss, &[], tape)
}

/// [`gradient`] of `loss` on the final positions plus `terms`, each a loss on the state at the
/// start of its step ([`Term`]: a tool's carried mass while it moves, or an observation of the
/// positions at that time). The reverse sweep adds each term's gradient to the particles' (and a
/// carry term's tool's) adjoints when it reaches the term's step.
pub fn gradient_with(
    sim: &mut Simulation,
    steps: usize,
    loss: &Loss,
    terms: &[Term],
    tape: Tape,
) -> Result<Gradients, AdjointError> {
    sim.on_worker(|sim| gradient_in_pool(sim, steps, loss, terms, tape))
}

/// Every body's positions, in scene order.
fn positions(world: &mut World) -> Vec<Vec<DVec3>> {
    let mut q = world.query::<(&Body, &Position)>();
    let mut xs: Vec<(usize, Vec<DVec3>)> =
        q.iter(world).map(|(b, x)| (b.index, x.0.clone())).collect();
    xs.sort_by_key(|e| e.0);
    xs.into_iter().map(|e| e.1).collect()
}

/// A term's value and gradients from the state at its step.
fn score_term(world: &mut World, term: &Term) -> Result<CarryGrad, AdjointError> {
    match term {
        Term::Carry(c) => {
            let (xs, pose) = positions_and_pose(world, &c.tool)?;
            Ok(c.eval(&xs, &pose))
        }
        Term::Positions { loss, .. } => {
            let (value, x) = loss.eval(&positions(world));
            Ok(CarryGrad {
                value,
                mass: 0.0,
                x,
                translation: DVec3::ZERO,
                rotation: DVec3::ZERO,
            })
        }
    }
}

/// Every body's positions, in scene order, and the pose of the collider named `tool`.
fn positions_and_pose(
    world: &mut World,
    tool: &str,
) -> Result<(Vec<Vec<DVec3>>, crate::math::pose::Pose), AdjointError> {
    let xs = positions(world);
    let mut c = world.query::<(&Collider, &ColliderPose)>();
    let pose = c
        .iter(world)
        .find(|(c, _)| c.name == tool)
        .map(|(_, p)| p.pose)
        .ok_or_else(|| {
            AdjointError::NotDifferentiable(format!(
                "a carry loss names a tool '{tool}' the scene does not have"
            ))
        })?;
    Ok((xs, pose))
}

/// Adds a term's gradient to the adjoint state (the particles' positions and, for a carry term,
/// its tool's pose).
fn add_term_gradient(world: &mut World, bodies: &[Entity], term: &Term, g: &CarryGrad) {
    for (e, gx) in bodies.iter().zip(&g.x) {
        if let Some(mut adj) = world.get_mut::<PositionAdj>(*e) {
            for (a, b) in adj.0.iter_mut().zip(gx) {
                *a += *b;
            }
        }
    }
    let Term::Carry(term) = term else {
        return;
    };
    let mut q = world.query::<(&Collider, &mut ColliderAdj)>();
    for (c, mut a) in q.iter_mut(world) {
        if c.name == term.tool {
            a.translation += g.translation;
            a.rotation += g.rotation;
        }
    }
}

fn gradient_in_pool(
    sim: &mut Simulation,
    steps: usize,
    loss: &Loss,
    terms: &[Term],
    tape: Tape,
) -> Result<Gradients, AdjointError> {
    if sim.rests() {
        return Err(AdjointError::NotDifferentiable(
            "the simulation sets resting powder aside (SimOptions::rest), which the tape does \
             not record; build it with rest: None for a gradient"
                .into(),
        ));
    }
    if let Some(t) = terms.iter().find(|t| t.step() > steps) {
        return Err(AdjointError::NotDifferentiable(format!(
            "a loss term at step {} of a {steps}-step pass",
            t.step()
        )));
    }
    for c in &sim.scene.colliders {
        if c.kind != crate::scene::ColliderKindSpec::Tool {
            continue;
        }
        if c.shape.sdf_hessian(DVec3::ZERO).is_none() {
            return Err(AdjointError::NotDifferentiable(format!(
                "tool '{}': the contact adjoint of a moving {} needs its SDF Hessian, not implemented yet (box, sphere, capsule and plane tools are differentiable)",
                c.name,
                c.shape.name()
            )));
        }
    }
    if let Some(c) = sim
        .scene
        .colliders
        .iter()
        .find(|c| c.particle_contact && c.shape.sdf_hessian(DVec3::ZERO).is_none())
    {
        return Err(AdjointError::NotDifferentiable(format!(
            "collider '{}': particle collision against a {} needs its SDF Hessian, not implemented yet",
            c.name,
            c.shape.name()
        )));
    }
    if sim.scene.colliders.len() > crate::adjoint::grid_collision::MAX_COLLIDERS {
        return Err(AdjointError::NotDifferentiable(format!(
            "more than {} colliders",
            crate::adjoint::grid_collision::MAX_COLLIDERS
        )));
    }
    if sim.plan.materials.iter().any(|m| m.hardens()) {
        return Err(AdjointError::NotDifferentiable(
            "Klár hardening has no adjoint yet".into(),
        ));
    }
    let substeps = sim.params().substeps;
    if steps == 0 {
        return Err(AdjointError::NotDifferentiable(
            "a horizon of 0 steps has no gradient to compute".into(),
        ));
    }
    let start = snapshot(&mut sim.world);
    let nodes = sim.world.resource::<Grid>().node_count();
    let particles: usize = start.bodies.iter().map(|b| b.x.len()).sum();
    let records_bytes = substeps * SubstepRecord::bytes(particles, nodes);
    let k = match tape {
        Tape::Budget(b) => checkpoint_interval(steps, start.bytes(), records_bytes, b)?,
        Tape::Every(k) => k.clamp(1, steps.max(1)),
    };
    let mut timing = Timing::default();
    let t_pass = Instant::now();
    // Forward, keeping a checkpoint every k steps.
    let mut checkpoints = Vec::with_capacity(steps.div_ceil(k));
    let last_segment = (steps - 1) / k * k;
    let mut last_starts = Vec::new();
    // Each term's value and gradients, from the forward state at its step.
    let mut carried: Vec<Option<CarryGrad>> = vec![None; terms.len()];
    let mut score = |world: &mut World, s: usize| -> Result<(), AdjointError> {
        for (t, slot) in terms.iter().zip(carried.iter_mut()) {
            if t.step() == s {
                *slot = Some(score_term(world, t)?);
            }
        }
        Ok(())
    };
    for s in 0..steps {
        score(&mut sim.world, s)?;
        if s % k == 0 {
            checkpoints.push(snapshot(&mut sim.world));
        }
        if s >= last_segment {
            last_starts.push(snapshot(&mut sim.world));
        }
        sim.step()?;
    }
    score(&mut sim.world, steps)?;
    let carried: Vec<CarryGrad> = carried
        .into_iter()
        .map(|c| c.expect("every term's step was scored"))
        .collect();
    let final_state = snapshot(&mut sim.world);
    timing.add("forward (taped)", t_pass.elapsed().as_secs_f64());
    let final_x: Vec<Vec<DVec3>> = final_state.bodies.iter().map(|b| b.x.clone()).collect();
    let (final_value, g_x) = loss.eval(&final_x);
    let loss_value = final_value + carried.iter().map(|c| c.value).sum::<f64>();

    let (body_ents, collider_ents) = install_adjoint_state(&mut sim.world, g_x);
    let add_terms_at = |world: &mut World, s: usize| {
        for (t, g) in terms.iter().zip(&carried) {
            if t.step() == s {
                add_term_gradient(world, &body_ents, t, g);
            }
        }
    };
    add_terms_at(&mut sim.world, steps);
    let plan = sim.plan.clone();
    let mut replay = Replay::new(&mut sim.world, &plan, body_ents.clone(), substeps);
    let mut peak_snaps = checkpoints.len();
    for (ci, cp) in checkpoints.iter().enumerate().rev() {
        let s0 = ci * k;
        let s1 = (s0 + k).min(steps);
        // Step-start states of the segment (kept from the first pass for the last segment).
        let step_starts = if s0 == last_segment {
            std::mem::take(&mut last_starts)
        } else {
            let t = Instant::now();
            restore(&mut sim.world, cp);
            let mut v = Vec::with_capacity(s1 - s0);
            for _ in s0..s1 {
                v.push(snapshot(&mut sim.world));
                sim.step()?;
            }
            timing.add("recompute: step starts", t.elapsed().as_secs_f64());
            v
        };
        peak_snaps = peak_snaps.max(checkpoints.len() + step_starts.len());
        for (si, ss) in step_starts.iter().enumerate().rev() {
            replay.recompute_step(sim, ss, &mut timing)?;
            replay.reverse_step(sim, s0 + si, &mut timing)?;
            add_terms_at(&mut sim.world, s0 + si);
        }
    }
    let snap_bytes = start.bytes();
    let mut q = sim
        .world
        .query::<(&Body, &PositionAdj, &VelocityAdj, &MaterialAdj)>();
    let mut per: Vec<_> = q
        .iter(&sim.world)
        .map(|(b, gx, gv, m)| (b.index, gx.0.clone(), gv.0.clone(), *m))
        .collect();
    per.sort_by_key(|e| e.0);
    let gravity = sim.world.resource::<GravityAdj>().0;
    let mut cq = sim.world.query::<(&Collider, &ColliderAdj)>();
    let mut tq = sim.world.query::<(&Collider, &ColliderAdj, &ControlAdj)>();
    let mut tools: Vec<ToolGrad> = tq
        .iter(&sim.world)
        .map(|(c, a, u)| {
            (
                c.index,
                c.name.clone(),
                a.translation,
                u.0.clone(),
                a.rotation,
            )
        })
        .collect();
    tools.sort_by_key(|e| e.0);
    let mut friction: Vec<(usize, String, f64)> = cq
        .iter(&sim.world)
        .map(|(c, a)| (c.index, c.name.clone(), a.friction))
        .collect();
    friction.sort_by_key(|e| e.0);
    for &e in &collider_ents {
        sim.world
            .entity_mut(e)
            .remove::<(ColliderAdj, ControlAdj)>();
    }
    sim.world.remove_resource::<ColliderInputVelocity>();
    // Leave the world at the final forward state, without adjoint buffers.
    for &e in &body_ents {
        sim.world.entity_mut(e).remove::<(
            PositionAdj,
            VelocityAdj,
            AffineVelocityAdj,
            DeformationGradientAdj,
            TrialDeformationAdj,
            SvdFactorsAdj,
            P2gAffineAdj,
            SubstepStart,
            ParticleCollisionInput,
            MaterialAdj,
            UpdateSaved,
            PrincipalStress,
        )>();
    }
    sim.world.remove_resource::<GridAdj>();
    sim.world.remove_resource::<WallInputVelocity>();
    sim.world.remove_resource::<GravityAdj>();
    sim.world.remove_resource::<NonFiniteSeen>();
    restore(&mut sim.world, &final_state);
    Ok(Gradients {
        loss: loss_value,
        x0: per.iter().map(|e| e.1.clone()).collect(),
        v0: per.iter().map(|e| e.2.clone()).collect(),
        material: per.iter().map(|e| e.3).collect(),
        material_params: sim
            .scene
            .bodies
            .iter()
            .map(|b| sim.scene.materials[&b.material].params())
            .collect(),
        gravity,
        friction: friction.into_iter().map(|e| (e.1, e.2)).collect(),
        tool_start: tools.iter().map(|e| (e.1.clone(), e.2)).collect(),
        tool_start_rotation: tools.iter().map(|e| (e.1.clone(), e.4)).collect(),
        controls: tools.into_iter().map(|e| (e.1, e.3)).collect(),
        checkpoint_every: k,
        tape_bytes: peak_snaps * snap_bytes + records_bytes,
        timing: timing.0,
    })
}

/// Inserts the adjoint buffers, zeroed but for `∂L/∂x(T) = g_x`, and the contact inputs the
/// recomputation saves; returns the body entities in scene order and the collider entities.
fn install_adjoint_state(world: &mut World, g_x: Vec<Vec<DVec3>>) -> (Vec<Entity>, Vec<Entity>) {
    let len = world.resource::<Grid>().node_count();
    world.insert_resource(GridAdj::new(len));
    world.insert_resource(GravityAdj::default());
    world.insert_resource(NonFiniteSeen::default());
    world.insert_resource(WallInputVelocity(vec![DVec3::ZERO; len]));
    world.insert_resource(ColliderInputVelocity(vec![DVec3::ZERO; len]));
    let collider_ents: Vec<Entity> = world
        .query_filtered::<Entity, With<Collider>>()
        .iter(world)
        .collect();
    for &e in &collider_ents {
        world.entity_mut(e).insert(ColliderAdj::default());
        let n = world.get::<Control>(e).map(|c| c.per_step.len());
        if let Some(n) = n {
            world.entity_mut(e).insert(ControlAdj(vec![[0.0; 6]; n]));
        }
    }
    let ents: Vec<(Entity, usize, usize)> = world
        .query::<(Entity, &Body, &Position)>()
        .iter(world)
        .map(|(e, b, x)| (e, b.index, x.0.len()))
        .collect();
    for &(e, bi, n) in &ents {
        world.entity_mut(e).insert((
            PositionAdj(g_x[bi].clone()),
            VelocityAdj(vec![DVec3::ZERO; n]),
            AffineVelocityAdj(vec![DMat3::ZERO; n]),
            DeformationGradientAdj(vec![DMat3::ZERO; n]),
            TrialDeformationAdj(vec![DMat3::ZERO; n]),
            SvdFactorsAdj {
                u: vec![DMat3::ZERO; n],
                s: vec![DVec3::ZERO; n],
                v: vec![DMat3::ZERO; n],
            },
            P2gAffineAdj(vec![DMat3::ZERO; n]),
            SubstepStart::zeroed(n),
            ParticleCollisionInput::default(),
            MaterialAdj::default(),
            // From here on the constitutive stage saves its update (and its stress, which the
            // records keep instead of the P2G affine term) for the adjoint.
            UpdateSaved(vec![[DVec3::ZERO; 3]; n]),
            PrincipalStress(vec![DVec3::ZERO; n]),
        ));
    }
    let mut by_index: Vec<(usize, Entity)> = ents.iter().map(|&(e, bi, _)| (bi, e)).collect();
    by_index.sort_by_key(|e| e.0);
    (by_index.into_iter().map(|e| e.1).collect(), collider_ents)
}
