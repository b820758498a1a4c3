//! Checkpoints of the backward pass: the particle and tool state at the start of a global
//! step ([`Snapshot`]), and the checkpoint interval a memory budget allows.
//!
//! The SVD's warm-start `V` is part of a snapshot, so a step recomputed from one is bitwise the
//! original step, and the gradient does not depend on the interval or the thread count.

use crate::components::*;
use crate::error::AdjointError;
use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3};

/// The particle state of every body (scene order) plus the clock.
#[derive(Clone, Debug)]
pub struct Snapshot {
    pub bodies: Vec<BodySnap>,
    /// Collider poses in scene order (tools move).
    pub colliders: Vec<ColliderPose>,
    pub clock: Clock,
}

#[derive(Clone, Debug)]
pub struct BodySnap {
    pub x: Vec<DVec3>,
    pub v: Vec<DVec3>,
    pub c: Vec<DMat3>,
    pub f: Vec<DMat3>,
    /// The SVD `V` the next substep warm-starts from.
    pub svd_v: Vec<DMat3>,
}

impl Snapshot {
    pub fn bytes(&self) -> usize {
        self.bodies
            .iter()
            .map(|b| b.x.len() * (2 * 24 + 3 * 72))
            .sum()
    }
}

type BodyStateQuery<'a> = (
    &'a Body,
    &'a Position,
    &'a Velocity,
    &'a AffineVelocity,
    &'a DeformationGradient,
    &'a SvdFactors,
);

/// Copies the state out of the world.
pub fn snapshot(world: &mut World) -> Snapshot {
    let mut q = world.query::<BodyStateQuery>();
    let mut b: Vec<_> = q
        .iter(world)
        .map(|(b, x, v, c, f, s)| {
            (
                b.index,
                BodySnap {
                    x: x.0.clone(),
                    v: v.0.clone(),
                    c: c.0.clone(),
                    f: f.0.clone(),
                    svd_v: s.v.clone(),
                },
            )
        })
        .collect();
    b.sort_by_key(|e| e.0);
    Snapshot {
        colliders: collider_states(world),
        bodies: b.into_iter().map(|e| e.1).collect(),
        clock: *world.resource::<Clock>(),
    }
}

/// Writes a snapshot back into the world.
pub fn restore(world: &mut World, snap: &Snapshot) {
    let mut q = world.query::<(
        &Body,
        &mut Position,
        &mut Velocity,
        &mut AffineVelocity,
        &mut DeformationGradient,
        &mut SvdFactors,
    )>();
    for (b, mut x, mut v, mut c, mut f, mut s) in q.iter_mut(world) {
        let sn = &snap.bodies[b.index];
        x.0.clone_from(&sn.x);
        v.0.clone_from(&sn.v);
        c.0.clone_from(&sn.c);
        f.0.clone_from(&sn.f);
        s.v.clone_from(&sn.svd_v);
    }
    *world.resource_mut::<Clock>() = snap.clock;
    let mut cq = world.query::<(&Collider, &mut ColliderPose)>();
    for (c, mut p) in cq.iter_mut(world) {
        *p = snap.colliders[c.index];
    }
}

/// Collider poses in scene order.
pub(crate) fn collider_states(world: &mut World) -> Vec<ColliderPose> {
    let mut cq = world.query::<(&Collider, &ColliderPose)>();
    let mut cs: Vec<(usize, ColliderPose)> = cq.iter(world).map(|(c, p)| (c.index, *p)).collect();
    cs.sort_by_key(|e| e.0);
    cs.into_iter().map(|e| e.1).collect()
}

/// Snapshots the tape holds at its peak with checkpoint interval `k`: `⌈T/k⌉` checkpoints and
/// the `k` step-start states of one segment (plus one step's substep records, counted apart).
pub fn tape_snapshots(steps: usize, k: usize) -> usize {
    steps.div_ceil(k) + k
}

/// The checkpoint interval for a memory budget: the largest `k` whose tape (snapshots plus one
/// step's substep records of `records_bytes`) fits; the first forward pass keeps the last
/// segment's step states, so a longer segment saves recomputation. An error if even the
/// smallest tape (`k ≈ √T`) does not fit.
pub fn checkpoint_interval(
    steps: usize,
    snapshot_bytes: usize,
    records_bytes: usize,
    budget_bytes: usize,
) -> Result<usize, AdjointError> {
    let bytes = |k: usize| tape_snapshots(steps, k) * snapshot_bytes + records_bytes;
    if let Some(k) = (1..=steps.max(1)).rev().find(|&k| bytes(k) <= budget_bytes) {
        return Ok(k);
    }
    let k = (1..=steps.max(1))
        .min_by_key(|&k| (tape_snapshots(steps, k), usize::MAX - k))
        .unwrap_or(1);
    let need = bytes(k);
    Err(AdjointError::OverBudget {
        steps,
        every: k,
        need,
        budget: budget_bytes,
    })
}

/// How the backward pass chooses its checkpoint interval.
#[derive(Clone, Copy, Debug)]
pub enum Tape {
    /// The smallest tape, refused if over this many bytes.
    Budget(usize),
    /// A fixed interval: `Every(T)` keeps every step (a full tape), `Every(1)` checkpoints
    /// every step.
    Every(usize),
}
