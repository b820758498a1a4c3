//! The driver: builds the ECS world and the substep schedule from a scene, applies the
//! stability guard, and runs `N_sub` substeps per global step.

use crate::components::*;
use crate::error::{FieldError, SceneError, SimError};
use crate::materials::MaterialSpec;
use crate::math::pose::Pose;
use crate::math::sdf::Shape;
use crate::scene::*;
use crate::systems::{self, SubstepPlan};
use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3};
use std::time::Instant;

/// The most substeps per step `stability: Auto` takes to meet the CFL bound. Beyond it a scene
/// is refused: at 1e6 substeps a step of even the smallest scene runs for minutes, and the cause
/// is a stiffness or speed far outside what the scene means (a typo in `youngs_modulus`).
pub const MAX_AUTO_SUBSTEPS: usize = 1_000_000;

/// What the stability guard found and chose.
#[derive(Clone, Debug, PartialEq)]
pub struct StabilityReport {
    /// Largest elastic wave speed `√((λ+2μ)/ρ)` over the bodies (m/s).
    pub wave_speed: f64,
    /// Largest speed of a tool point or initial particle (m/s).
    pub max_speed: f64,
    /// Largest stable substep `C·dx/(c + v)` (s).
    pub dt_max: f64,
    pub substeps_requested: usize,
    pub substeps: usize,
}

impl StabilityReport {
    pub fn raised(&self) -> bool {
        self.substeps > self.substeps_requested
    }
}

/// Options that override the scene.
#[derive(Clone, Debug, Default)]
pub struct SimOptions {
    /// Worker threads (overrides the scene; 0 = all cores).
    pub threads: Option<usize>,
    /// Time each stage separately (for `bench`).
    pub stage_timers: bool,
    /// Run the systems in the caller's rayon pool instead of a pool of the simulation's own
    /// (`threads` is then ignored). For many simulations side by side, such as the rollouts of
    /// `optimize`: the caller's pool balances them, and an idle worker helps a running one.
    pub shared_pool: bool,
}

/// Runs `f` in `pool`, or in the caller's pool when there is none: inline on a worker of the
/// pool the caller runs on, else on a worker of rayon's global pool (the pool the caller's
/// parallel loops would use). Either way `f` starts on a worker, so its parallel loops do not
/// each hand their work from a foreign thread to the pool and sleep until it is done.
pub(crate) fn run_in<R: Send>(pool: &Option<rayon::ThreadPool>, f: impl FnOnce() -> R + Send) -> R {
    match pool {
        Some(p) => p.install(f),
        None if rayon::current_thread_index().is_some() => f(),
        None => rayon::scope(|_| f()),
    }
}

