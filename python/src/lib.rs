//! The Python bindings of powderlab: `powderlab._powderlab`, re-exported by the `powderlab`
//! package (`python/powderlab/__init__.py`).
//!
//! The bindings are thin: every number comes from the Rust library
//! ([`powderlab::rollout`], [`powderlab::sim::Simulation`]), so the same scene and Θ give the
//! same bits in Python as in Rust. The GIL is released while the simulator runs, so Python
//! threads and Ray workers do not serialise on it. Arrays come back as float64 numpy arrays
//! that own the buffer the simulator's state was copied into (one copy out of the world, none
//! after).

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray2};
use powderlab::components::{Body, Position, Velocity};
use powderlab::error::SceneError as RsSceneError;
use powderlab::rollout::{self as rs_rollout, Request};
use powderlab::scene::{ColliderKindSpec, ControlSpec, Scene as RsScene};
use powderlab::sim::Simulation as RsSimulation;
use powderlab::skills::Theta;
use pyo3::create_exception;
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};
use std::collections::BTreeMap;
use std::path::PathBuf;

mod policy;
mod simulation;

create_exception!(
    _powderlab,
    SceneError,
    PyValueError,
    "A scene the checks refuse. The message is one line: file, line, column, field, value and what to do."
);
create_exception!(
    _powderlab,
    SimulationError,
    PyRuntimeError,
    "A run that stopped: a non-finite value (with the stage, particle and field), or an adjoint failure."
);

/// Maps the library's errors onto the package's exceptions, keeping the one-line message.
pub(crate) fn to_py(e: anyhow::Error) -> PyErr {
    match e.downcast_ref::<RsSceneError>() {
        Some(se) => SceneError::new_err(se.to_string()),
        None => SimulationError::new_err(format!("{e:#}")),
    }
}

pub(crate) fn scene_err(e: RsSceneError) -> PyErr {
    SceneError::new_err(e.to_string())
}

/// `threads` as the library takes it: `None` for all cores, a positive count otherwise.
pub(crate) fn threads_arg(threads: Option<usize>) -> PyResult<Option<usize>> {
    match threads {
        Some(0) => Err(PyValueError::new_err(
            "threads = 0: expected a positive number of worker threads, or None for all cores",
        )),
        t => Ok(t),
    }
}

/// An (N, 3) float64 array that owns `flat` (3N values, row-major).
pub(crate) fn rows3<'py>(py: Python<'py>, flat: Vec<f64>) -> Bound<'py, PyArray2<f64>> {
    let n = flat.len() / 3;
    Array2::from_shape_vec((n, 3), flat)
        .expect("three values per row")
        .into_pyarray(py)
}

/// An (N, 3) array of vectors.
pub(crate) fn vec3s<'py>(py: Python<'py>, v: &[glam::DVec3]) -> Bound<'py, PyArray2<f64>> {
    rows3(py, v.iter().flat_map(|x| x.to_array()).collect())
}

/// A scene: parsed, every field checked.
#[pyclass(module = "powderlab._powderlab", name = "Scene", frozen)]
#[derive(Clone)]
pub struct Scene {
    pub(crate) inner: RsScene,
}

#[pymethods]
impl Scene {
    /// Loads and checks a scene file (RON). Raises SceneError naming the file, line, column
    /// and field of the first problem.
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Scene> {
        RsScene::load(&path)
            .map(|inner| Scene { inner })
            .map_err(scene_err)
    }

    /// The shipped scene `name` (see `powderlab.scenes()`), compiled into the package so that it
    /// loads from any working folder. Raises SceneError listing the shipped names otherwise.
    #[staticmethod]
    fn shipped(name: &str) -> PyResult<Scene> {
        RsScene::shipped(name)
            .map(|inner| Scene { inner })
            .map_err(scene_err)
    }

