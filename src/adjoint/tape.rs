//! The backward pass: checkpoints, recomputation and the reverse sweep.
//!
//! The forward pass stores the particle state every `k` global steps (a checkpoint). The
//! backward pass walks the segments between checkpoints from last to first: it restores the
//! segment's checkpoint, recomputes the segment's step-start states, and for each step in
//! reverse recomputes its substeps once, keeping a `SubstepRecord` of each (the substep-start
//! state, the SVD factors, the material's saved update, the P2G affine term and scatter order,
//! the grid and the contact inputs), then reverses the substeps from their records, running the
//! adjoint stages in reverse order.
//!
//! Memory: `O(T/k·N + k·N)` particle states of `(x, v, C, F, V_svd)` plus `N_sub` substep
//! records; `k` comes from a memory budget ([`checkpoint_interval`]). The SVD's warm-start `V` is part of the stored
//! state, so a recomputed substep is bitwise the original one and the gradient does not depend
//! on `k` or on the thread count.

use crate::adjoint::gravity::GravityAdj;
use crate::adjoint::grid_collision::ColliderAdj;
pub use crate::adjoint::loss::Loss;
use crate::adjoint::particle_collision::ParticleCollisionInput;
use crate::adjoint::tool_move::ControlAdj;
use crate::adjoint::{add_adjoint_stage, NonFiniteSeen, SubstepAdjoint};
use crate::components::*;
use crate::error::AdjointError;
use crate::math::sdf::Shape;
use crate::sim::{run_in, Simulation};
use crate::systems::{self, new_schedule, Stage};
use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3};
use std::time::Instant;

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

/// Everything the adjoint stages of one substep read that its forward stages computed: the
/// substep-start state, the SVD factors, the P2G affine term and scatter order, the grid and the
/// inputs of the contact responses, the collider poses and the clock. The backward pass records
/// the substeps of one step while it recomputes them, then reverses them from these records, so
/// each substep's forward runs twice in all (taped pass and recomputation), not three times.
///
/// Recording swaps buffers with the world instead of copying them (the forward stages overwrite
/// every swapped-out scratch buffer before reading it); only the SVD's `V`, which the next
/// substep's SVD warm-starts from, is copied.
struct SubstepRecord {
    clock: Clock,
    colliders: Vec<ColliderPose>,
    bodies: Vec<BodyRecord>,
    grid_mass: Vec<f64>,
    grid_momentum: Vec<DVec3>,
    grid_velocity: Vec<DVec3>,
    collider_input: Vec<DVec3>,
    wall_input: Vec<DVec3>,
}

struct BodyRecord {
    start: SubstepStart,
    /// The velocity advect used (after particle collision).
    v_end: Vec<DVec3>,
    collision_input: Vec<DVec3>,
    trial: Vec<DMat3>,
    svd: SvdFactors,
    /// What the material update saved for its adjoint.
    saved: Vec<crate::materials::Saved>,
    affine: Vec<DMat3>,
    order: ScatterOrder,
}

type RecordQuery<'a> = (
    &'a mut Position,
    &'a mut Velocity,
    &'a mut SubstepStart,
    &'a mut ParticleCollisionInput,
    &'a mut TrialDeformation,
    &'a mut SvdFactors,
    &'a mut UpdateSaved,
    &'a mut P2gAffine,
    &'a mut ScatterOrder,
);

impl SubstepRecord {
    /// A record with buffers of the world's sizes.
    fn like(world: &mut World, bodies: &[Entity]) -> SubstepRecord {
        let grid = world.resource::<Grid>();
        let (grid_mass, grid_momentum, grid_velocity) = (
            grid.mass.clone(),
            grid.momentum.clone(),
            grid.velocity.clone(),
        );
        let bodies = bodies
            .iter()
            .map(|&e| {
                let n = world.get::<Position>(e).map_or(0, |x| x.0.len());
                BodyRecord {
                    start: SubstepStart::zeroed(n),
                    v_end: Vec::new(),
                    collision_input: Vec::new(),
                    trial: vec![DMat3::ZERO; n],
                    svd: SvdFactors {
                        u: vec![DMat3::ZERO; n],
                        s: vec![DVec3::ZERO; n],
                        v: vec![DMat3::ZERO; n],
                    },
                    saved: vec![[DVec3::ZERO; 3]; n],
                    affine: vec![DMat3::ZERO; n],
                    order: ScatterOrder::default(),
                }
            })
            .collect();
        SubstepRecord {
            clock: Clock::default(),
            colliders: Vec::new(),
            bodies,
            collider_input: grid_velocity.clone(),
            wall_input: grid_velocity.clone(),
            grid_mass,
            grid_momentum,
            grid_velocity,
        }
    }