/// A running simulation.
pub struct Simulation {
    pub world: World,
    schedule: Schedule,
    stage_schedules: Option<Vec<(&'static str, Schedule)>>,
    /// The simulation's own worker pool; `None` runs in the caller's (`SimOptions::shared_pool`).
    pub(crate) pool: Option<rayon::ThreadPool>,
    pub plan: SubstepPlan,
    pub stability: StabilityReport,
    /// Global steps of the scene's horizon.
    pub horizon: usize,
    pub scene: Scene,
}

/// Bytes a forward simulation holds per grid node: mass, momentum and velocity in f64
/// (`study growth`'s grid series measured 56 bytes per node of peak RSS).
const GRID_BYTES_PER_NODE: f64 = 56.0;
/// Bytes a forward simulation holds per particle: x, v, C, F, F_tmp, the SVD factors, the P2G
/// affine term and the scatter order in f64, plus the material's state (`study growth`'s
/// particle series measured about 516 bytes per particle of peak RSS at 1M particles).
const PARTICLE_BYTES: f64 = 520.0;
/// Bytes per lattice point while a fill is generated (a position in f64).
const LATTICE_BYTES_PER_POINT: f64 = 24.0;

/// Refuses the scene, naming the field that `what` describes (field, value, what needs the
/// memory, how to fix it), when `need` bytes exceed the memory available; passes where the
/// available memory is unknown.
fn check_memory(
    scene: &Scene,
    available: Option<u64>,
    need: f64,
    what: impl FnOnce() -> (String, String, String, String),
) -> Result<(), SceneError> {
    let Some(avail) = available else {
        return Ok(());
    };
    if need <= avail as f64 {
        return Ok(());
    }
    let (field, value, needs, fix) = what();
    Err(scene.field_error(FieldError::new(
        field,
        value,
        format!(
            "a scene that fits in memory: {needs} need about {:.1} GB, and {:.1} GB are available; {fix}",
            need / 1e9,
            avail as f64 / 1e9
        ),
    )))
}

/// The lattice a body's fill is cut from: its first corner, its spacing and its point count
/// per axis (for `InsideContainer`, in the cup's own frame). The counts are in f64, so that the
/// memory check measures an absurd fill before `fill_points` allocates it.
fn fill_lattice(scene: &Scene, body: &BodySpec) -> (DVec3, f64, DVec3) {
    let h = scene.particle_spacing(body);
    let (lo, hi) = fill_bounds(scene, body);
    let n = ((hi - lo) / h + DVec3::splat(1e-9))
        .floor()
        .max(DVec3::ZERO);
    (lo, h, n)
}

/// The box the fill's lattice spans (for `InsideContainer`, in the cup's own frame).
fn fill_bounds(scene: &Scene, body: &BodySpec) -> (DVec3, DVec3) {
    match &body.fill {
        Fill::Box { min, max } => (DVec3::from(*min), DVec3::from(*max)),
        Fill::Column {
            base,
            length,
            aspect,
            depth,
        } => {
            let b = DVec3::from(*base);
            (b, b + DVec3::new(*length, aspect * length, *depth))
        }
        Fill::Cylinder {
            base,
            radius,
            height,
        } => {
            let b = DVec3::from(*base);
            (
                b - DVec3::new(*radius, 0.0, *radius),
                b + DVec3::new(*radius, *height, *radius),
            )
        }
        Fill::InsideContainer { container, height } => {
            let (r, floor) = cup_cavity(fill_container(scene, container));
            (DVec3::new(-r, floor, -r), DVec3::new(r, floor + height, r))
        }
    }
}

/// The collider an `InsideContainer` fill names.
fn fill_container<'a>(scene: &'a Scene, container: &str) -> &'a ColliderSpec {
    scene
        .colliders
        .iter()
        .find(|c| c.name == container)
        .expect("validated")
}

/// The cavity radius and floor height of a cup collider, in its own frame.
fn cup_cavity(c: &ColliderSpec) -> (f64, f64) {
    let Shape::Cup {
        outer_radius,
        wall_thickness,
        floor_thickness,
        ..
    } = c.shape
    else {
        unreachable!("validated: fill container is a cup")
    };
    (outer_radius - wall_thickness, floor_thickness)
}

/// Particles of a fill, before collider clearance and domain checks.
fn fill_points(scene: &Scene, body: &BodySpec) -> Vec<DVec3> {
    let lattice = |keep: &dyn Fn(DVec3) -> bool| -> Vec<DVec3> {
        let (lo, h, n) = fill_lattice(scene, body);
        let (nx, ny, nz) = (n.x as usize, n.y as usize, n.z as usize);
        let mut out = Vec::with_capacity(nx * ny * nz);
        for i in 0..nx {
            for j in 0..ny {
                for k in 0..nz {
                    let p = lo + DVec3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5) * h;
                    if keep(p) {
                        out.push(p);
                    }
                }
            }
        }
        out
    };
    match &body.fill {
        Fill::Box { .. } | Fill::Column { .. } => lattice(&|_| true),
        Fill::Cylinder { base, radius, .. } => {
            let b = DVec3::from(*base);
            lattice(&|p| (p.x - b.x).hypot(p.z - b.z) < *radius)
        }
        Fill::InsideContainer { container, .. } => {
            let c = fill_container(scene, container);
            let (r, _) = cup_cavity(c);
            let pose = Scene::collider_pose(c);
            lattice(&|p| p.x.hypot(p.z) < r)
                .into_iter()
                .map(|p| pose.to_world(p))
                .collect()
        }
    }
}

