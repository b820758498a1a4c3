//! One rollout of a scene, as an embedder asks for it (the Python bindings and their Ray
//! workers, or a Rust program): the scene at new skill parameters Θ, or with a tool's per-step
//! controls replaced, run over its horizon, scored by the scene's loss and task, with the
//! adjoint's gradients when asked for.
//!
//! It is the one rollout path: [`run`] is [`Prepared::run`] on a scene built for one rollout,
//! and the optimisers hold a [`Prepared`] (the scene checked and built once) and call the same
//! [`Prepared::run`] for every Θ, with the [`Variant`]s their methods need (another packing of
//! the powder, carry terms, edited controls). The same scene and Θ give the same bits through
//! every caller, for any thread count (`tests/rollout_matches_the_optimiser.rs`), and as
//! `powderlab gradcheck`'s adjoint column.

use crate::adjoint::loss::{scene_loss, Carry};
use crate::adjoint::tape::{gradient_with, Gradients, Loss, Tape, Term};
use crate::components::BodyState;
use crate::error::{FieldError, SceneError};
use crate::scene::{ColliderKindSpec, ControlSpec, Scene};
use crate::sim::{Build, SimOptions, Simulation};
use crate::skills::Theta;
use std::time::Instant;

/// The tape's memory budget when the caller names none: 1 GiB, within which the default
/// scene's backward pass keeps every checkpoint it wants.
pub const DEFAULT_TAPE_BUDGET: usize = 1 << 30;

/// What to run.
#[derive(Clone, Debug)]
pub struct Request {
    /// Θ of the scene's skill-driven tool (it must have exactly one), replacing the scene's.
    pub theta: Option<Theta>,
    /// One displacement per global step (translation in m, rotation vector in rad) replacing a
    /// tool's control: the tool's name, or `None` for the scene's only tool.
    pub controls: Option<(Option<String>, Vec<[f64; 6]>)>,
    /// Global steps to run (default: the scene's horizon).
    pub steps: Option<usize>,
    /// Evaluate the scene's loss on the final positions (implied by `grad`).
    pub loss: bool,
    /// Run the backward pass.
    pub grad: bool,
    /// Worker threads (default: rayon's, all cores).
    pub threads: Option<usize>,
    /// Bytes the backward pass's tape may hold.
    pub tape_budget: usize,
}

impl Default for Request {
    fn default() -> Self {
        Request {
            theta: None,
            controls: None,
            steps: None,
            loss: true,
            grad: false,
            threads: None,
            tape_budget: DEFAULT_TAPE_BUDGET,
        }
    }
}

/// What one rollout gives.
#[derive(Clone, Debug)]
pub struct Rollout {
    /// The scene's loss on the final positions (`None` when not asked for).
    pub loss: Option<f64>,
    /// Powder in the task's target cup at the end, in the task's unit; `None` without a task.
    pub transported: Option<f64>,
    /// `target − transported` (its absolute value is the dose error); `None` without a task.
    pub indicator: Option<f64>,
    /// Global steps run.
    pub steps: usize,
    /// Substeps per step (the stability guard's choice).
    pub substeps: usize,
    /// Final particle state per body, in scene order.
    pub bodies: Vec<BodyState>,
    /// Every gradient of the loss, when asked for.
    pub gradients: Option<Gradients>,
    /// `∂L/∂Θ` of the skill-driven tool, by name, when the gradient was asked for and the
    /// scene has one.
    pub skill: Option<(String, [f64; 5])>,
    /// With [`Variant::terms_only`], the value of the terms the gradient is of.
    pub terms: Option<f64>,
    /// Particles of the rollout.
    pub particles: usize,
    /// Seconds the rollout took: the world's build, the simulation, the backward pass.
    pub wall_s: f64,
}

/// An edit of a skill's per-step controls, given them and the steps of each phase.
pub type ControlEdit<'a> = &'a dyn Fn(&mut Vec<[f64; 6]>, [usize; 6]);

