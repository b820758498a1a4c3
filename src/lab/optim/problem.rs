//! The optimisation problem: a scene whose tool follows a skill, and one rollout at given skill
//! parameters Θ (forward only, or with `∂L/∂Θ` from the adjoint pass).

use crate::adjoint::tape::{gradient_with, Carry, Loss, Tape, Term};
use crate::error::FieldError;
use crate::rollout::{Prepared, Request, Rollout, Variant};
use crate::scene::{ControlSpec, Scene, TargetValue};
use crate::sim::Simulation;
use crate::skills::Theta;
use anyhow::Context;

/// A scene prepared for optimisation: the skill problem over the core's one rollout path
/// ([`crate::rollout::Prepared`]), which it calls for every Θ.
#[derive(Clone, Debug)]
pub struct Problem {
    /// Index of the skill-driven tool in `scene.colliders`.
    pub tool: usize,
    /// Target amount of the indicator metric.
    pub target: TargetValue,
    /// Memory budget of one backward pass's tape (bytes).
    pub tape_budget: usize,
    /// The scene checked and built once, with its loss: every rollout reuses it with its own
    /// controls, and the problem's scene and loss are its ([`Problem::scene`], [`Problem::loss`]).
    prepared: Prepared,
}

/// What one rollout gives.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Outcome {
    pub loss: f64,
    /// `target − transported`, in the target's unit (particles or grams).
    pub indicator: f64,
    /// Powder inside the target cup at the end, in the target's unit.
    pub transported: f64,
    /// `∂L/∂Θ` (straight-through rounding of the phase step counts), when asked for.
    pub grad: Option<[f64; 5]>,
    /// Global steps of the rollout (depends on Θ).
    pub steps: usize,
    /// Substeps per step chosen by the stability guard.
    pub substeps: usize,
    /// Particles of the rollout's scene.
    #[serde(default)]
    pub particles: usize,
    /// Seconds the rollout took (simulation, and the backward pass when asked for).
    pub wall_s: f64,
}

impl Problem {
    /// Checks that the scene can be optimised: one tool with a `Skill` control and a `task`.
    pub fn new(scene: Scene, tape_budget: usize) -> Result<Problem, crate::error::SceneError> {
        let tool = crate::rollout::skill_tool(&scene)?;
        let Some(task) = scene.task.clone() else {
            return Err(scene.field_error(FieldError::new(
                "task",
                "None",
                "Some((target: \"cup\", target_value: Particles(n) | Grams(g))): the indicator needs a target",
            )));
        };
        let prepared = Prepared::new(scene)?;
        Ok(Problem {
            prepared,
            tool,
            target: task.target_value,
            tape_budget,
        })
    }

    /// The scene, as checked and built.
    pub fn scene(&self) -> &Scene {
        self.prepared.scene()
    }

    /// The scene's loss.
    pub fn loss(&self) -> &Loss {
        self.prepared.loss()
    }

    /// The same problem with its bodies starting from `states` (see
    /// [`Build::with_start`]): a planner's next scoop from the powder the last one left.
    pub fn with_start(
        mut self,
        states: &[crate::components::BodyState],
    ) -> anyhow::Result<Problem> {
        self.prepared = self.prepared.with_start(states)?;
        Ok(self)
    }

    /// The powder's particle positions before the first step, over every body.
    pub fn initial_positions(&self) -> Vec<glam::DVec3> {
        self.prepared.initial_positions()
    }

    /// The Θ written in the scene.
    pub fn scene_theta(&self) -> Theta {
        match &self.scene().colliders[self.tool].control {
            Some(ControlSpec::Skill(sk)) => sk.theta,
            _ => unreachable!("checked in Problem::new"),
        }
    }

    /// The scene with the tool's Θ replaced.
    pub fn scene_at(&self, theta: Theta) -> Scene {
        self.prepared
            .scene_at(theta)
            .expect("checked in Problem::new: one skill tool")
    }

    /// Builds the simulation of Θ from the scene built once: only the tool's controls are new.
    /// `shared_pool` runs it in the caller's rayon pool.
    pub fn simulation(&self, theta: Theta, shared_pool: bool) -> anyhow::Result<Simulation> {
        self.prepared.simulation(
            &self.request(theta, false),
            &Variant {
                shared_pool,
                ..Default::default()
            },
        )
    }

    /// [`Problem::simulation`] with the skill's per-step controls edited by `edit` (given them
    /// and the steps of each phase) before the world is built.
    pub fn simulation_with(
        &self,
        theta: Theta,
        shared_pool: bool,
        edit: impl Fn(&mut Vec<[f64; 6]>, [usize; 6]),
    ) -> anyhow::Result<Simulation> {
        self.prepared.simulation(
            &self.request(theta, false),
            &Variant {
                edit: Some(&edit),
                shared_pool,
                ..Default::default()
            },
        )
    }