impl Simulation {
    /// Builds a simulation from a validated scene.
    pub fn new(scene: &Scene, opts: &SimOptions) -> Result<Simulation, SceneError> {
        let s = &scene.simulation;
        let dx = s.dx;
        let n = [s.cells.0, s.cells.1, s.cells.2];
        // Refuse a scene that cannot fit in memory before allocating it (an allocation that
        // fails aborts the process, and an over-committed one brings the OOM killer): the grid,
        // and the lattice every fill is cut from, at their largest.
        let available = crate::util::available_memory_bytes();
        let nodes = (n[0] * n[1] * n[2]) as f64;
        let grid_bytes = nodes * GRID_BYTES_PER_NODE;
        let candidates: f64 = scene
            .bodies
            .iter()
            .map(|b| {
                let n = fill_lattice(scene, b).2;
                n.x * n.y * n.z
            })
            .sum();
        check_memory(
            scene,
            available,
            grid_bytes + candidates * LATTICE_BYTES_PER_POINT,
            || {
                (
                    "simulation.cells".into(),
                    format!("{:?}", s.cells),
                    format!(
                        "a grid of {nodes:.3e} nodes and fills of {candidates:.3e} lattice points"
                    ),
                    "raise simulation.dx, shrink simulation.cells or the fills".into(),
                )
            },
        )?;
        let grid = Grid::new(DVec3::from(s.domain_min), dx, n);
        let (safe_lo, safe_hi) = (
            grid.origin + DVec3::splat(dx),
            grid.extent_max() - DVec3::splat(dx),
        );
        let mut world = World::new();

        // Colliders first: particle fills are cleared against them.
        let mut poses = Vec::new();
        let mut horizon_from_controls = 0usize;
        let mut max_speed = 0.0f64;
        for (i, c) in scene.colliders.iter().enumerate() {
            let pose = Scene::collider_pose(c);
            let kind = match c.kind {
                ColliderKindSpec::Tool => ColliderKind::Tool,
                ColliderKindSpec::Container => ColliderKind::Container,
            };
            let controls: Vec<[f64; 6]> = match &c.control {
                None => Vec::new(),
                Some(ControlSpec::Actions(a)) => a.clone(),
                Some(ControlSpec::Constant {
                    linear,
                    angular,
                    steps,
                }) => {
                    let u = [
                        linear.0, linear.1, linear.2, angular.0, angular.1, angular.2,
                    ]
                    .map(|x| x * s.dt);
                    vec![u; *steps]
                }
                Some(ControlSpec::Skill(sk)) => sk.controls(s.dt, Scene::tool_bottom(c)).0,
            };
            horizon_from_controls = horizon_from_controls.max(controls.len());
            let r = c.shape.bounding_radius();
            check_collider_reaches_grid(scene, i, &grid, pose.translation, r, &controls)?;
            for u in &controls {
                let lin = DVec3::new(u[0], u[1], u[2]).length() / s.dt;
                let ang = DVec3::new(u[3], u[4], u[5]).length() / s.dt;
                max_speed = max_speed.max(lin + if r.is_finite() { ang * r } else { 0.0 });
            }
            poses.push((c, pose));
            let mut e = world.spawn((
                Collider {
                    name: c.name.clone(),
                    index: i,
                    kind,
                    shape: c.shape.clone(),
                    friction: c.friction,
                    contact: c.contact,
                    band: c.band_cells * dx,
                    soft_band: c.soft_band,
                    bounding_radius: c.shape.bounding_radius(),
                    particle_contact: c.particle_contact,
                },
                ColliderPose {
                    pose,
                    ..Default::default()
                },
            ));
            if kind == ColliderKind::Tool {
                e.insert(Control { per_step: controls });
            }
        }
        check_tools_clear_of_containers(scene, &poses)?;

        // Bodies.
        let mut wave_speed = 0.0f64;
        let mut min_particle_mass = f64::INFINITY;
        let mut materials_used: Vec<MaterialSpec> = Vec::new();
        let mut rng = crate::util::SplitMix64(s.seed);
        let mut particles_so_far = 0.0f64;
        for (i, b) in scene.bodies.iter().enumerate() {
            let mat = &scene.materials[&b.material];
            let mat = match mat {
                MaterialSpec::DruckerPrager(dp) => {
                    MaterialSpec::DruckerPrager(dp.clone().prepared())
                }
                other => other.clone(),
            };
            let h = scene.particle_spacing(b);
            let mut x: Vec<DVec3> = fill_points(scene, b);
            if let Lattice::Jittered(j) = b.lattice {
                for p in &mut x {
                    let d = DVec3::new(rng.uniform(), rng.uniform(), rng.uniform());
                    *p += (d - DVec3::splat(0.5)) * (j * h);
                }
            }
            // Keep particles clear of every collider by a quarter spacing.
            x.retain(|&p| {
                poses.iter().all(|(c, pose)| {
                    let cp = ColliderPose {
                        pose: *pose,
                        ..Default::default()
                    };
                    cp.sdf(&c.shape, p).0 > 0.25 * h
                })
            });
            if let Some(p) = x
                .iter()
                .find(|p| !(p.cmpge(safe_lo).all() && p.cmple(safe_hi).all()))
            {
                return Err(scene.field_error(FieldError::new(
                    format!("bodies[{i}].fill"),
                    format!("a particle at ({:.4}, {:.4}, {:.4})", p.x, p.y, p.z),
                    format!(
                        "every particle inside the grid's safe region ({:.4}, {:.4}, {:.4})–({:.4}, {:.4}, {:.4}) m; shrink the fill or enlarge simulation.cells",
                        safe_lo.x, safe_lo.y, safe_lo.z, safe_hi.x, safe_hi.y, safe_hi.z
                    ),
                )));
            }
            particles_so_far += x.len() as f64;
            check_memory(
                scene,
                available,
                grid_bytes + particles_so_far * PARTICLE_BYTES,
                || {
                    (
                        format!("bodies[{i}].particles_per_cell"),
                        b.particles_per_cell.to_string(),
                        format!(
                            "{particles_so_far:.3e} particles (this body {}) on a grid of {nodes:.3e} nodes",
                            x.len()
                        ),
                        "lower particles_per_cell, shrink the fills or raise simulation.dx".into(),
                    )
                },
            )?;
            let volume = h * h * h;
            let mass = mat.density() * volume;
            let (mu, lambda) = mat.lame();
            wave_speed = wave_speed.max(((lambda + 2.0 * mu) / mat.density()).sqrt());
            min_particle_mass = min_particle_mass.min(mass);
            let v0 = DVec3::from(b.velocity);
            max_speed = max_speed.max(v0.length());
            if !materials_used
                .iter()
                .any(|m| m.plugin_index() == mat.plugin_index())
            {
                materials_used.push(mat.clone());
            }
            let np = x.len();
            let mut e = world.spawn((
                Body {
                    name: b.name.clone(),
                    index: i,
                    particle_mass: mass,
                    particle_volume: volume,
                    lame: (mu, lambda),
                },
                Position(x),
                Velocity(vec![v0; np]),
                AffineVelocity(vec![DMat3::ZERO; np]),
                DeformationGradient(vec![DMat3::IDENTITY; np]),
                TrialDeformation(vec![DMat3::IDENTITY; np]),
                SvdFactors {
                    u: vec![DMat3::IDENTITY; np],
                    s: vec![DVec3::ONE; np],
                    v: vec![DMat3::IDENTITY; np],
                },
                P2gAffine(vec![DMat3::ZERO; np]),
                ScatterOrder::default(),
            ));
            if mat.hardens() {
                e.insert(Hardening(vec![0.0; np]));
            }
            mat.insert_into(&mut e);
        }

        // Stability guard.
        let dt_sub = s.dt / s.substeps as f64;
        let dt_max = s.cfl * dx / (wave_speed + max_speed);
        let mut substeps = s.substeps;
        if dt_sub > dt_max * (1.0 + 1e-12) {
            // In f64: for an absurd stiffness the count exceeds any integer (`as usize` would
            // saturate and print 18446744073709551615 as the advice).
            let needed = (s.dt / dt_max).ceil();
            let too_many = needed > MAX_AUTO_SUBSTEPS as f64;
            // Fixed-point below 1e6 m/s, as the stability table prints them; an absurd
            // stiffness in scientific notation rather than 150 digits.
            let speed = |v: f64| {
                if v < 1e6 {
                    format!("{v:.3}")
                } else {
                    format!("{v:.3e}")
                }
            };
            let reason = format!(
                "elastic wave speed {} m/s + largest speed {} m/s, dx {dx} m, CFL {}",
                speed(wave_speed),
                speed(max_speed),
                s.cfl
            );
            let refuse = move |advice: String| SceneError::Unstable {
                file: scene.path.clone(),
                dt_sub,
                dt_max,
                needed,
                reason,
                advice,
            };
            if too_many {
                return Err(refuse(format!(
                    "it would need {needed:.3e} substeps per step, more than the {MAX_AUTO_SUBSTEPS} even stability: Auto takes: lower the materials' youngs_modulus (the wave speed grows as its square root) or the tool speeds, or raise dx"
                )));
            }
            match s.stability {
                Stability::Strict => {
                    return Err(refuse(format!(
                        "with stability: Strict the scene is refused: raise simulation.substeps to at least {needed} or set stability: Auto"
                    )))
                }
                Stability::Auto => substeps = needed as usize,
            }
        }
        let stability = StabilityReport {
            wave_speed,
            max_speed,
            dt_max,
            substeps_requested: s.substeps,
            substeps,
        };

        world.insert_resource(SimParams {
            dt: s.dt,
            substeps,
            dt_sub: s.dt / substeps as f64,
            gravity: DVec3::from(s.gravity),
            empty_node_mass: if min_particle_mass.is_finite() {
                s.empty_node_ratio * min_particle_mass
            } else {
                0.0
            },
        });
        // Static containers' contact with the grid nodes, found once (a table per container).
        let mut containers = world.query::<(Entity, &Collider, &ColliderPose)>();
        let tables: Vec<_> = containers
            .iter(&world)
            .filter(|(_, c, _)| c.kind == ColliderKind::Container)
            .map(|(e, c, p)| (e, NodeContacts::build(c, p, &grid)))
            .collect();
        for (e, t) in tables {
            world.entity_mut(e).insert(t);
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
            materials: materials_used,
            has_tools: scene
                .colliders
                .iter()
                .any(|c| c.kind == ColliderKindSpec::Tool),
            has_colliders: !scene.colliders.is_empty(),
            particle_contact: scene.colliders.iter().any(|c| c.particle_contact),
        };
        let mut schedule = systems::build_substep_schedule(&plan);
        schedule
            .initialize(&mut world)
            .map_err(|e| SceneError::Parse {
                file: scene.path.clone(),
                line: 1,
                col: 1,
                message: format!("internal: the substep schedule does not build: {e:?}"),
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
                    .map_err(|e| SceneError::Parse {
                        file: scene.path.clone(),
                        line: 1,
                        col: 1,
                        message: format!("cannot start {threads} worker threads: {e}"),
                    })?,
            )
        };
        Ok(Simulation {
            world,
            schedule,
            stage_schedules,
            pool,
            plan,
            stability,
            horizon: s.steps.unwrap_or(horizon_from_controls.max(1)),
            scene: scene.clone(),
        })
    }