/// How a rollout departs from the scene's own beyond what a [`Request`] sets: what the lab's
/// methods vary. The default departs in nothing.
#[derive(Clone, Default)]
pub struct Variant<'a> {
    /// Another packing of the same powder: every particle's start moved by `frac` of its
    /// body's particle spacing times a standard normal draw per axis, from a generator seeded
    /// with `seed` (bodies in scene order, particles in order, so it does not depend on the
    /// threads); `frac = 0` is the scene's own packing, bit for bit. The particle-collision
    /// stage projects a particle moved into a wall back out at the first substep.
    pub repack: Option<(f64, u64)>,
    /// Terms added to the objective the gradient is of (the carried mass at given steps).
    pub terms: Vec<Carry>,
    /// The gradient is of `terms` alone; the scene's loss is still evaluated and returned.
    pub terms_only: bool,
    /// Edits the skill's per-step controls (given them and the steps of each phase) before the
    /// world is built: residual controls on top of the skill.
    pub edit: Option<ControlEdit<'a>>,
    /// Runs in the caller's rayon pool (a rollout among parallel ones) instead of its own.
    pub shared_pool: bool,
}

/// A scene checked and built once (its particle fills and container contact tables), for many
/// rollouts that change the skill's Θ, a tool's controls or the [`Variant`].
#[derive(Clone, Debug)]
pub struct Prepared {
    /// Read through [`Prepared::scene`]: the build is of this scene, so it cannot change alone.
    scene: Scene,
    /// The scene's loss.
    loss: Loss,
    build: Build,
}

/// The index of the scene's one skill-driven tool.
pub fn skill_tool(scene: &Scene) -> Result<usize, SceneError> {
    let tools: Vec<usize> = scene
        .colliders
        .iter()
        .enumerate()
        .filter(|(_, c)| matches!(c.control, Some(ControlSpec::Skill(_))))
        .map(|(i, _)| i)
        .collect();
    match tools.as_slice() {
        [t] => Ok(*t),
        [] => Err(scene.field_error(FieldError::new(
            "colliders",
            "no tool with a Skill control",
            "exactly one tool with `control: Skill((...))`: Θ sets its skill parameters",
        ))),
        _ => Err(scene.field_error(FieldError::new(
            format!("colliders[{}].control", tools[1]),
            "a second Skill control",
            "exactly one tool with `control: Skill((...))`",
        ))),
    }
}

/// The index of the tool named `name`, or of the scene's only tool.
pub fn tool_index(scene: &Scene, name: Option<&str>) -> Result<usize, SceneError> {
    let tools: Vec<(usize, &str)> = scene
        .colliders
        .iter()
        .enumerate()
        .filter(|(_, c)| c.kind == ColliderKindSpec::Tool)
        .map(|(i, c)| (i, c.name.as_str()))
        .collect();
    let names: Vec<&str> = tools.iter().map(|t| t.1).collect();
    match name {
        Some(n) => tools.iter().find(|t| t.1 == n).map(|t| t.0).ok_or_else(|| {
            scene.field_error(FieldError::new(
                "colliders",
                format!("no tool named '{n}'"),
                format!("one of the scene's tools {names:?}"),
            ))
        }),
        None => match tools.as_slice() {
            [(i, _)] => Ok(*i),
            _ => Err(scene.field_error(FieldError::new(
                "colliders",
                format!("{} tools", tools.len()),
                format!("name the tool whose controls these are, one of {names:?}"),
            ))),
        },
    }
}

/// The scene with Θ and the controls of `req` written into it, checked as a scene file is (a
/// Θ outside [−1, 1]⁵ is refused, naming the component, not extrapolated).
pub fn edited(scene: &Scene, req: &Request) -> Result<Scene, SceneError> {
    let mut s = scene.clone();
    if let Some(theta) = req.theta {
        let i = skill_tool(scene)?;
        if let Some(ControlSpec::Skill(sk)) = &mut s.colliders[i].control {
            sk.theta = theta;
        }
    }
    if let Some((name, controls)) = &req.controls {
        let i = tool_index(scene, name.as_deref())?;
        s.colliders[i].control = Some(ControlSpec::Actions(controls.clone()));
    }
    if req.theta.is_some() || req.controls.is_some() {
        s.validate()?;
    }
    Ok(s)
}

