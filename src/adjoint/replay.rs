//! Replaying one global step for the backward pass: its substeps recomputed forward from the
//! step's start, each recorded ([`SubstepRecord`]), then reversed through the adjoint stages
//! in reverse stage order, with the finiteness of what each adjoint stage wrote checked.
//!
//! Each substep's forward thus runs twice in all (the taped pass and this recomputation), not
//! three times.

use super::checkpoint::{collider_states, restore, Snapshot};
use super::particle_collision::ParticleCollisionInput;
use super::{add_adjoint_stage, NonFiniteSeen, SubstepAdjoint};
use crate::components::*;
use crate::error::AdjointError;
use crate::sim::{run_in, Simulation};
use crate::systems::{self, new_schedule, Stage, SubstepPlan};
use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3};
use rayon::prelude::*;
use std::time::Instant;

type StartQuery<'a> = (
    &'a Position,
    &'a mut Velocity,
    &'a mut AffineVelocity,
    &'a mut DeformationGradient,
    &'a mut SubstepStart,
    &'a mut ParticleCollisionInput,
);

/// The schedules, queries and substep records of the replay, made once per backward pass.
pub(crate) struct Replay {
    forward: Vec<(Stage, Schedule)>,
    adjoint: Vec<(Stage, Schedule)>,
    /// Whether the recomputation takes the substep-start F (and v, C) by swapping buffers
    /// before the stage that overwrites them, or must copy them because the plan lacks that
    /// stage.
    swap_f: bool,
    swap_vc: bool,
    /// Body entities in scene order.
    bodies: Vec<Entity>,
    record_query: QueryState<RecordQuery<'static>>,
    start_query: QueryState<StartQuery<'static>>,
    adj_query: QueryState<AdjQuery<'static>>,
    records: Vec<SubstepRecord>,
}

impl Replay {
    /// The forward and the adjoint stages of `plan`, one schedule each, so the replay can take
    /// the substep-start state between forward stages and check finiteness between adjoint
    /// stages; and `substeps` records sized for the world.
    pub(crate) fn new(
        world: &mut World,
        plan: &SubstepPlan,
        bodies: Vec<Entity>,
        substeps: usize,
    ) -> Replay {
        let forward: Vec<(Stage, Schedule)> = Stage::ALL
            .iter()
            .filter_map(|&st| {
                let mut s = new_schedule();
                systems::add_stage(&mut s, st, plan).then_some((st, s))
            })
            .collect();
        let adjoint: Vec<(Stage, Schedule)> = Stage::ALL
            .iter()
            .rev()
            .filter_map(|&st| {
                let mut s = Schedule::new(SubstepAdjoint);
                s.set_executor_kind(bevy_ecs::schedule::ExecutorKind::SingleThreaded);
                add_adjoint_stage(&mut s, st, plan).then_some((st, s))
            })
            .collect();
        let runs = |st: Stage| forward.iter().any(|(s, _)| *s == st);
        let (swap_f, swap_vc) = (runs(Stage::Constitutive), runs(Stage::G2p));
        let records = (0..substeps)
            .map(|_| SubstepRecord::like(world, &bodies))
            .collect();
        Replay {
            forward,
            adjoint,
            swap_f,
            swap_vc,
            bodies,
            record_query: world.query::<RecordQuery>(),
            start_query: world.query::<StartQuery>(),
            adj_query: world.query::<AdjQuery>(),
            records,
        }
    }