    /// Loads a scene file and builds it.
    pub fn from_file(
        path: impl AsRef<std::path::Path>,
        opts: &SimOptions,
    ) -> Result<Simulation, SceneError> {
        Simulation::new(&Scene::load(path)?, opts)
    }

    /// Names of the systems in the substep schedule, in run order.
    pub fn system_names(&self) -> Vec<String> {
        self.schedule
            .systems()
            .map(|it| {
                it.map(|(_, s)| {
                    let name = s.name().to_string();
                    // Drop the crate and module prefix; keep `stage::system<Material>`.
                    let name = name.replace("powderlab::systems::", "");
                    name.replace("powderlab::materials::", "")
                })
                .collect()
            })
            .unwrap_or_default()
    }

    /// Worker threads in use.
    pub fn threads(&self) -> usize {
        self.pool
            .as_ref()
            .map_or_else(rayon::current_num_threads, |p| p.current_num_threads())
    }

    pub fn clock(&self) -> Clock {
        *self.world.resource::<Clock>()
    }

    pub fn params(&self) -> &SimParams {
        self.world.resource::<SimParams>()
    }

    /// Runs `f` with the simulation on a worker of its pool (its own, or the caller's for a
    /// shared-pool simulation), the pool set aside meanwhile: every stage's [`run_in`] inside
    /// then runs inline on that worker, for work of many stages such as a backward pass.
    pub(crate) fn on_worker<R: Send>(&mut self, f: impl FnOnce(&mut Simulation) -> R + Send) -> R {
        let pool = self.pool.take();
        let out = run_in(&pool, || f(self));
        self.pool = pool;
        out
    }

