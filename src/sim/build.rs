//! Building the ECS world and the substep schedule from a prepared scene.
//!
//! [`Build`] holds what does not depend on the tools' controls: the prepared scene (its particle
//! fills) and each static container's contact table with the grid nodes. A rollout for new
//! controls ([`Build::with_controls`]) reuses both and only spawns a fresh world, so the
//! optimiser's rollouts do not refill the powder or re-evaluate the containers' SDFs.

use super::{SimOptions, Simulation};
use crate::components::*;
use crate::error::SceneError;
use crate::scene::{ColliderKindSpec, Prepared, PreparedBody, Scene, StartColumns};
use crate::systems::{self, SubstepPlan};
use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3};
use std::sync::Arc;

/// A scene ready to be spawned into worlds, any number of times.
#[derive(Clone, Debug)]
pub struct Build {
    pub prepared: Prepared,
    /// Static containers' contact tables, by scene index.
    node_contacts: Arc<Vec<(usize, NodeContacts)>>,
}

/// The grid of a scene, with zeroed nodes.
fn grid_of(scene: &Scene) -> Grid {
    let s = &scene.simulation;
    Grid::new(
        DVec3::from(s.domain_min),
        s.dx,
        [s.cells.0, s.cells.1, s.cells.2],
    )
}

impl Build {
    /// Prepares the scene (every check) and computes its containers' contact tables.
    pub fn new(scene: &Scene) -> Result<Build, SceneError> {
        let prepared = scene.prepare()?;
        let grid = grid_of(scene);
        let dx = scene.simulation.dx;
        let node_contacts = scene
            .colliders
            .iter()
            .zip(&prepared.colliders)
            .enumerate()
            .filter(|(_, (c, _))| c.kind == ColliderKindSpec::Container)
            .map(|(i, (c, p))| {
                let pose = ColliderPose {
                    pose: p.pose,
                    ..Default::default()
                };
                (i, NodeContacts::build(&collider(c, i, dx), &pose, &grid))
            })
            .collect();
        Ok(Build {
            prepared,
            node_contacts: Arc::new(node_contacts),
        })
    }

    /// The same build with collider `i`'s controls replaced (see [`Prepared::with_controls`]).
    pub fn with_controls(
        &self,
        scene: &Scene,
        i: usize,
        controls: Vec<[f64; 6]>,
    ) -> Result<Build, SceneError> {
        Ok(Build {
            prepared: self.prepared.with_controls(scene, i, controls)?,
            node_contacts: self.node_contacts.clone(),
        })
    }

    /// The same build with every body starting from `states` (one per body, in scene order,
    /// with the body's name) instead of its fill at rest: a snapshot of an earlier rollout, so
    /// that a sequence of actions (a planner's scoops) continues where the last one ended. A
    /// state may hold fewer particles than the fill (a planner discards what fell outside the
    /// cups); an empty body is refused, as in a scene.
    ///
    /// Refused: a different body count, columns of unequal length, a non-finite value or a
    /// hardening material (its plastic strain is not part of [`BodyState`]). The stability
    /// guard runs again with the state's fastest particle, so a snapshot in motion may raise
    /// the substeps (and a scene under `Strict` refuse it), as a body's initial velocity does.
    pub fn with_start(&self, scene: &Scene, states: &[BodyState]) -> anyhow::Result<Build> {
        let p = &self.prepared;
        anyhow::ensure!(
            states.len() == p.bodies.len(),
            "a start state of {} bodies for a scene of {}",
            states.len(),
            p.bodies.len()
        );
        let mut bodies = Vec::with_capacity(states.len());
        for (i, (st, pb)) in states.iter().zip(p.bodies.iter()).enumerate() {
            let n = st.x.len();
            anyhow::ensure!(
                n > 0 && st.v.len() == n && st.c.len() == n && st.f.len() == n,
                "start state of body {i} ('{}'): {} positions, {} velocities, {} C and {} F; \
                 expected the same number, at least one",
                st.name,
                n,
                st.v.len(),
                st.c.len(),
                st.f.len()
            );
            anyhow::ensure!(
                !pb.material.hardens(),
                "start state of body {i} ('{}'): its material hardens, and a snapshot does \
                 not carry the plastic strain",
                st.name
            );
            let finite = st.x.iter().chain(&st.v).all(|a| a.is_finite())
                && st.c.iter().chain(&st.f).all(|m| m.is_finite());
            anyhow::ensure!(
                finite,
                "start state of body {i} ('{}'): a non-finite value",
                st.name
            );
            bodies.push(PreparedBody {
                x: st.x.clone(),
                start: Some(Arc::new(StartColumns {
                    v: st.v.clone(),
                    c: st.c.clone(),
                    f: st.f.clone(),
                    max_speed: st.v.iter().map(|v| v.length()).fold(0.0, f64::max),
                })),
                ..pb.clone()
            });
        }
        let mut prepared = p.clone();
        prepared.bodies = Arc::new(bodies);
        prepared.guard(scene)?;
        Ok(Build {
            prepared,
            node_contacts: self.node_contacts.clone(),
        })
    }