    /// Recomputes the substeps of the step that starts at `start`, recording each one.
    pub(crate) fn recompute_step(
        &mut self,
        sim: &mut Simulation,
        start: &Snapshot,
        timing: &mut Timing,
    ) -> Result<(), AdjointError> {
        restore(&mut sim.world, start);
        sim.world.resource_mut::<Clock>().substep = 0;
        for record in self.records.iter_mut() {
            let clock = *sim.world.resource::<Clock>();
            // The substep-start state: `x` is copied (advect updates it in place); `F`, `v`
            // and `C` are taken by swapping buffers just before the stage that overwrites
            // them without reading them (constitutive, G2P), so they are not copied, unless
            // the plan lacks that stage.
            let t = Instant::now();
            for (x, v, c, f, mut st, _) in self.start_query.iter_mut(&mut sim.world) {
                st.x.clone_from(&x.0);
                if !self.swap_f {
                    st.f.clone_from(&f.0);
                }
                if !self.swap_vc {
                    st.v.clone_from(&v.0);
                    st.c.clone_from(&c.0);
                }
            }
            timing.add("recompute: substep starts", t.elapsed().as_secs_f64());
            for (stage, s) in self.forward.iter_mut() {
                let t = Instant::now();
                match stage {
                    Stage::Constitutive => {
                        // Writes every particle's F without reading it.
                        for (_, _, _, mut f, mut st, _) in self.start_query.iter_mut(&mut sim.world)
                        {
                            std::mem::swap(&mut f.0, &mut st.f);
                        }
                    }
                    Stage::G2p => {
                        // Writes every particle's v and C without reading them.
                        for (_, mut v, mut c, _, mut st, _) in
                            self.start_query.iter_mut(&mut sim.world)
                        {
                            std::mem::swap(&mut v.0, &mut st.v);
                            std::mem::swap(&mut c.0, &mut st.c);
                        }
                    }
                    Stage::ParticleCollision => {
                        for (_, v, _, _, _, mut input) in self.start_query.iter_mut(&mut sim.world)
                        {
                            input.0.clone_from(&v.0);
                        }
                    }
                    _ => {}
                }
                let world = &mut sim.world;
                run_in(&sim.pool, || s.run(world));
                timing.add_stage("recompute: ", *stage, t.elapsed().as_secs_f64());
            }
            sim.finish_substep()?;
            let t = Instant::now();
            record.exchange(&mut sim.world, &self.bodies, &mut self.record_query, true);
            record.clock = clock;
            timing.add("record substep", t.elapsed().as_secs_f64());
        }
        Ok(())
    }

    /// Reverses the recorded substeps of global step `step` through the adjoint stages.
    pub(crate) fn reverse_step(
        &mut self,
        sim: &mut Simulation,
        step: usize,
        timing: &mut Timing,
    ) -> Result<(), AdjointError> {
        for (j, record) in self.records.iter_mut().enumerate().rev() {
            let t = Instant::now();
            // Restoring rebuilds the P2G affine term in parallel: on the simulation's workers.
            let (world, query, bodies) = (&mut sim.world, &mut self.record_query, &self.bodies);
            run_in(&sim.pool, || record.exchange(world, bodies, query, false));
            timing.add("record substep", t.elapsed().as_secs_f64());
            for (stage, s) in self.adjoint.iter_mut() {
                let t = Instant::now();
                let world = &mut sim.world;
                run_in(&sim.pool, || s.run(world));
                let t1 = Instant::now();
                let flagged = sim.world.resource::<NonFiniteSeen>().take();
                check_finite(&sim.world, &mut self.adj_query, step, j, *stage, flagged)?;
                timing.add_stage("adjoint: ", *stage, (t1 - t).as_secs_f64());
                timing.add("adjoint: finiteness checks", t1.elapsed().as_secs_f64());
            }
        }
        Ok(())
    }
}

/// Everything the adjoint stages of one substep read that its forward stages computed: the
/// substep-start state, the SVD factors, the P2G affine term and scatter order, the grid and the
/// inputs of the contact responses, the collider poses and the clock. The backward pass records
/// the substeps of one step while it recomputes them, then reverses them from these records, so
/// each substep's forward runs twice in all (taped pass and recomputation), not three times.
///
/// Recording swaps particle buffers with the world instead of copying them (the forward stages
/// overwrite every swapped-out scratch buffer before reading it); only the SVD's `V`, which the
/// next substep's SVD warm-starts from, is copied. The grid is copied, packed to its active
/// spans ([`PackedGrid`]): a tenth of the dense arrays' bytes on `sand_box`.
pub(crate) struct SubstepRecord {
    clock: Clock,
    colliders: Vec<ColliderPose>,
    bodies: Vec<BodyRecord>,
    grid: PackedGrid,
}

/// The grid of a substep's end as its adjoint reads it: the node values inside the active
/// spans (`Grid::active`; every node of a dense grid), packed in span order. Outside the spans
/// every node is zero and no contact input is read (the contact adjoints act on non-empty
/// nodes only), so the spans hold the whole grid: on `sand_box` about a tenth of the nodes.
#[derive(Default)]
struct PackedGrid {
    /// The grid's active spans (`None`: a dense grid, packed whole).
    spans: Option<Vec<[u32; 2]>>,
    nodes: Vec<Node>,
    velocity: Vec<DVec3>,
    collider_input: Vec<DVec3>,
    wall_input: Vec<DVec3>,
}