    /// One substep.
    pub fn substep(&mut self) -> Result<(), SimError> {
        let world = &mut self.world;
        match &mut self.stage_schedules {
            None => run_in(&self.pool, || self.schedule.run(world)),
            Some(stages) => {
                for (name, s) in stages.iter_mut() {
                    let t = Instant::now();
                    run_in(&self.pool, || s.run(world));
                    let dt = t.elapsed().as_secs_f64();
                    world.resource_mut::<StageTimers>().add(name, dt);
                }
            }
        }
        self.finish_substep()
    }

    /// Ends a substep whose stages have run: stops on a recorded non-finite value, else advances
    /// the clock.
    pub(crate) fn finish_substep(&mut self) -> Result<(), SimError> {
        let world = &mut self.world;
        let mut clock = *world.resource::<Clock>();
        if let Some(fault) = world.resource_mut::<Health>().fault.take() {
            return Err(SimError::NonFinite {
                step: clock.step,
                substep: clock.substep,
                fault,
            });
        }
        clock.total_substeps += 1;
        clock.substep += 1;
        *world.resource_mut::<Clock>() = clock;
        Ok(())
    }

    /// One global step: `N_sub` substeps.
    pub fn step(&mut self) -> Result<(), SimError> {
        self.step_with(|_, _| {})
    }