    /// A scene from a path, or from a shipped scene's name when no such file exists and the
    /// argument is a bare name (no folder, no `.ron`): what the environments' `scene` takes.
    #[staticmethod]
    fn resolve(path: PathBuf) -> PyResult<Scene> {
        RsScene::resolve(&path)
            .map(|inner| Scene { inner })
            .map_err(scene_err)
    }

    /// Parses a scene from RON text; `name` stands for the file name in messages.
    #[staticmethod]
    #[pyo3(signature = (text, name = "<string>"))]
    fn from_str(text: &str, name: &str) -> PyResult<Scene> {
        RsScene::parse(text, name.as_ref())
            .map(|inner| Scene { inner })
            .map_err(scene_err)
    }

    /// The scene as RON text (every field, defaults written out); `Scene.from_str` reads it
    /// back to an equal scene.
    fn to_ron(&self) -> PyResult<String> {
        ron::ser::to_string_pretty(&self.inner, ron::ser::PrettyConfig::default())
            .map_err(|e| PyValueError::new_err(format!("cannot write the scene as RON: {e}")))
    }

    /// The file the scene came from.
    #[getter]
    fn path(&self) -> String {
        self.inner.path.display().to_string()
    }

    /// Global step length (s).
    #[getter]
    fn dt(&self) -> f64 {
        self.inner.simulation.dt
    }

    /// The grid's box (m): (lower corner, upper corner).
    #[getter]
    fn domain(&self) -> ([f64; 3], [f64; 3]) {
        let (lo, hi) = self.inner.domain();
        (lo.to_array(), hi.to_array())
    }

    /// Body names, in scene order.
    #[getter]
    fn bodies(&self) -> Vec<String> {
        self.inner.bodies.iter().map(|b| b.name.clone()).collect()
    }

    /// Tool names (kinematic colliders), in scene order.
    #[getter]
    fn tools(&self) -> Vec<String> {
        self.inner
            .colliders
            .iter()
            .filter(|c| c.kind == ColliderKindSpec::Tool)
            .map(|c| c.name.clone())
            .collect()
    }

    /// Θ of the skill-driven tool, or None when the scene has none.
    #[getter]
    fn theta(&self) -> Option<Vec<f64>> {
        let i = rs_rollout::skill_tool(&self.inner).ok()?;
        match &self.inner.colliders[i].control {
            Some(ControlSpec::Skill(sk)) => Some(sk.theta.to_vec()),
            _ => None,
        }
    }

    /// The task as (target cup, amount, unit) with unit "g" or "particles"; None without one.
    #[getter]
    fn task(&self) -> Option<(String, f64, &'static str)> {
        self.inner.task.as_ref().map(|t| match t.target_value {
            powderlab::scene::TargetValue::Grams(g) => (t.target.clone(), g, "g"),
            powderlab::scene::TargetValue::Particles(n) => (t.target.clone(), n, "particles"),
        })
    }

    /// A copy with the skill tool's Θ replaced (five values in [-1, 1]).
    fn with_theta(&self, theta: [f64; 5]) -> PyResult<Scene> {
        let req = Request {
            theta: Some(Theta(theta)),
            ..Default::default()
        };
        let inner = rs_rollout::edited(&self.inner, &req).map_err(scene_err)?;
        Ok(Scene { inner })
    }

    /// A copy with parameters set by name: a material parameter (`friction_deg`,
    /// `youngs_modulus`, `poisson_ratio`, `density`, or `MATERIAL.PARAM` where several
    /// materials have it) or a collider's friction (`COLLIDER.friction`). The copy is checked.
    fn with_params(&self, params: BTreeMap<String, f64>) -> PyResult<Scene> {
        let names: Vec<String> = params.keys().cloned().collect();
        // The calibration's parameter names; its messages speak of the --fit flag.
        let fit =
            powderlab::lab::calibrate::params::parse(&self.inner, &names, &[]).map_err(|e| {
                SceneError::new_err(format!(
                    "{}: {}",
                    self.inner.path.display(),
                    e.strip_prefix("--fit ").unwrap_or(&e)
                ))
            })?;
        let mut inner = self.inner.clone();
        for (p, name) in fit.iter().zip(&names) {
            p.apply(&mut inner, params[name]);
        }
        inner.validate().map_err(scene_err)?;
        Ok(Scene { inner })
    }

