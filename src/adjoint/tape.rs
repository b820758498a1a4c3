//! The backward pass: checkpoints, recomputation and the reverse sweep.
//!
//! The forward pass stores the particle state every `k` global steps (a checkpoint). The
//! backward pass walks the segments between checkpoints from last to first: it restores the
//! segment's checkpoint, recomputes the segment's step-start states, and for each step in
//! reverse recomputes its substep-start states, then reverses each substep: restore its start
//! state, re-run the forward stages up to G2P (which refills the SVD factors, the P2G affine
//! term and the grid), and run the adjoint stages in reverse order.
//!
//! Memory: `O(T/k·N + k·N + N_sub·N)` particle states of `(x, v, C, F, V_svd)`; `k` comes from
//! a memory budget ([`checkpoint_interval`]). The SVD's warm-start `V` is part of the stored
//! state, so a recomputed substep is bitwise the original one and the gradient does not depend
//! on `k` or on the thread count.

use crate::adjoint::gravity::GravityAdj;
use crate::adjoint::grid_collision::{ColliderAdj, ColliderInputVelocity, WallInputVelocity};
use crate::adjoint::particle_collision::ParticleCollisionInput;
use crate::adjoint::tool_move::ControlAdj;
use crate::adjoint::{add_adjoint_stage, SubstepAdjoint};
use crate::components::*;
use crate::error::AdjointError;
use crate::math::sdf::Shape;
use crate::sim::Simulation;
use crate::systems::{self, new_schedule, Stage};
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
    let mut cq = world.query::<(&Collider, &ColliderPose)>();
    let mut cs: Vec<(usize, ColliderPose)> = cq.iter(world).map(|(c, p)| (c.index, *p)).collect();
    cs.sort_by_key(|e| e.0);
    Snapshot {
        colliders: cs.into_iter().map(|e| e.1).collect(),
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

/// A loss on the final particle positions.
#[derive(Clone, Debug)]
pub enum Loss {
    /// `mean_p Σ_d |x_p,d − t_d|`, the Taichi reference benchmark's loss.
    MeanL1(DVec3),
    /// `Σ_p ‖x_p − t‖` (seed paper eq. 5).
    SumDistance(DVec3),
    /// `Σ_bodies Σ_p w_p·x_p` with given weights (closed-form checks).
    Linear(Vec<Vec<DVec3>>),
}

impl Loss {
    /// The loss and `∂L/∂x` per body. `|·|` and `‖·‖` use the subgradient 0 at 0.
    pub fn eval(&self, xs: &[Vec<DVec3>]) -> (f64, Vec<Vec<DVec3>>) {
        let n: usize = xs.iter().map(|x| x.len()).sum();
        let mut l = 0.0;
        let g = xs
            .iter()
            .enumerate()
            .map(|(b, x)| {
                x.iter()
                    .enumerate()
                    .map(|(i, p)| match self {
                        Loss::MeanL1(t) => {
                            let d = *p - *t;
                            l += (d.x.abs() + d.y.abs() + d.z.abs()) / n as f64;
                            let s = |v: f64| {
                                if v > 0.0 {
                                    1.0
                                } else if v < 0.0 {
                                    -1.0
                                } else {
                                    0.0
                                }
                            };
                            DVec3::new(s(d.x), s(d.y), s(d.z)) / n as f64
                        }
                        Loss::SumDistance(t) => {
                            let d = *p - *t;
                            let len = d.length();
                            l += len;
                            if len > 0.0 {
                                d / len
                            } else {
                                DVec3::ZERO
                            }
                        }
                        Loss::Linear(w) => {
                            l += w[b][i].dot(*p);
                            w[b][i]
                        }
                    })
                    .collect()
            })
            .collect();
        (l, g)
    }
}

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
    /// Material-parameter gradients per body.
    pub material: Vec<MaterialAdj>,
    /// `∂L/∂g`.
    pub gravity: DVec3,
    /// `∂L/∂μ` per collider (name, gradient), in scene order.
    pub friction: Vec<(String, f64)>,
    /// `∂L/∂t(0)`: the gradient with respect to each tool's start position.
    pub tool_start: Vec<(String, DVec3)>,
    /// `∂L/∂θ(0)`: with respect to each tool's start orientation (world-frame rotation vector).
    pub tool_start_rotation: Vec<(String, DVec3)>,
    /// `∂L/∂Θ` of each tool driven by a skill (straight-through rounding of the step counts).
    pub skills: Vec<(String, [f64; 5])>,
    /// `∂L/∂u` per global step of each tool's control sequence (translation, rotation vector).
    pub controls: Vec<(String, Vec<[f64; 6]>)>,
    /// Checkpoint interval used, in global steps.
    pub checkpoint_every: usize,
    /// Bytes of particle state held at the peak (checkpoints + one segment + one step).
    pub tape_bytes: usize,
}