    /// One global step that calls `before(world, t)` before each substep, with `t` the simulated
    /// time at the substep's start: for loads that vary in time, such as a gravity ramp in the
    /// validation cases.
    pub fn step_with(&mut self, mut before: impl FnMut(&mut World, f64)) -> Result<(), SimError> {
        let n = self.params().substeps;
        let (dt, dt_sub) = (self.params().dt, self.params().dt_sub);
        self.world.resource_mut::<Clock>().substep = 0;
        let t0 = self.clock().step as f64 * dt;
        for k in 0..n {
            before(&mut self.world, t0 + k as f64 * dt_sub);
            self.substep()?;
        }
        let mut clock = self.world.resource_mut::<Clock>();
        clock.step += 1;
        clock.substep = 0;
        Ok(())
    }

    /// Runs `steps` global steps, calling `progress` after each.
    pub fn run(&mut self, steps: usize, mut progress: impl FnMut(usize)) -> Result<(), SimError> {
        for k in 0..steps {
            self.step()?;
            progress(k + 1);
        }
        Ok(())
    }

    /// Particle state of every body, in scene order.
    pub fn body_states(&mut self) -> Vec<BodyState> {
        let mut q = self.world.query::<(
            &Body,
            &Position,
            &Velocity,
            &AffineVelocity,
            &DeformationGradient,
        )>();
        let mut out: Vec<(usize, BodyState)> = q
            .iter(&self.world)
            .map(|(b, x, v, c, f)| {
                (
                    b.index,
                    BodyState {
                        name: b.name.clone(),
                        x: x.0.clone(),
                        v: v.0.clone(),
                        c: c.0.clone(),
                        f: f.0.clone(),
                    },
                )
            })
            .collect();
        out.sort_by_key(|e| e.0);
        out.into_iter().map(|e| e.1).collect()
    }

    /// Total particles.
    pub fn particle_count(&mut self) -> usize {
        let mut q = self.world.query::<&Position>();
        q.iter(&self.world).map(|x| x.0.len()).sum()
    }

    /// Poses of every collider, in scene order: (name, kind, shape, pose).
    pub fn collider_poses(&mut self) -> Vec<(String, ColliderKind, Shape, Pose)> {
        collider_poses(&mut self.world)
    }

    /// Runs one stage alone (only with `SimOptions::stage_timers`); for benchmarks and tests.
    /// Returns false if the scene has no such stage.
    pub fn run_stage(&mut self, name: &str) -> bool {
        let world = &mut self.world;
        let Some(stages) = &mut self.stage_schedules else {
            return false;
        };
        match stages.iter_mut().find(|s| s.0 == name) {
            Some((_, s)) => {
                run_in(&self.pool, || s.run(world));
                true
            }
            None => false,
        }
    }

    /// Names of the stages this scene runs, in order.
    pub fn stage_names(&self) -> Vec<&'static str> {
        self.stage_schedules
            .as_ref()
            .map_or_else(Vec::new, |s| s.iter().map(|s| s.0).collect())
    }

    /// Per-stage wall time so far (only with `SimOptions::stage_timers`).
    pub fn stage_seconds(&self) -> Vec<(&'static str, f64)> {
        self.world
            .get_resource::<StageTimers>()
            .map(|t| t.seconds.clone())
            .unwrap_or_default()
    }
}