    /// Spawns a world at the scene's start and builds its schedule. `scene` is the scene this
    /// build was made from (with the new controls' source, for a build with new controls).
    pub fn simulation(&self, owned: Scene, opts: &SimOptions) -> Result<Simulation, SceneError> {
        let scene = &owned;
        let s = &scene.simulation;
        let p = &self.prepared;
        let grid = grid_of(scene);
        let mut world = World::new();
        for (i, (c, pc)) in scene.colliders.iter().zip(&p.colliders).enumerate() {
            let mut e = world.spawn((
                collider(c, i, s.dx),
                ColliderPose {
                    pose: pc.pose,
                    ..Default::default()
                },
            ));
            if pc.kind == ColliderKind::Tool {
                e.insert(Control {
                    per_step: pc.controls.clone(),
                });
            }
        }
        // The substep every body and the schedule run at, fixed when the world is built.
        let substeps = p.stability.substeps;
        let dt_sub = s.dt / substeps as f64;
        for (i, (b, pb)) in scene.bodies.iter().zip(p.bodies.iter()).enumerate() {
            let np = pb.x.len();
            let mut e = world.spawn((
                Body {
                    name: b.name.clone(),
                    index: i,
                    particle_mass: pb.particle_mass,
                    particle_volume: pb.particle_volume,
                    lame: pb.lame,
                },
                Position(pb.x.clone()),
                Velocity(
                    pb.start
                        .as_ref()
                        .map_or_else(|| vec![pb.velocity; np], |s| s.v.clone()),
                ),
                AffineVelocity(
                    pb.start
                        .as_ref()
                        .map_or_else(|| vec![DMat3::ZERO; np], |s| s.c.clone()),
                ),
                DeformationGradient(
                    pb.start
                        .as_ref()
                        .map_or_else(|| vec![DMat3::IDENTITY; np], |s| s.f.clone()),
                ),
                TrialDeformation(vec![DMat3::IDENTITY; np]),
                SvdFactors {
                    u: vec![DMat3::IDENTITY; np],
                    s: vec![DVec3::ONE; np],
                    v: vec![DMat3::IDENTITY; np],
                },
                P2gAffine(vec![DMat3::ZERO; np]),
                ScatterOrder::default(),
            ));
            if pb.material.hardens() {
                e.insert(Hardening(vec![0.0; np]));
            }
            pb.material
                .insert_into(&mut e, s.dt / p.stability.substeps as f64);
        }
        world.insert_resource(SimParams {
            dt: s.dt,
            substeps,
            dt_sub,
            gravity: DVec3::from(s.gravity),
            empty_node_mass: if p.min_particle_mass.is_finite() {
                s.empty_node_ratio * p.min_particle_mass
            } else {
                0.0
            },
            svd: s.svd,
        });
        // Static containers' contact with the grid nodes, found once (a table per container).
        let mut containers = world.query::<(Entity, &Collider)>();
        let entities: Vec<(Entity, usize)> = containers
            .iter(&world)
            .filter(|(_, c)| c.kind == ColliderKind::Container)
            .map(|(e, c)| (e, c.index))
            .collect();
        for (e, i) in entities {
            let (_, table) = self
                .node_contacts
                .iter()
                .find(|t| t.0 == i)
                .expect("a table per container");
            world.entity_mut(e).insert(table.clone());
        }
        if let Some(spec) = &scene.balance {
            // Validation made the balance's container a Cup; containers never move.
            let boat = scene
                .colliders
                .iter()
                .zip(&p.colliders)
                .find(|(c, _)| c.name == spec.container)
                .and_then(|(c, pc)| crate::math::geometry::CupRegion::of(&c.shape, pc.pose))
                .ok_or_else(|| {
                    internal_error(
                        scene,
                        format!(
                            "internal: the balance's boat '{}' is not a Cup",
                            spec.container
                        ),
                    )
                })?;
            world.spawn(Balance::new(boat, spec));
        }
        world.insert_resource(grid);
        world.insert_resource(DomainWalls {
            cells: s.walls.cells,
            mode: s.walls.contact,
            friction: s.walls.friction,
        });
        world.insert_resource(Clock::default());
        world.insert_resource(Health::default());

        let plan = SubstepPlan {
            materials: p.materials_used.clone(),
            has_tools: scene
                .colliders
                .iter()
                .any(|c| c.kind == ColliderKindSpec::Tool),
            has_colliders: !scene.colliders.is_empty(),
            particle_contact: scene.colliders.iter().any(|c| c.particle_contact),
        };
        let internal = |message: String| internal_error(scene, message);
        let mut schedule = systems::build_substep_schedule(&plan);
        schedule.initialize(&mut world).map_err(|e| {
            internal(format!(
                "internal: the substep schedule does not build: {e:?}"
            ))
        })?;
        let stage_schedules = opts
            .stage_timers
            .then(|| systems::build_stage_schedules(&plan));
        if opts.stage_timers {
            world.insert_resource(StageTimers {
                enabled: true,
                ..Default::default()
            });
        }
        let threads = opts.threads.unwrap_or(s.threads);
        if threads > crate::scene::MAX_THREADS && !opts.shared_pool {
            // The scene file and the CLI are checked where they are read; this is a caller in
            // code. (`--threads 100000`, before any bound, had started 15,589 threads after 14
            // minutes without finishing a step.)
            return Err(SceneError::Invalid {
                file: scene.path.clone(),
                line: 1,
                col: 1,
                field: "SimOptions::threads (set in code, not in this file)".into(),
                value: threads.to_string(),
                expected: format!("<= {} (0 uses all cores)", crate::scene::MAX_THREADS),
            });
        }
        let pool = if opts.shared_pool {
            None
        } else {
            Some(
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .map_err(|e| internal(format!("cannot start {threads} worker threads: {e}")))?,
            )
        };
        let mut instruments = systems::build_instrument_schedule(scene.balance.is_some());
        if let Some(i) = &mut instruments {
            i.initialize(&mut world).map_err(|e| {
                internal(format!(
                    "internal: the instruments' schedule does not build: {e:?}"
                ))
            })?;
        }
        if opts.rest.is_some() {
            let mut q = world.query_filtered::<Entity, With<Body>>();
            let bodies: Vec<Entity> = q.iter(&world).collect();
            for e in bodies {
                world.entity_mut(e).insert(Parked::default());
            }
        }
        Ok(Simulation {
            world,
            schedule,
            rest: opts.rest,
            particle_substeps: 0.0,
            instruments,
            stage_schedules,
            pool,
            plan,
            stability: p.stability.clone(),
            horizon: p.horizon,
            scene: owned,
        })
    }
}

/// The `Collider` component of scene collider `i`.
fn collider(c: &crate::scene::ColliderSpec, i: usize, dx: f64) -> Collider {
    Collider {
        name: c.name.clone(),
        index: i,
        kind: match c.kind {
            ColliderKindSpec::Tool => ColliderKind::Tool,
            ColliderKindSpec::Container => ColliderKind::Container,
        },
        shape: c.shape.clone(),
        friction: c.friction,
        contact: c.contact,
        band: c.band_cells * dx,
        soft_band: c.soft_band,
        bounding_radius: c.shape.bounding_radius(),
        particle_contact: c.particle_contact,
        soft_particle_contact: c.soft_particle_contact,
    }
}

/// An error of this code, not of the scene, reported against the scene's file.
fn internal_error(scene: &Scene, message: String) -> SceneError {
    SceneError::Parse {
        file: scene.path.clone(),
        line: 1,
        col: 1,
        message,
    }
}