/// Makes room for `n` values in a packed buffer: twice that when it must grow, so that a
/// spreading powder reallocates a record's buffers a few times in a run, not every substep.
fn make_room<T>(v: &mut Vec<T>, n: usize) {
    v.clear();
    if v.capacity() < n {
        v.reserve(2 * n);
    }
}

impl PackedGrid {
    /// Copies the world's grid and contact inputs at the active spans.
    fn pack(&mut self, world: &World) {
        let grid = world.resource::<Grid>();
        let (ci, wi) = (
            &world.resource::<ColliderInputVelocity>().0,
            &world.resource::<WallInputVelocity>().0,
        );
        match (&grid.active, &mut self.spans) {
            (Some(a), Some(s)) => s.clone_from(&a.span),
            (Some(a), None) => self.spans = Some(a.span.clone()),
            (None, _) => self.spans = None,
        }
        let nodes = grid.node_count();
        let mut count = 0;
        for_span_ranges(self.spans.as_deref(), nodes, grid.n[2], |r| {
            count += r.len()
        });
        make_room(&mut self.nodes, count);
        make_room(&mut self.velocity, count);
        make_room(&mut self.collider_input, count);
        make_room(&mut self.wall_input, count);
        for_span_ranges(self.spans.as_deref(), nodes, grid.n[2], |r| {
            self.nodes.extend_from_slice(&grid.nodes[r.clone()]);
            self.velocity.extend_from_slice(&grid.velocity[r.clone()]);
            // The contact inputs are world-sized where the scene has the stage, else empty.
            if let Some(c) = ci.get(r.clone()) {
                self.collider_input.extend_from_slice(c);
            }
            if let Some(w) = wi.get(r) {
                self.wall_input.extend_from_slice(w);
            }
        });
    }

    /// Puts the packed grid back into the world: the world's active nodes are zeroed, the
    /// packed ones written, and the world's spans become the packed ones.
    fn unpack(&self, world: &mut World) {
        let mut grid = world.resource_mut::<Grid>();
        let g = &mut *grid;
        let (n, nodes) = (g.n, g.node_count());
        let old = g.active.as_ref().map(|a| a.span.as_slice());
        for_span_ranges(old, nodes, n[2], |r| {
            g.nodes[r.clone()].fill(Node::ZERO);
            g.velocity[r].fill(DVec3::ZERO);
        });
        let mut at = 0;
        for_span_ranges(self.spans.as_deref(), nodes, n[2], |r| {
            let k = r.len();
            g.nodes[r.clone()].copy_from_slice(&self.nodes[at..at + k]);
            g.velocity[r].copy_from_slice(&self.velocity[at..at + k]);
            at += k;
        });
        match (&self.spans, &mut g.active) {
            (Some(s), Some(a)) => a.span.clone_from(s),
            (Some(s), active @ None) => {
                let mut a = ActiveRows::empty(n);
                a.span.clone_from(s);
                *active = Some(a);
            }
            (None, active) => *active = None,
        }
        let spans = self.spans.as_deref();
        let put = |input: &mut Vec<DVec3>, packed: &[DVec3]| {
            if packed.is_empty() {
                return;
            }
            let mut at = 0;
            for_span_ranges(spans, nodes, n[2], |r| {
                let k = r.len();
                input[r].copy_from_slice(&packed[at..at + k]);
                at += k;
            });
        };
        put(
            &mut world.resource_mut::<ColliderInputVelocity>().0,
            &self.collider_input,
        );
        put(
            &mut world.resource_mut::<WallInputVelocity>().0,
            &self.wall_input,
        );
    }
}

struct BodyRecord {
    start: SubstepStart,
    /// The velocity advect used (after particle collision).
    v_end: Vec<DVec3>,
    collision_input: Vec<DVec3>,
    svd: SvdFactors,
    /// What the material update saved for its adjoint.
    saved: Vec<crate::materials::Saved>,
    /// The principal stress `τ_p`, from which the P2G affine term is rebuilt (24 bytes a
    /// particle instead of 72).
    stress: Vec<DVec3>,
    order: ScatterOrder,
}