/// Runs one rollout of `scene` as `req` asks: [`Prepared::run`] on the scene with Θ and the
/// controls written in and checked as a scene file is. Errors are the scene's checks
/// ([`SceneError`], with file, line, column and field) or the simulation's
/// ([`SimError`](crate::error::SimError), [`AdjointError`](crate::error::AdjointError)).
pub fn run(scene: &Scene, req: &Request) -> anyhow::Result<Rollout> {
    let scene = edited(scene, req)?;
    let req = Request {
        theta: None,
        controls: None,
        ..req.clone()
    };
    Prepared::new(scene)?.run(&req, &Variant::default())
}

impl Prepared {
    /// The scene, as checked and built.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The scene's loss.
    pub fn loss(&self) -> &Loss {
        &self.loss
    }

    /// Checks and builds `scene`.
    pub fn new(scene: Scene) -> Result<Prepared, SceneError> {
        Ok(Prepared {
            build: Build::new(&scene)?,
            loss: scene_loss(&scene),
            scene,
        })
    }

    /// The same scene with its bodies starting from `states` (see [`Build::with_start`]): a
    /// planner's next scoop from the powder the last one left.
    pub fn with_start(mut self, states: &[BodyState]) -> anyhow::Result<Prepared> {
        self.build = self.build.with_start(&self.scene, states)?;
        Ok(self)
    }

    /// The powder's particle positions before the first step, over every body.
    pub fn initial_positions(&self) -> Vec<glam::DVec3> {
        self.build
            .prepared
            .bodies
            .iter()
            .flat_map(|b| b.x.iter().copied())
            .collect()
    }

    /// The scene with the skill-driven tool's Θ replaced.
    pub fn scene_at(&self, theta: Theta) -> Result<Scene, SceneError> {
        let mut s = self.scene.clone();
        let i = skill_tool(&s)?;
        if let Some(ControlSpec::Skill(sk)) = &mut s.colliders[i].control {
            sk.theta = theta;
        }
        Ok(s)
    }

    /// The simulation of the rollout `req` and `v` ask for, at step 0, built from the scene
    /// built once: only the edited tool's controls, and the start under a repacking, are new.
    /// A Θ outside [−1, 1]⁵ is refused, naming the component, not extrapolated.
    pub fn simulation(&self, req: &Request, v: &Variant) -> anyhow::Result<Simulation> {
        let mut scene = self.scene.clone();
        let mut build = None;
        if let Some(theta) = req.theta {
            scene = self.scene_at(theta)?;
            let i = skill_tool(&scene)?;
            let tool = &scene.colliders[i];
            let Some(ControlSpec::Skill(sk)) = &tool.control else {
                unreachable!("skill_tool found a Skill control")
            };
            sk.validate().map_err(|e| {
                anyhow::anyhow!(
                    "Θ = {theta:?}: {} = {} is not {}; clamp Θ to [−1, 1]⁵",
                    e.field,
                    e.value,
                    e.expected
                )
            })?;
            let (mut controls, phases) = sk.controls(scene.simulation.dt, Scene::tool_bottom(tool));
            if let Some(edit) = v.edit {
                edit(&mut controls, phases);
            }
            build = Some(self.build.with_controls(&scene, i, controls)?);
        } else if v.edit.is_some() {
            anyhow::bail!("edited controls need a Θ: they edit the skill's controls");
        }
        if let Some((name, controls)) = &req.controls {
            let i = tool_index(&scene, name.as_deref())?;
            scene.colliders[i].control = Some(ControlSpec::Actions(controls.clone()));
            let b = build.as_ref().unwrap_or(&self.build);
            build = Some(b.with_controls(&scene, i, controls.clone())?);
        }
        let opts = SimOptions {
            threads: req.threads,
            shared_pool: v.shared_pool,
            ..Default::default()
        };
        let mut sim = build
            .as_ref()
            .unwrap_or(&self.build)
            .simulation(scene, &opts)?;
        if let Some((frac, seed)) = v.repack.filter(|(frac, _)| *frac != 0.0) {
            self.repack(&mut sim, frac, seed);
        }
        Ok(sim)
    }