/// Snapshots the tape holds at its peak with checkpoint interval `k`: `⌈T/k⌉` checkpoints, the
/// `k` step-start states of one segment and the `N_sub` substep-start states of one step.
pub fn tape_snapshots(steps: usize, substeps: usize, k: usize) -> usize {
    steps.div_ceil(k) + k + substeps
}

/// The checkpoint interval for a memory budget: the largest `k` whose tape fits (the first
/// forward pass keeps the last segment's step states, so the recomputation is the forward pass
/// minus the last segment); an error if even the smallest tape (`k ≈ √T`) does not fit.
pub fn checkpoint_interval(
    steps: usize,
    substeps: usize,
    snapshot_bytes: usize,
    budget_bytes: usize,
) -> Result<usize, AdjointError> {
    // The last segment's step states are kept from the first forward pass, so a longer
    // segment saves recomputation: take the largest k that fits, else the smallest tape.
    let fits = |k: usize| tape_snapshots(steps, substeps, k) * snapshot_bytes <= budget_bytes;
    if let Some(k) = (1..=steps.max(1)).rev().find(|&k| fits(k)) {
        return Ok(k);
    }
    let k = (1..=steps.max(1))
        .min_by_key(|&k| (tape_snapshots(steps, substeps, k), usize::MAX - k))
        .unwrap_or(1);
    let need = tape_snapshots(steps, substeps, k) * snapshot_bytes;
    Err(AdjointError::NotDifferentiable(format!(
        "the smallest tape for {steps} steps (checkpoint every {k} steps) needs {need} bytes, over the memory budget of {budget_bytes} bytes: raise the budget or shorten the horizon"
    )))
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

/// The adjoint fields a stage writes: checking only those after each stage finds the stage that
/// produced a non-finite value at a third of the cost of scanning every field every time.
fn written_by(stage: Stage) -> &'static [&'static str] {
    match stage {
        Stage::Advect => &["x adjoint", "v adjoint"],
        Stage::G2p => &["x adjoint", "grid velocity adjoint"],
        Stage::GridCollision => &["grid velocity adjoint"],
        Stage::P2g => &["x adjoint", "v adjoint", "affine adjoint"],
        Stage::Constitutive => &["C adjoint", "sigma adjoint", "F_tmp adjoint"],
        Stage::Svd => &["F_tmp adjoint"],
        Stage::DeformationUpdate => &["C adjoint", "F adjoint"],
        Stage::GridReset | Stage::Gravity | Stage::ToolMove | Stage::ParticleCollision => &[],
    }
}

type AdjQuery<'a> = (
    &'a Body,
    &'a PositionAdj,
    &'a VelocityAdj,
    &'a AffineVelocityAdj,
    &'a DeformationGradientAdj,
    &'a TrialDeformationAdj,
    &'a SvdFactorsAdj,
    &'a P2gAffineAdj,
);