    /// A copy whose tool (by name, or the only one) follows the given per-step displacements:
    /// an (T, 6) array of translation (m) and rotation vector (rad) per global step.
    #[pyo3(signature = (actions, tool = None))]
    fn with_actions(&self, actions: Vec<[f64; 6]>, tool: Option<String>) -> PyResult<Scene> {
        let req = Request {
            controls: Some((tool, actions)),
            ..Default::default()
        };
        let inner = rs_rollout::edited(&self.inner, &req).map_err(scene_err)?;
        Ok(Scene { inner })
    }

    /// Pickling (Ray sends scenes to its workers this way): the RON text and the path.
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        let ctor = py.get_type::<Scene>().getattr("_from_pickle")?;
        let args = (self.to_ron()?, self.path());
        (ctor, args).into_pyobject(py)
    }

    #[staticmethod]
    fn _from_pickle(text: &str, path: &str) -> PyResult<Scene> {
        Scene::from_str(text, path)
    }

    /// Equal fields (the text the scenes were parsed from, kept for messages, may differ).
    fn __eq__(&self, other: &Scene) -> bool {
        let strip = |s: &RsScene| RsScene {
            source: String::new(),
            ..s.clone()
        };
        strip(&self.inner) == strip(&other.inner)
    }

    fn __repr__(&self) -> String {
        format!(
            "Scene('{}': {} bodies, {} colliders, dt {} s)",
            self.inner.path.display(),
            self.inner.bodies.len(),
            self.inner.colliders.len(),
            self.inner.simulation.dt
        )
    }
}

/// Particle columns of every body in scene order, concatenated: positions or velocities.
pub(crate) fn particle_rows(sim: &mut RsSimulation, velocities: bool) -> Vec<f64> {
    let mut out: Vec<(usize, Vec<f64>)> = if velocities {
        let mut q = sim.world.query::<(&Body, &Velocity)>();
        q.iter(&sim.world)
            .map(|(b, v)| (b.index, v.0.iter().flat_map(|x| x.to_array()).collect()))
            .collect()
    } else {
        let mut q = sim.world.query::<(&Body, &Position)>();
        q.iter(&sim.world)
            .map(|(b, x)| (b.index, x.0.iter().flat_map(|x| x.to_array()).collect()))
            .collect()
    };
    out.sort_by_key(|e| e.0);
    out.into_iter().flat_map(|e| e.1).collect()
}