    /// Moves every particle's start as [`Variant::repack`] says.
    fn repack(&self, sim: &mut Simulation, frac: f64, seed: u64) {
        let spacing: Vec<f64> = self
            .scene
            .bodies
            .iter()
            .map(|b| self.scene.particle_spacing(b))
            .collect();
        let mut rng = crate::util::SplitMix64(seed);
        let mut q = sim
            .world
            .query::<(&crate::components::Body, &mut crate::components::Position)>();
        let mut bodies: Vec<_> = q.iter_mut(&mut sim.world).collect();
        bodies.sort_by_key(|(b, _)| b.index);
        for (b, mut x) in bodies {
            let h = frac * spacing[b.index];
            for p in x.0.iter_mut() {
                *p += glam::DVec3::new(rng.normal(), rng.normal(), rng.normal()) * h;
            }
        }
    }

    /// Runs one rollout as `req` and `v` ask: the simulation over `req.steps` (default the
    /// horizon), the backward pass when `req.grad`, the loss and the task's score.
    pub fn run(&self, req: &Request, v: &Variant) -> anyhow::Result<Rollout> {
        let t0 = Instant::now();
        let mut sim = self.simulation(req, v)?;
        let steps = req.steps.unwrap_or(sim.horizon);
        // A rollout at Θ says which Θ failed; a scene's own rollout fails with the simulation's
        // error as it is.
        let at = |e: anyhow::Error| match req.theta {
            Some(theta) => e.context(format!("rollout at Θ = {theta:?}")),
            None => e,
        };
        let final_loss = |sim: &mut Simulation| {
            let xs: Vec<_> = sim.body_states().into_iter().map(|b| b.x).collect();
            self.loss.eval(&xs).0
        };
        let (loss, gradients, terms) = if req.grad || v.terms_only {
            let terms: Vec<Term> = v.terms.iter().cloned().map(Term::Carry).collect();
            let nothing;
            let objective = if v.terms_only {
                nothing = Loss::Linear(
                    sim.body_states()
                        .iter()
                        .map(|b| vec![glam::DVec3::ZERO; b.x.len()])
                        .collect(),
                );
                &nothing
            } else {
                &self.loss
            };
            let g = gradient_with(
                &mut sim,
                steps,
                objective,
                &terms,
                Tape::Budget(req.tape_budget),
            )
            .map_err(|e| at(e.into()))?;
            if v.terms_only {
                let terms = g.loss;
                (Some(final_loss(&mut sim)), Some(g), Some(terms))
            } else {
                (Some(g.loss), Some(g), None)
            }
        } else {
            sim.run(steps, |_| {}).map_err(|e| at(e.into()))?;
            (req.loss.then(|| final_loss(&mut sim)), None, None)
        };
        // The simulation's scene carries the rollout's Θ, which the skill's adjoint needs.
        let skill = gradients.as_ref().and_then(|g| {
            let i = skill_tool(&sim.scene).ok()?;
            let tool = &sim.scene.colliders[i];
            let g_u = g.tool_controls(&tool.name)?;
            Some((
                tool.name.clone(),
                tool.skill_gradient(sim.scene.simulation.dt, g_u)?,
            ))
        });
        let (transported, indicator) = match &self.scene.task {
            Some(task) => {
                let (t, i) = crate::metrics::task_indicator(&mut sim.world, task);
                (Some(t), Some(i))
            }
            None => (None, None),
        };
        Ok(Rollout {
            loss,
            transported,
            indicator,
            steps,
            substeps: sim.params().substeps,
            particles: sim.particle_count(),
            bodies: sim.body_states(),
            gradients,
            skill,
            terms,
            wall_s: t0.elapsed().as_secs_f64(),
        })
    }
}