fn check_finite(
    world: &mut World,
    step: usize,
    substep: usize,
    stage: Stage,
) -> Result<(), AdjointError> {
    let fields = written_by(stage);
    if fields.is_empty() {
        return Ok(());
    }
    let fault =
        |field: &'static str, owner: String, index: usize, value: String| AdjointError::NonFinite {
            step,
            substep,
            stage: stage.name(),
            field,
            owner,
            index,
            value,
        };
    let mut q = world.query::<AdjQuery>();
    for (b, gx, gv, gc, gf, gft, gsvd, ga) in q.iter(world) {
        for &field in fields {
            let hit = match field {
                "x adjoint" => {
                    systems::first_nonfinite_vec(&gx.0).map(|i| (i, format!("{:?}", gx.0[i])))
                }
                "v adjoint" => {
                    systems::first_nonfinite_vec(&gv.0).map(|i| (i, format!("{:?}", gv.0[i])))
                }
                "C adjoint" => {
                    systems::first_nonfinite_mat(&gc.0).map(|i| (i, format!("{:?}", gc.0[i])))
                }
                "F adjoint" => {
                    systems::first_nonfinite_mat(&gf.0).map(|i| (i, format!("{:?}", gf.0[i])))
                }
                "F_tmp adjoint" => {
                    systems::first_nonfinite_mat(&gft.0).map(|i| (i, format!("{:?}", gft.0[i])))
                }
                "sigma adjoint" => {
                    systems::first_nonfinite_vec(&gsvd.s).map(|i| (i, format!("{:?}", gsvd.s[i])))
                }
                "affine adjoint" => {
                    systems::first_nonfinite_mat(&ga.0).map(|i| (i, format!("{:?}", ga.0[i])))
                }
                _ => None,
            };
            if let Some((i, value)) = hit {
                return Err(fault(
                    field,
                    format!("body '{}' particle", b.name),
                    i,
                    value,
                ));
            }
        }
    }
    if fields.contains(&"grid velocity adjoint") {
        if let Some(i) = systems::first_nonfinite_vec(&world.resource::<GridAdj>().velocity) {
            let value = format!("{:?}", world.resource::<GridAdj>().velocity[i]);
            return Err(fault("grid velocity adjoint", "grid node".into(), i, value));
        }
    }
    Ok(())
}

