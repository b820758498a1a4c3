//! The driver: builds the ECS world and the substep schedule from a scene ([`build`]), and
//! runs `N_sub` substeps per global step.
//!
//! A scene goes through three layers: [`crate::scene`] parses and checks it and derives the
//! particle fills and the controls ([`crate::scene::Prepared`]); [`build::Build`] spawns worlds
//! from that; [`Simulation`] steps one.

pub mod build;
pub mod rest;

pub use crate::scene::{StabilityReport, MAX_AUTO_SUBSTEPS};
pub use build::Build;

use crate::components::*;
use crate::error::{SceneError, SimError};
use crate::math::pose::Pose;
use crate::math::sdf::Shape;
use crate::scene::Scene;
use crate::systems::SubstepPlan;
use bevy_ecs::prelude::*;
use std::time::Instant;

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
    /// Set resting powder aside while nothing comes near it ([`rest`]); forward runs only.
    pub rest: Option<rest::RestRule>,
}

impl SimOptions {
    /// The defaults with `threads` worker threads (`None`: the scene's setting).
    pub fn threads(threads: Option<usize>) -> Self {
        SimOptions {
            threads,
            ..Default::default()
        }
    }
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
    /// The instruments (a balance), run once after each global step; `None` without any.
    instruments: Option<Schedule>,
    stage_schedules: Option<Vec<(&'static str, Schedule)>>,
    /// Resting powder set aside between steps, where the options ask for it.
    rest: Option<rest::RestRule>,
    /// Particle-substeps simulated so far: the awake particles of each substep.
    particle_substeps: f64,
    /// The simulation's own worker pool; `None` runs in the caller's (`SimOptions::shared_pool`).
    pub(crate) pool: Option<rayon::ThreadPool>,
    pub plan: SubstepPlan,
    pub stability: StabilityReport,
    /// Global steps of the scene's horizon.
    pub horizon: usize,
    pub scene: Scene,
}

impl Simulation {
    /// Builds a simulation from a validated scene: every check of [`Scene::prepare`], then a
    /// fresh world.
    pub fn new(scene: &Scene, opts: &SimOptions) -> Result<Simulation, SceneError> {
        Build::new(scene)?.simulation(scene.clone(), opts)
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
        if self.rest.is_some() {
            rest::before_step(&mut self.world);
        }
        self.particle_substeps += (self.awake_particle_count() * n) as f64;
        for k in 0..n {
            before(&mut self.world, t0 + k as f64 * dt_sub);
            self.substep()?;
        }
        let mut clock = self.world.resource_mut::<Clock>();
        clock.step += 1;
        clock.substep = 0;
        if let Some(i) = &mut self.instruments {
            i.run(&mut self.world);
        }
        if let Some(rule) = self.rest {
            rest::after_step(&mut self.world, &rule);
        }
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

    /// The balance's display (g), if the scene has a balance: all a controller may read of it.
    pub fn balance_reading_g(&mut self) -> Option<f64> {
        let mut q = self.world.query::<&Balance>();
        q.iter(&self.world).next().map(|b| b.reading_g)
    }

    /// The mass (g) in the balance's boat now, if the scene has a balance: the truth a dose is
    /// judged by, which no controller reads.
    pub fn balance_load_g(&mut self) -> Option<f64> {
        let mut q = self.world.query::<&Balance>();
        q.iter(&self.world).next().map(|b| b.load_g)
    }

    /// Sets the tool `tool`'s (scene index) control for the next step to `u` (translation and
    /// rotation vector over the step), for a controller that decides one step at a time; the
    /// tool's controls past the next step are dropped.
    pub fn drive_tool(&mut self, tool: usize, u: [f64; 6]) {
        let step = self.clock().step;
        let mut q = self.world.query::<(&Collider, &mut Control)>();
        for (c, mut ctl) in q.iter_mut(&mut self.world) {
            if c.index == tool {
                ctl.per_step.resize(step, [0.0; 6]);
                ctl.per_step.push(u);
            }
        }
    }

    /// The pose of the collider with scene index `index`.
    pub fn collider_pose(&mut self, index: usize) -> Option<Pose> {
        let mut q = self.world.query::<(&Collider, &ColliderPose)>();
        q.iter(&self.world)
            .find(|(c, _)| c.index == index)
            .map(|(_, p)| p.pose)
    }

    /// Particle state of every body, in scene order (parked particles included, in their
    /// places).
    pub fn body_states(&mut self) -> Vec<BodyState> {
        let mut q = self.world.query::<(
            &Body,
            &Position,
            &Velocity,
            &AffineVelocity,
            &DeformationGradient,
            Option<&Parked>,
        )>();
        let mut out: Vec<(usize, BodyState)> = q
            .iter(&self.world)
            .map(|(b, x, v, c, f, parked)| {
                let state = match parked {
                    Some(p) if !p.is_empty() => {
                        let (pv, pc, pf) = p.state();
                        BodyState {
                            name: b.name.clone(),
                            x: p.merged(&x.0, p.positions()),
                            v: p.merged(&v.0, pv),
                            c: p.merged(&c.0, pc),
                            f: p.merged(&f.0, pf),
                        }
                    }
                    _ => BodyState {
                        name: b.name.clone(),
                        x: x.0.clone(),
                        v: v.0.clone(),
                        c: c.0.clone(),
                        f: f.0.clone(),
                    },
                };
                (b.index, state)
            })
            .collect();
        out.sort_by_key(|e| e.0);
        out.into_iter().map(|e| e.1).collect()
    }

    /// Total particles, parked ones included.
    pub fn particle_count(&mut self) -> usize {
        let mut q = self.world.query::<(&Position, Option<&Parked>)>();
        q.iter(&self.world)
            .map(|(x, p)| x.0.len() + p.map_or(0, |p| p.len()))
            .sum()
    }

    /// The particles the stages visit: all but the parked ones.
    pub fn awake_particle_count(&mut self) -> usize {
        let mut q = self.world.query::<&Position>();
        q.iter(&self.world).map(|x| x.0.len()).sum()
    }

    /// Whether resting powder is set aside between steps ([`rest`]): forward runs only.
    pub fn rests(&self) -> bool {
        self.rest.is_some()
    }

    /// Particle-substeps simulated by [`Simulation::step`] so far: each step's awake particles
    /// times its substeps.
    pub fn particle_substeps(&self) -> f64 {
        self.particle_substeps
    }

    /// The work of `steps` steps at the current substeps, particles and grid (what `simulate`
    /// prints before it starts).
    pub fn work(&mut self, steps: usize) -> crate::scene::WorkEstimate {
        crate::scene::WorkEstimate {
            particles: self.particle_count(),
            nodes: self
                .world
                .resource::<crate::components::Grid>()
                .node_count(),
            substeps: self.params().substeps,
            steps,
        }
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

/// Prints, before a study starts, the work of `rollouts` forward rollouts' worth of `scene` at
/// its own horizon: what `simulate` prints for one run, and the total at the reference rate.
/// A rollout of a skill scene runs to a horizon that depends on Θ, so this is about the size.
pub fn announce_work(scene: &std::path::Path, rollouts: f64) -> anyhow::Result<()> {
    let mut sim = Simulation::from_file(scene, &SimOptions::default())?;
    let one = sim.work(sim.horizon);
    let all = one.times(rollouts);
    eprintln!(
        "work: {}: {rollouts:.0} forward rollouts' worth of {}; in all {:.2e} particle-substeps, about {} at that rate",
        scene.display(),
        one.describe(),
        all.particle_substeps(),
        all.duration()
    );
    Ok(())
}