    /// The core's request for a rollout at Θ, with the gradient if asked, on this problem's tape.
    fn request(&self, theta: Theta, grad: bool) -> Request {
        Request {
            theta: Some(theta),
            grad,
            tape_budget: self.tape_budget,
            ..Default::default()
        }
    }

    /// One rollout at Θ through the core's one path, with the variant `v`, as an [`Outcome`].
    fn rollout(&self, theta: Theta, grad: bool, v: &Variant) -> anyhow::Result<(Outcome, Rollout)> {
        let r = self.prepared.run(&self.request(theta, grad), v)?;
        let outcome = Outcome {
            loss: r.loss.expect("the loss is evaluated"),
            indicator: r.indicator.expect("checked in Problem::new: a task"),
            transported: r.transported.expect("checked in Problem::new: a task"),
            grad: r.skill.as_ref().map(|s| s.1),
            steps: r.steps,
            substeps: r.substeps,
            particles: r.particles,
            wall_s: r.wall_s,
        };
        Ok((outcome, r))
    }

    /// The residual of `knots` knots per channel on Θ's transport and pour
    /// ([`crate::lab::optim::refine`]).
    pub fn residual(&self, theta: Theta, knots: usize) -> crate::lab::optim::refine::Residual {
        let scene = self.scene_at(theta);
        let tool = &scene.colliders[self.tool];
        let Some(ControlSpec::Skill(sk)) = &tool.control else {
            unreachable!("checked in Problem::new")
        };
        let dt = scene.simulation.dt;
        let (_, phases) = sk.controls(dt, Scene::tool_bottom(tool));
        let (v, w) = (
            0.5 * sk.linear_speed * dt,
            0.5 * sk.angular_speed_deg.to_radians() * dt,
        );
        crate::lab::optim::refine::Residual {
            knots: knots.max(1),
            start: phases[0] + phases[1] + phases[2],
            len: (phases[3] + phases[4]).max(1),
            scale: [v, v, v, w, w, w],
        }
    }

    /// One rollout of Θ with the residual `w` added to its controls, and `∂L/∂w` if asked.
    pub fn evaluate_residual(
        &self,
        theta: Theta,
        residual: &crate::lab::optim::refine::Residual,
        w: &[f64],
        with_grad: bool,
        shared_pool: bool,
    ) -> anyhow::Result<(Outcome, Option<Vec<f64>>)> {
        let edit = |u: &mut Vec<[f64; 6]>, _: [usize; 6]| residual.apply(u, w);
        let v = Variant {
            edit: Some(&edit),
            shared_pool,
            ..Default::default()
        };
        let (o, r) = self.rollout(theta, with_grad, &v)?;
        let name = &self.scene().colliders[self.tool].name;
        let grad = r.gradients.as_ref().map(|g| {
            residual.apply_adj(g.tool_controls(name).expect("the skill tool has controls"))
        });
        Ok((Outcome { grad: None, ..o }, grad))
    }

    /// Θ's simulation with another packing of the same powder: every particle's start position
    /// moved by `frac` of its body's particle spacing times a standard normal draw per axis,
    /// from a generator seeded with `seed` (bodies in scene order, particles in order, so the
    /// packing does not depend on the threads). Seed B's smoothing perturbs the initial state
    /// as well as the actions; this is its initial-state noise. `frac = 0` is the scene's own
    /// packing, bit for bit. The particle-collision stage projects any particle moved into a
    /// wall back out at the first substep.
    pub fn simulation_repacked(
        &self,
        theta: Theta,
        shared_pool: bool,
        frac: f64,
        seed: u64,
    ) -> anyhow::Result<Simulation> {
        self.prepared.simulation(
            &self.request(theta, false),
            &Variant {
                repack: Some((frac, seed)),
                shared_pool,
                ..Default::default()
            },
        )
    }

    /// [`Problem::evaluate`] with the gradient, on another packing of the powder
    /// ([`Problem::simulation_repacked`]).
    pub fn evaluate_repacked(
        &self,
        theta: Theta,
        shared_pool: bool,
        frac: f64,
        seed: u64,
    ) -> anyhow::Result<Outcome> {
        let v = Variant {
            repack: Some((frac, seed)),
            shared_pool,
            ..Default::default()
        };
        Ok(self.rollout(theta, true, &v)?.0)
    }