/// Runs `steps` global steps from the simulation's current state and returns the gradients of
/// `loss` on the final positions. The simulation is left at the final state.
pub fn gradient(
    sim: &mut Simulation,
    steps: usize,
    loss: &Loss,
    tape: Tape,
) -> Result<Gradients, AdjointError> {
    for c in &sim.scene.colliders {
        if c.kind != crate::scene::ColliderKindSpec::Tool {
            continue;
        }
        if c.shape.sdf_hessian(DVec3::ZERO).is_none() {
            return Err(AdjointError::NotDifferentiable(format!(
                "tool '{}': the contact adjoint of a moving {} needs its SDF Hessian, not implemented yet (box, sphere, capsule and plane tools are differentiable)",
                c.name,
                shape_name(&c.shape)
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
            shape_name(&c.shape)
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
    let k = match tape {
        Tape::Budget(b) => checkpoint_interval(steps, substeps, start.bytes(), b)?,
        Tape::Every(k) => k.clamp(1, steps.max(1)),
    };
    // Forward, keeping a checkpoint every k steps.
    let mut checkpoints = Vec::with_capacity(steps.div_ceil(k));
    let last_segment = (steps - 1) / k * k;
    let mut last_starts = Vec::new();
    for s in 0..steps {
        if s % k == 0 {
            checkpoints.push(snapshot(&mut sim.world));
        }
        if s >= last_segment {
            last_starts.push(snapshot(&mut sim.world));
        }
        sim.step()?;
    }
    let final_x: Vec<Vec<DVec3>> = snapshot(&mut sim.world)
        .bodies
        .into_iter()
        .map(|b| b.x)
        .collect();
    let (loss_value, g_x) = loss.eval(&final_x);

    // Adjoint state.
    let plan = sim.plan.clone();
    let len = sim.world.resource::<Grid>().mass.len();
    sim.world.insert_resource(GridAdj::new(len));
    sim.world.insert_resource(GravityAdj::default());
    sim.world
        .insert_resource(WallInputVelocity(vec![DVec3::ZERO; len]));
    sim.world
        .insert_resource(ColliderInputVelocity(vec![DVec3::ZERO; len]));
    let collider_ents: Vec<Entity> = sim
        .world
        .query_filtered::<Entity, With<Collider>>()
        .iter(&sim.world)
        .collect();
    for &e in &collider_ents {
        sim.world.entity_mut(e).insert(ColliderAdj::default());
        let n = sim.world.get::<Control>(e).map(|c| c.per_step.len());
        if let Some(n) = n {
            sim.world
                .entity_mut(e)
                .insert(ControlAdj(vec![[0.0; 6]; n]));
        }
    }
    let ents: Vec<(Entity, usize, usize)> = sim
        .world
        .query::<(Entity, &Body, &Position)>()
        .iter(&sim.world)
        .map(|(e, b, x)| (e, b.index, x.0.len()))
        .collect();
    for &(e, bi, n) in &ents {
        sim.world.entity_mut(e).insert((
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
            SubstepStart::default(),
            ParticleCollisionInput::default(),
            MaterialAdj::default(),
        ));
    }
    // Forward stages up to G2P (no advect), and the adjoint stages, one schedule each so the
    // driver can save the wall input and check finiteness between them.
    let forward: Vec<(Stage, Schedule)> = Stage::ALL
        .iter()
        .filter(|s| **s != Stage::Advect)
        .filter_map(|&st| {
            let mut s = new_schedule();
            systems::add_stage(&mut s, st, &plan).then_some((st, s))
        })
        .collect();
    let mut adjoint: Vec<(Stage, Schedule)> = Stage::ALL
        .iter()
        .rev()
        .filter_map(|&st| {
            let mut s = Schedule::new(SubstepAdjoint);
            s.set_executor_kind(bevy_ecs::schedule::ExecutorKind::SingleThreaded);
            add_adjoint_stage(&mut s, st, &plan).then_some((st, s))
        })
        .collect();
    let mut forward = forward;
    let mut collider_only = new_schedule();
    collider_only.add_systems(systems::grid_collision::collider_contact);
    let mut walls_only = new_schedule();
    walls_only.add_systems(systems::grid_collision::domain_walls);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(sim.threads())
        .build()
        .map_err(|e| crate::error::SimError::Other(e.to_string()))?;

    let mut peak_snaps = checkpoints.len();
    for (ci, cp) in checkpoints.iter().enumerate().rev() {
        let s0 = ci * k;
        let s1 = (s0 + k).min(steps);
        // Step-start states of the segment (kept from the first pass for the last segment).
        let step_starts = if s0 == last_segment {
            std::mem::take(&mut last_starts)
        } else {
            restore(&mut sim.world, cp);
            let mut v = Vec::with_capacity(s1 - s0);
            for _ in s0..s1 {
                v.push(snapshot(&mut sim.world));
                sim.step()?;
            }
            v
        };
        for (si, ss) in step_starts.iter().enumerate().rev() {
            let step = s0 + si;
            // Substep-start states of the step.
            restore(&mut sim.world, ss);
            sim.world.resource_mut::<Clock>().substep = 0;
            let mut sub_starts = Vec::with_capacity(substeps);
            for _ in 0..substeps {
                sub_starts.push(snapshot(&mut sim.world));
                sim.substep()?;
            }
            peak_snaps = peak_snaps.max(checkpoints.len() + step_starts.len() + sub_starts.len());
            for (j, sub) in sub_starts.iter().enumerate().rev() {
                restore(&mut sim.world, sub);
                {
                    let mut q = sim.world.query::<(&Body, &mut SubstepStart)>();
                    for (b, mut st) in q.iter_mut(&mut sim.world) {
                        let sn = &sub.bodies[b.index];
                        st.x.clone_from(&sn.x);
                        st.v.clone_from(&sn.v);
                        st.c.clone_from(&sn.c);
                        st.f.clone_from(&sn.f);
                    }
                }
                for (stage, s) in forward.iter_mut() {
                    if *stage == Stage::ParticleCollision {
                        let mut q = sim
                            .world
                            .query::<(&Velocity, &mut ParticleCollisionInput)>();
                        for (v, mut input) in q.iter_mut(&mut sim.world) {
                            input.0.clone_from(&v.0);
                        }
                    }
                    if *stage == Stage::GridCollision {
                        // Save the inputs of the collider and wall responses for their adjoints.
                        let v = sim.world.resource::<Grid>().velocity.clone();
                        sim.world
                            .resource_mut::<ColliderInputVelocity>()
                            .0
                            .clone_from(&v);
                        if plan.has_colliders {
                            let world = &mut sim.world;
                            pool.install(|| collider_only.run(world));
                        }
                        let v = sim.world.resource::<Grid>().velocity.clone();
                        sim.world.resource_mut::<WallInputVelocity>().0 = v;
                        let world = &mut sim.world;
                        pool.install(|| walls_only.run(world));
                        continue;
                    }
                    let world = &mut sim.world;
                    pool.install(|| s.run(world));
                }
                for (stage, s) in adjoint.iter_mut() {
                    let world = &mut sim.world;
                    pool.install(|| s.run(world));
                    check_finite(&mut sim.world, step, j, *stage)?;
                }
            }
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
    for &(e, _, _) in &ents {
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
        )>();
    }
    sim.world.remove_resource::<GridAdj>();
    sim.world.remove_resource::<WallInputVelocity>();
    sim.world.remove_resource::<GravityAdj>();
    let last = checkpoints.last().expect("at least one step");
    restore(&mut sim.world, last);
    for _ in (checkpoints.len() - 1) * k..steps {
        sim.step()?;
    }
    Ok(Gradients {
        loss: loss_value,
        x0: per.iter().map(|e| e.1.clone()).collect(),
        v0: per.iter().map(|e| e.2.clone()).collect(),
        material: per.iter().map(|e| e.3).collect(),
        gravity,
        friction: friction.into_iter().map(|e| (e.1, e.2)).collect(),
        tool_start: tools.iter().map(|e| (e.1.clone(), e.2)).collect(),
        tool_start_rotation: tools.iter().map(|e| (e.1.clone(), e.4)).collect(),
        skills: skill_gradients(&sim.scene, &tools),
        controls: tools.into_iter().map(|e| (e.1, e.3)).collect(),
        checkpoint_every: k,
        tape_bytes: peak_snaps * snap_bytes,
    })
}

fn shape_name(s: &Shape) -> &'static str {
    match s {
        Shape::Plane { .. } => "plane",
        Shape::Box { .. } => "box",
        Shape::Sphere { .. } => "sphere",
        Shape::Capsule { .. } => "capsule",
        Shape::Cylinder { .. } => "cylinder",
        Shape::Cup { .. } => "cup",
        Shape::Spoon { .. } => "spoon",
    }
}

/// `∂L/∂Θ` for the tools whose controls come from a skill.
fn skill_gradients(scene: &crate::scene::Scene, tools: &[ToolGrad]) -> Vec<(String, [f64; 5])> {
    tools
        .iter()
        .filter_map(|(_, name, _, g_u, _)| {
            let c = scene.colliders.iter().find(|c| &c.name == name)?;
            let Some(crate::scene::ControlSpec::Skill(sk)) = &c.control else {
                return None;
            };
            let pose = crate::math::pose::Pose {
                translation: DVec3::from(c.position),
                rotation: crate::scene::Scene::collider_rotation(c),
            };
            let bottom = pose.to_world(crate::sim::lowest_local_point(&c.shape)).y;
            Some((
                name.clone(),
                sk.controls_adj(scene.simulation.dt, bottom, g_u),
            ))
        })
        .collect()
}
