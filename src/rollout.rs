//! One rollout of a scene, as an embedder asks for it (the Python bindings and their Ray
//! workers, or a Rust program): the scene at new skill parameters Θ, or with a tool's per-step
//! controls replaced, run over its horizon, scored by the scene's loss and task, with the
//! adjoint's gradients when asked for.
//!
//! The numbers are those of every other path through the simulator: the same scene and Θ give
//! the same bits as [`Problem::evaluate`](crate::lab::optim::problem::Problem) and `powderlab
//! gradcheck`'s adjoint column, for any thread count (`tests/rollout_matches_the_optimiser.rs`).

use crate::adjoint::loss::scene_loss;
use crate::adjoint::tape::{gradient, Gradients, Tape};
use crate::components::BodyState;
use crate::error::{FieldError, SceneError};
use crate::scene::{ColliderKindSpec, ControlSpec, Scene};
use crate::sim::{SimOptions, Simulation};

/// The tape's memory budget when the caller names none: 1 GiB, within which the default
/// scene's backward pass keeps every checkpoint it wants.
pub const DEFAULT_TAPE_BUDGET: usize = 1 << 30;

/// What to run.
#[derive(Clone, Debug)]
pub struct Request {
    /// Θ of the scene's skill-driven tool (it must have exactly one), replacing the scene's.
    pub theta: Option<[f64; 5]>,
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

/// Runs one rollout of `scene` as `req` asks. Errors are the scene's checks
/// ([`SceneError`], with file, line, column and field) or the simulation's
/// ([`SimError`](crate::error::SimError), [`AdjointError`](crate::error::AdjointError)).
pub fn run(scene: &Scene, req: &Request) -> anyhow::Result<Rollout> {
    let scene = edited(scene, req)?;
    let opts = SimOptions {
        threads: req.threads,
        ..Default::default()
    };
    let mut sim = Simulation::new(&scene, &opts)?;
    let steps = req.steps.unwrap_or(sim.horizon);
    let loss_fn = scene_loss(&scene);
    let (loss, gradients) = if req.grad {
        let g = gradient(&mut sim, steps, &loss_fn, Tape::Budget(req.tape_budget))?;
        (Some(g.loss), Some(g))
    } else {
        sim.run(steps, |_| {})?;
        let loss = req.loss.then(|| {
            let xs: Vec<_> = sim.body_states().into_iter().map(|b| b.x).collect();
            loss_fn.eval(&xs).0
        });
        (loss, None)
    };
    let skill = gradients.as_ref().and_then(|g| {
        let i = skill_tool(&scene).ok()?;
        let tool = &scene.colliders[i];
        let g_u = g.tool_controls(&tool.name)?;
        Some((
            tool.name.clone(),
            tool.skill_gradient(scene.simulation.dt, g_u)?,
        ))
    });
    let (transported, indicator) = match &scene.task {
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
        bodies: sim.body_states(),
        gradients,
        skill,
    })
}