    /// Transported amount and indicator of the simulation's current state.
    pub fn indicator(&self, sim: &mut Simulation) -> (f64, f64) {
        let task = self.scene().task.as_ref().expect("checked in Problem::new");
        crate::metrics::task_indicator(&mut sim.world, task)
    }

    /// Runs `sim` (a fresh simulation of this problem, at step 0) through its whole horizon
    /// with the backward pass of `loss`, and returns the loss and `∂loss/∂Θ` of the skill tool.
    /// `sim` is left at its final state.
    pub fn skill_gradient(
        &self,
        sim: &mut Simulation,
        loss: &Loss,
    ) -> Result<(f64, [f64; 5]), crate::error::AdjointError> {
        self.skill_gradient_with(sim, loss, &[])
    }

    /// [`Problem::skill_gradient`] of `loss` plus the carry `terms`.
    pub fn skill_gradient_with(
        &self,
        sim: &mut Simulation,
        loss: &Loss,
        terms: &[Carry],
    ) -> Result<(f64, [f64; 5]), crate::error::AdjointError> {
        let steps = sim.horizon;
        let terms: Vec<Term> = terms.iter().cloned().map(Term::Carry).collect();
        let g = gradient_with(sim, steps, loss, &terms, Tape::Budget(self.tape_budget))?;
        // The simulation's scene carries the rollout's Θ, which the skill's adjoint needs.
        let tool = &sim.scene.colliders[self.tool];
        let g_u = g
            .tool_controls(&tool.name)
            .expect("the skill tool has controls");
        let gt = tool
            .skill_gradient(sim.scene.simulation.dt, g_u)
            .expect("checked in Problem::new: the tool has a skill");
        Ok((g.loss, gt))
    }

    /// The carry terms of Θ's rollout (see [`Carry`]): the spoon's soft carried mass against
    /// the task's target mass at the end of the lift and at the end of the transport, each of
    /// weight 1, in a ball of the bowl's radius about the bowl's sphere and a ramp one particle
    /// spacing wide. `None` unless the tool is a spoon.
    pub fn carry_terms(&self, theta: Theta) -> Option<Vec<Carry>> {
        let scene = self.scene_at(theta);
        let tool = &scene.colliders[self.tool];
        let crate::math::sdf::Shape::Spoon { bowl_radius, .. } = tool.shape else {
            return None;
        };
        let Some(ControlSpec::Skill(sk)) = &tool.control else {
            return None;
        };
        let (_, phases) = sk.controls(scene.simulation.dt, Scene::tool_bottom(tool));
        let masses = scene.particle_masses();
        let target_mass = match self.target {
            TargetValue::Grams(g) => g * 1e-3,
            TargetValue::Particles(n) => n * masses.first().copied().unwrap_or(0.0),
        };
        let width = scene
            .bodies
            .iter()
            .map(|b| scene.particle_spacing(b))
            .fold(scene.simulation.dx, f64::min);
        // Phases: descend, scoop, lift, transport, pour, settle.
        let lift_end = phases[0] + phases[1] + phases[2];
        let transport_end = lift_end + phases[3];
        Some(
            [lift_end, transport_end]
                .into_iter()
                .map(|step| Carry {
                    tool: tool.name.clone(),
                    step,
                    centre: glam::DVec3::ZERO,
                    radius: bowl_radius,
                    width,
                    particle_mass: masses.clone(),
                    target_mass,
                    weight: 1.0,
                })
                .collect(),
        )
    }

    /// One rollout at Θ whose gradient is that of the carry terms ([`Problem::carry_terms`])
    /// alone; its `loss` is still the scene's loss (what every method is selected by), and the
    /// carry objective's value is returned beside it.
    pub fn evaluate_carry(
        &self,
        theta: Theta,
        shared_pool: bool,
    ) -> anyhow::Result<(Outcome, f64)> {
        let terms = self
            .carry_terms(theta)
            .context("the carry loss needs a spoon tool (a ball about its bowl)")?;
        let v = Variant {
            terms,
            terms_only: true,
            shared_pool,
            ..Default::default()
        };
        let (o, r) = self.rollout(theta, true, &v)?;
        Ok((o, r.terms.expect("terms_only gives the terms' value")))
    }

    /// One rollout at Θ (clamped to [−1, 1] by the caller), with the gradient if asked.
    pub fn evaluate(
        &self,
        theta: Theta,
        with_grad: bool,
        shared_pool: bool,
    ) -> anyhow::Result<Outcome> {
        let v = Variant {
            shared_pool,
            ..Default::default()
        };
        Ok(self.rollout(theta, with_grad, &v)?.0)
    }
}