    /// Exchanges the recorded buffers with the world's. `save`: the world's current values go
    /// into the record (the SVD's `V` is copied, so the world keeps it for the next warm
    /// start); otherwise the record's values go back into the world.
    fn exchange(
        &mut self,
        world: &mut World,
        bodies: &[Entity],
        q: &mut QueryState<RecordQuery>,
        save: bool,
    ) {
        for (&e, b) in bodies.iter().zip(&mut self.bodies) {
            let (
                mut x,
                mut v,
                mut start,
                mut pc,
                mut trial,
                mut svd,
                mut saved,
                mut affine,
                mut order,
            ) = q.get_mut(world, e).expect("a body entity");
            if save {
                b.v_end.clone_from(&v.0);
            } else {
                // The world as advect saw it: substep-start positions, final velocities.
                std::mem::swap(&mut v.0, &mut b.v_end);
                x.0.clone_from(&b.start.x);
            }
            std::mem::swap(&mut *start, &mut b.start);
            std::mem::swap(&mut pc.0, &mut b.collision_input);
            std::mem::swap(&mut trial.0, &mut b.trial);
            std::mem::swap(&mut svd.u, &mut b.svd.u);
            std::mem::swap(&mut svd.s, &mut b.svd.s);
            if save {
                b.svd.v.clone_from(&svd.v);
            } else {
                std::mem::swap(&mut svd.v, &mut b.svd.v);
            }
            std::mem::swap(&mut saved.0, &mut b.saved);
            std::mem::swap(&mut affine.0, &mut b.affine);
            std::mem::swap(&mut *order, &mut b.order);
        }
        {
            let mut grid = world.resource_mut::<Grid>();
            std::mem::swap(&mut grid.mass, &mut self.grid_mass);
            std::mem::swap(&mut grid.momentum, &mut self.grid_momentum);
            std::mem::swap(&mut grid.velocity, &mut self.grid_velocity);
        }
        std::mem::swap(
            &mut world.resource_mut::<ColliderInputVelocity>().0,
            &mut self.collider_input,
        );
        std::mem::swap(
            &mut world.resource_mut::<WallInputVelocity>().0,
            &mut self.wall_input,
        );
        if save {
            self.colliders = collider_states(world);
        } else {
            let mut cq = world.query::<(&Collider, &mut ColliderPose)>();
            for (c, mut p) in cq.iter_mut(world) {
                *p = self.colliders[c.index];
            }
            *world.resource_mut::<Clock>() = self.clock;
        }
    }

    /// Bytes held by one record of a world.
    fn bytes(particles: usize, nodes: usize) -> usize {
        // start (x, v, C, F), final v, collision input, trial F, U, σ, V, the material's saved
        // update, affine, order; grid m, p, v and the two contact inputs.
        particles * (2 * 24 + 2 * 72 + 24 + 24 + 72 + 72 + 24 + 72 + 72 + 72 + 4)
            + nodes * (8 + 4 * 24)
    }
}

/// Collider poses in scene order.
fn collider_states(world: &mut World) -> Vec<ColliderPose> {
    let mut cq = world.query::<(&Collider, &ColliderPose)>();
    let mut cs: Vec<(usize, ColliderPose)> = cq.iter(world).map(|(c, p)| (c.index, *p)).collect();
    cs.sort_by_key(|e| e.0);
    cs.into_iter().map(|e| e.1).collect()
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
    /// Wall seconds per part of the pass: the taped forward, the recomputations, each stage's
    /// forward re-run and adjoint, in first-run order.
    pub timing: Vec<(String, f64)>,
}

/// Accumulated wall time per named part.
#[derive(Default)]
struct Timing(Vec<(String, f64)>);