type RecordQuery<'a> = (
    &'a mut Position,
    &'a mut Velocity,
    &'a mut SubstepStart,
    &'a mut ParticleCollisionInput,
    &'a mut SvdFactors,
    &'a mut UpdateSaved,
    (&'a mut P2gAffine, &'a mut PrincipalStress, &'a Body),
    &'a mut ScatterOrder,
);

impl SubstepRecord {
    /// A record with buffers of the world's sizes.
    fn like(world: &mut World, bodies: &[Entity]) -> SubstepRecord {
        let bodies = bodies
            .iter()
            .map(|&e| {
                let n = world.get::<Position>(e).map_or(0, |x| x.0.len());
                BodyRecord {
                    start: SubstepStart::zeroed(n),
                    v_end: Vec::new(),
                    collision_input: Vec::new(),
                    svd: SvdFactors {
                        u: vec![DMat3::ZERO; n],
                        s: vec![DVec3::ZERO; n],
                        v: vec![DMat3::ZERO; n],
                    },
                    saved: vec![[DVec3::ZERO; 3]; n],
                    stress: vec![DVec3::ZERO; n],
                    order: ScatterOrder::default(),
                }
            })
            .collect();
        SubstepRecord {
            clock: Clock::default(),
            colliders: Vec::new(),
            bodies,
            grid: PackedGrid::default(),
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
        let (dt, dx) = (
            world.resource::<SimParams>().dt_sub,
            world.resource::<Grid>().dx,
        );
        for (&e, b) in bodies.iter().zip(&mut self.bodies) {
            let (mut x, mut v, mut start, mut pc, mut svd, mut saved, stress, mut order) =
                q.get_mut(world, e).expect("a body entity");
            let (mut affine, mut tau, body) = stress;
            if save {
                b.v_end.clone_from(&v.0);
            } else {
                // The world as advect saw it: substep-start positions, final velocities.
                std::mem::swap(&mut v.0, &mut b.v_end);
                x.0.clone_from(&b.start.x);
            }
            std::mem::swap(&mut *start, &mut b.start);
            std::mem::swap(&mut pc.0, &mut b.collision_input);
            std::mem::swap(&mut svd.u, &mut b.svd.u);
            std::mem::swap(&mut svd.s, &mut b.svd.s);
            if save {
                b.svd.v.clone_from(&svd.v);
            } else {
                std::mem::swap(&mut svd.v, &mut b.svd.v);
            }
            std::mem::swap(&mut saved.0, &mut b.saved);
            std::mem::swap(&mut tau.0, &mut b.stress);
            if !save {
                // The P2G affine term as the constitutive stage computed it, to the bit.
                let coef = crate::systems::constitutive::stress_coef(dt, body.particle_volume, dx);
                let mass = body.particle_mass;
                affine
                    .0
                    .par_iter_mut()
                    .zip(
                        svd.u
                            .par_iter()
                            .zip(tau.0.par_iter().zip(start.c.par_iter())),
                    )
                    .for_each(|(a, (&u, (&t, &c)))| {
                        *a = crate::systems::constitutive::p2g_affine(u, t, c, coef, mass);
                    });
            }
            std::mem::swap(&mut *order, &mut b.order);
        }
        if save {
            self.grid.pack(&*world);
        } else {
            self.grid.unpack(world);
        }
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
    pub(crate) fn bytes(particles: usize, nodes: usize) -> usize {
        // start (x, v, C, F), final v, collision input, U, σ, V, the material's saved update,
        // the principal stress (the affine term is rebuilt from it), order; grid m, p, v and the
        // two contact inputs. The trial F is not kept: no adjoint stage reads it (the SVD's
        // adjoint works from U, σ, V). The grid is an upper bound: a record packs the active
        // spans only (`PackedGrid`).
        particles * (2 * 24 + 2 * 72 + 24 + 24 + 72 + 24 + 72 + 72 + 24 + 4) + nodes * (8 + 4 * 24)
    }
}

/// Accumulated wall time per named part.
#[derive(Default)]
pub(crate) struct Timing(pub(crate) Vec<(String, f64)>);

impl Timing {
    pub(crate) fn add(&mut self, name: &str, secs: f64) {
        match self.0.iter_mut().find(|e| e.0 == name) {
            Some(e) => e.1 += secs,
            None => self.0.push((name.to_string(), secs)),
        }
    }
    pub(crate) fn add_stage(&mut self, prefix: &str, stage: Stage, secs: f64) {
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