/// Poses of every collider in a world, in scene order.
pub fn collider_poses(world: &mut World) -> Vec<(String, ColliderKind, Shape, Pose)> {
    let mut q = world.query::<(&Collider, &ColliderPose)>();
    let mut v: Vec<_> = q
        .iter(world)
        .map(|(c, p)| (c.index, (c.name.clone(), c.kind, c.shape.clone(), p.pose)))
        .collect();
    v.sort_by_key(|e| e.0);
    v.into_iter().map(|e| e.1).collect()
}

/// The lowest point of a shape in its local frame (used for the skill's descent).
pub fn lowest_local_point(shape: &Shape) -> DVec3 {
    match *shape {
        Shape::Spoon {
            bowl_radius,
            thickness,
            ..
        } => DVec3::new(0.0, -bowl_radius - 0.5 * thickness, 0.0),
        Shape::Sphere { radius } => DVec3::new(0.0, -radius, 0.0),
        Shape::Box { half_extents } => DVec3::new(0.0, -half_extents[1], 0.0),
        Shape::Capsule {
            half_length,
            radius,
        } => DVec3::new(0.0, -half_length - radius, 0.0),
        Shape::Cylinder { half_height, .. } => DVec3::new(0.0, -half_height, 0.0),
        Shape::Cup { .. } | Shape::Plane { .. } => DVec3::ZERO,
    }
}

/// Refuses a collider that never touches the grid: its bounding sphere (radius `r` about the
/// pose origin) lies outside the domain at the start and at every step of its controls. Such a
/// collider does nothing, and the usual cause is a position in the wrong units (millimetres
/// for metres) or a slip of sign, which would otherwise run silently with no container or tool.
fn check_collider_reaches_grid(
    scene: &Scene,
    i: usize,
    grid: &Grid,
    start: DVec3,
    r: f64,
    controls: &[[f64; 6]],
) -> Result<(), SceneError> {
    if !r.is_finite() {
        return Ok(());
    }
    let (lo, hi) = (grid.origin, grid.extent_max());
    let reaches = |p: DVec3| (p.clamp(lo, hi) - p).length() <= r;
    let mut p = start;
    if reaches(p) {
        return Ok(());
    }
    for u in controls {
        p += DVec3::new(u[0], u[1], u[2]);
        if reaches(p) {
            return Ok(());
        }
    }
    let c = &scene.colliders[i];
    Err(scene.field_error(FieldError::new(
        format!("colliders[{i}].position"),
        format!("{:?}", c.position),
        format!(
            "a collider that reaches the simulation domain ({:.4}, {:.4}, {:.4})–({:.4}, {:.4}, {:.4}) m at some step ('{}' stays outside it{}); positions are in metres",
            lo.x,
            lo.y,
            lo.z,
            hi.x,
            hi.y,
            hi.z,
            c.name,
            if controls.is_empty() { "" } else { " over its whole trajectory" }
        ),
    )))
}

/// Refuses a tool that starts inside a container's wall: samples points of the tool's solid on
/// a 16³ lattice over its bounding box and tests them against every container.
fn check_tools_clear_of_containers(
    scene: &Scene,
    poses: &[(&ColliderSpec, Pose)],
) -> Result<(), SceneError> {
    for (ti, (tool, tpose)) in poses.iter().enumerate() {
        if tool.kind != ColliderKindSpec::Tool {
            continue;
        }
        let r = tool.shape.bounding_radius();
        if !r.is_finite() {
            continue;
        }
        const N: usize = 16;
        for a in 0..N {
            for b in 0..N {
                for c in 0..N {
                    let local = (DVec3::new(a as f64, b as f64, c as f64) / (N - 1) as f64 * 2.0
                        - DVec3::ONE)
                        * r;
                    if tool.shape.sdf(local).0 >= 0.0 {
                        continue;
                    }
                    let p = tpose.to_world(local);
                    for (cont, cpose) in poses {
                        if cont.kind != ColliderKindSpec::Container {
                            continue;
                        }
                        if cont.shape.sdf(cpose.to_local(p)).0 < 0.0 {
                            return Err(scene.field_error(FieldError::new(
                                format!("colliders[{ti}].position"),
                                format!("{:?}", tool.position),
                                format!(
                                    "a start pose clear of container '{}' (the tool overlaps its wall at ({:.4}, {:.4}, {:.4}))",
                                    cont.name, p.x, p.y, p.z
                                ),
                            )));
                        }
                    }
                }
            }
        }
    }
    Ok(())
}