impl Timing {
    fn add(&mut self, name: &str, secs: f64) {
        match self.0.iter_mut().find(|e| e.0 == name) {
            Some(e) => e.1 += secs,
            None => self.0.push((name.to_string(), secs)),
        }
    }
    fn add_stage(&mut self, prefix: &str, stage: Stage, secs: f64) {
        match self
            .0
            .iter_mut()
            .find(|e| e.0.starts_with(prefix) && &e.0[prefix.len()..] == stage.name())
        {
            Some(e) => e.1 += secs,
            None => self.0.push((format!("{prefix}{}", stage.name()), secs)),
        }
    }
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

/// The adjoint fields a stage writes: checking only those after each stage finds the stage that
/// produced a non-finite value at a third of the cost of scanning every field every time. The
/// stages that write particle fields test them as they write them and raise
/// [`NonFiniteSeen`]; the particle fields are scanned (to name the particle) only then, the grid
/// field after every stage that writes it.
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
    world: &World,
    q: &mut QueryState<AdjQuery>,
    step: usize,
    substep: usize,
    stage: Stage,
    flagged: bool,
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
    for (b, gx, gv, gc, gf, gft, gsvd, ga) in q.iter(world).filter(|_| flagged) {
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
    if flagged {
        // A stage raised the flag for a field it is not listed as writing: a bug of this crate,
        // reported as loudly as the value itself.
        return Err(fault(
            "a particle field the stage does not list",
            "unknown".into(),
            0,
            "non-finite".into(),
        ));
    }
    Ok(())
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
    sim.on_worker(|sim| gradient_in_pool(sim, steps, loss, tape))
}

fn gradient_in_pool(
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
    let nodes = sim.world.resource::<Grid>().mass.len();
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
    for s in 0..steps {
        if s % k == 0 {
            checkpoints.push(snapshot(&mut sim.world));
        }
        if s >= last_segment {
            last_starts.push(snapshot(&mut sim.world));
        }
        sim.step()?;
    }
    let final_state = snapshot(&mut sim.world);
    timing.add("forward (taped)", t_pass.elapsed().as_secs_f64());
    let final_x: Vec<Vec<DVec3>> = final_state.bodies.iter().map(|b| b.x.clone()).collect();
    let (loss_value, g_x) = loss.eval(&final_x);

    // Adjoint state.
    let plan = sim.plan.clone();
    let len = sim.world.resource::<Grid>().mass.len();
    sim.world.insert_resource(GridAdj::new(len));
    sim.world.insert_resource(GravityAdj::default());
    sim.world.insert_resource(NonFiniteSeen::default());
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
            SubstepStart::zeroed(n),
            ParticleCollisionInput::default(),
            MaterialAdj::default(),
            // From here on the constitutive stage saves its update for the adjoint.
            UpdateSaved(vec![[DVec3::ZERO; 3]; n]),
        ));
    }
    // The forward and the adjoint stages, one schedule each, so the driver can take the
    // substep-start state between forward stages and check finiteness between adjoint stages.
    // (The contact stages save their inputs themselves into the two input resources inserted
    // above.)
    let mut forward: Vec<(Stage, Schedule)> = Stage::ALL
        .iter()
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
    // Whether the recomputation takes the substep-start F (and v, C) by swapping buffers before
    // the stage that overwrites them, or must copy them because the plan lacks that stage.
    let runs = |st: Stage| forward.iter().any(|(s, _)| *s == st);
    let (swap_f, swap_vc) = (runs(Stage::Constitutive), runs(Stage::G2p));

    let mut body_ents: Vec<(usize, Entity)> = ents.iter().map(|&(e, bi, _)| (bi, e)).collect();
    body_ents.sort_by_key(|e| e.0);
    let body_ents: Vec<Entity> = body_ents.into_iter().map(|e| e.1).collect();
    let mut record_query = sim.world.query::<RecordQuery>();
    let mut start_query = sim.world.query::<(
        &Position,
        &mut Velocity,
        &mut AffineVelocity,
        &mut DeformationGradient,
        &mut SubstepStart,
        &mut ParticleCollisionInput,
    )>();
    let mut records: Vec<SubstepRecord> = (0..substeps)
        .map(|_| SubstepRecord::like(&mut sim.world, &body_ents))
        .collect();
    let mut adj_query = sim.world.query::<AdjQuery>();
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
            let step = s0 + si;
            // Recompute the step's substeps, recording each one.
            restore(&mut sim.world, ss);
            sim.world.resource_mut::<Clock>().substep = 0;
            for record in records.iter_mut() {
                let clock = *sim.world.resource::<Clock>();
                // The substep-start state: `x` is copied (advect updates it in place); `F`, `v`
                // and `C` are taken by swapping buffers just before the stage that overwrites
                // them without reading them (constitutive, G2P), so they are not copied, unless
                // the plan lacks that stage.
                let t = Instant::now();
                for (x, v, c, f, mut st, _) in start_query.iter_mut(&mut sim.world) {
                    st.x.clone_from(&x.0);
                    if !swap_f {
                        st.f.clone_from(&f.0);
                    }
                    if !swap_vc {
                        st.v.clone_from(&v.0);
                        st.c.clone_from(&c.0);
                    }
                }
                timing.add("recompute: substep starts", t.elapsed().as_secs_f64());
                for (stage, s) in forward.iter_mut() {
                    let t = Instant::now();
                    match stage {
                        Stage::Constitutive => {
                            // Writes every particle's F without reading it.
                            for (_, _, _, mut f, mut st, _) in start_query.iter_mut(&mut sim.world)
                            {
                                std::mem::swap(&mut f.0, &mut st.f);
                            }
                            let world = &mut sim.world;
                            run_in(&sim.pool, || s.run(world));
                        }
                        Stage::G2p => {
                            // Writes every particle's v and C without reading them.
                            for (_, mut v, mut c, _, mut st, _) in
                                start_query.iter_mut(&mut sim.world)
                            {
                                std::mem::swap(&mut v.0, &mut st.v);
                                std::mem::swap(&mut c.0, &mut st.c);
                            }
                            let world = &mut sim.world;
                            run_in(&sim.pool, || s.run(world));
                        }
                        Stage::ParticleCollision => {
                            for (_, v, _, _, _, mut input) in start_query.iter_mut(&mut sim.world) {
                                input.0.clone_from(&v.0);
                            }
                            let world = &mut sim.world;
                            run_in(&sim.pool, || s.run(world));
                        }
                        _ => {
                            let world = &mut sim.world;
                            run_in(&sim.pool, || s.run(world));
                        }
                    }
                    timing.add_stage("recompute: ", *stage, t.elapsed().as_secs_f64());
                }
                sim.finish_substep()?;
                let t = Instant::now();
                record.exchange(&mut sim.world, &body_ents, &mut record_query, true);
                record.clock = clock;
                timing.add("record substep", t.elapsed().as_secs_f64());
            }
            // Reverse them.
            for (j, record) in records.iter_mut().enumerate().rev() {
                let t = Instant::now();
                record.exchange(&mut sim.world, &body_ents, &mut record_query, false);
                timing.add("record substep", t.elapsed().as_secs_f64());
                for (stage, s) in adjoint.iter_mut() {
                    let t = Instant::now();
                    let world = &mut sim.world;
                    run_in(&sim.pool, || s.run(world));
                    let t1 = Instant::now();
                    let flagged = sim.world.resource::<NonFiniteSeen>().take();
                    check_finite(&sim.world, &mut adj_query, step, j, *stage, flagged)?;
                    timing.add_stage("adjoint: ", *stage, (t1 - t).as_secs_f64());
                    timing.add("adjoint: finiteness checks", t1.elapsed().as_secs_f64());
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
            UpdateSaved,
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
        gravity,
        friction: friction.into_iter().map(|e| (e.1, e.2)).collect(),
        tool_start: tools.iter().map(|e| (e.1.clone(), e.2)).collect(),
        tool_start_rotation: tools.iter().map(|e| (e.1.clone(), e.4)).collect(),
        skills: skill_gradients(&sim.scene, &tools),
        controls: tools.into_iter().map(|e| (e.1, e.3)).collect(),
        checkpoint_every: k,
        tape_bytes: peak_snaps * snap_bytes + records_bytes,
        timing: timing.0,
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
            let bottom = crate::scene::Scene::tool_bottom(c);
            Some((
                name.clone(),
                sk.controls_adj(scene.simulation.dt, bottom, g_u),
            ))
        })
        .collect()
}