/// Runs one rollout: the scene at Θ (or with a tool's per-step controls), over its horizon
/// (or `steps`), scored by the scene's loss and task.
///
/// Returns a dict with `loss`, `indicator` (target − transported, in the task's unit),
/// `transported`, `steps`, `substeps`, and the final `positions` and `velocities` ((N, 3)
/// float64, bodies in scene order). With `grad=True` also `grad_theta` (∂L/∂Θ, shape (5,),
/// when the scene has a skill tool), `grad_controls` ({tool: (T, 6)}), `grad_material`
/// ({body: {parameter: value}}), `grad_x0` and `grad_v0` ((N, 3)), `grad_friction`
/// ({collider: value}) and `grad_gravity` ((3,)). The GIL is released while it runs.
#[pyfunction]
#[pyo3(signature = (scene, theta = None, controls = None, tool = None, loss = true, grad = false, steps = None, threads = None, tape_budget_mb = None))]
#[allow(clippy::too_many_arguments)]
fn rollout<'py>(
    py: Python<'py>,
    scene: &Scene,
    theta: Option<[f64; 5]>,
    controls: Option<Vec<[f64; 6]>>,
    tool: Option<String>,
    loss: bool,
    grad: bool,
    steps: Option<usize>,
    threads: Option<usize>,
    tape_budget_mb: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    let req = Request {
        theta: theta.map(Theta),
        controls: controls.map(|c| (tool, c)),
        steps,
        loss,
        grad,
        threads: threads_arg(threads)?,
        tape_budget: tape_budget_mb.map_or(rs_rollout::DEFAULT_TAPE_BUDGET, |mb| mb << 20),
    };
    let owned = scene.inner.clone();
    let r = py
        .detach(move || rs_rollout::run(&owned, &req))
        .map_err(to_py)?;
    let d = PyDict::new(py);
    d.set_item("loss", r.loss)?;
    d.set_item("indicator", r.indicator)?;
    d.set_item("transported", r.transported)?;
    d.set_item("steps", r.steps)?;
    d.set_item("substeps", r.substeps)?;
    let xs: Vec<glam::DVec3> = r.bodies.iter().flat_map(|b| b.x.iter().copied()).collect();
    let vs: Vec<glam::DVec3> = r.bodies.iter().flat_map(|b| b.v.iter().copied()).collect();
    d.set_item("positions", vec3s(py, &xs))?;
    d.set_item("velocities", vec3s(py, &vs))?;
    if let Some(g) = &r.gradients {
        if let Some((_, gt)) = r.skill {
            d.set_item("grad_theta", gt.to_vec().into_pyarray(py))?;
        }
        let controls = PyDict::new(py);
        for (name, gu) in &g.controls {
            let flat: Vec<f64> = gu.iter().flatten().copied().collect();
            let a = Array2::from_shape_vec((gu.len(), 6), flat).expect("six per step");
            controls.set_item(name, a.into_pyarray(py))?;
        }
        d.set_item("grad_controls", controls)?;
        let material = PyDict::new(py);
        for (i, b) in r.bodies.iter().enumerate() {
            let per = PyDict::new(py);
            for (k, p) in g.material_params[i].iter().enumerate() {
                per.set_item(p.name, g.material[i].0[k])?;
            }
            material.set_item(&b.name, per)?;
        }
        d.set_item("grad_material", material)?;
        let x0: Vec<glam::DVec3> = g.x0.iter().flatten().copied().collect();
        let v0: Vec<glam::DVec3> = g.v0.iter().flatten().copied().collect();
        d.set_item("grad_x0", vec3s(py, &x0))?;
        d.set_item("grad_v0", vec3s(py, &v0))?;
        let friction = PyDict::new(py);
        for (name, v) in &g.friction {
            friction.set_item(name, *v)?;
        }
        d.set_item("grad_friction", friction)?;
        d.set_item(
            "grad_gravity",
            g.gravity.to_array().to_vec().into_pyarray(py),
        )?;
    }
    Ok(d)
}

/// The names of the scenes shipped with the package, for `Scene.shipped`.
#[pyfunction]
fn scenes() -> Vec<&'static str> {
    powderlab::scene::shipped::names().collect()
}

/// The version of the Rust library the bindings were built from.
#[pyfunction]
fn version() -> &'static str {
    env!("CARGO_PKG_VERSION")
}

#[pymodule]
fn _powderlab(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Scene>()?;
    m.add_class::<simulation::Simulation>()?;
    m.add_function(wrap_pyfunction!(rollout, m)?)?;
    m.add_function(wrap_pyfunction!(version, m)?)?;
    m.add_function(wrap_pyfunction!(scenes, m)?)?;
    m.add_function(wrap_pyfunction!(policy::policy_dataset_config, m)?)?;
    m.add_function(wrap_pyfunction!(policy::policy_dataset_claim, m)?)?;
    m.add_function(wrap_pyfunction!(policy::policy_dataset_scene, m)?)?;
    m.add_function(wrap_pyfunction!(policy::policy_dataset_scene_file, m)?)?;
    m.add_function(wrap_pyfunction!(policy::policy_dataset_write, m)?)?;
    m.add("SceneError", m.py().get_type::<SceneError>())?;
    m.add("SimulationError", m.py().get_type::<SimulationError>())?;
    Ok(())
}
