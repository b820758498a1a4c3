//! `powderlab.Simulation`: a running simulation stepped from Python, with per-step tool
//! controls, particle state as numpy arrays, PLY output and a Rerun recording.

use crate::{rows3, scene_err, threads_arg, to_py, Scene, SimulationError};
use numpy::{IntoPyArray, PyArray1, PyArray2};
use powderlab::adjoint::loss::scene_loss;
use powderlab::components::{Collider, ColliderKind, Control};
use powderlab::metrics::task_indicator;
use powderlab::scene::prepare::control_speed;
use powderlab::sim::{SimOptions, Simulation as RsSimulation};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;

/// A tool's speed limit: what the stability guard chose the substeps for.
struct ToolLimit {
    name: String,
    /// Largest point speed (m/s) of the scene's own controls.
    max_speed: f64,
    /// Bounding radius of its shape (m).
    radius: f64,
}

fn no_tool(tool: &str, limits: &[ToolLimit]) -> PyErr {
    let names: Vec<&str> = limits.iter().map(|l| l.name.as_str()).collect();
    PyValueError::new_err(format!(
        "'{tool}': the scene has no tool of that name; its tools are {names:?}"
    ))
}

/// A running simulation.
#[pyclass(module = "powderlab._powderlab", name = "Simulation")]
pub struct Simulation {
    sim: RsSimulation,
    limits: Vec<ToolLimit>,
    recorder: Option<powderlab::record::Recorder>,
}

impl Simulation {
    fn finish_recording_inner(&mut self) -> anyhow::Result<Option<PathBuf>> {
        if let Some(r) = self.recorder.take() {
            let path = r.path().to_path_buf();
            r.finish()?;
            return Ok(Some(path));
        }
        Ok(None)
    }
}

impl Drop for Simulation {
    fn drop(&mut self) {
        // A recording left open is still completed, so that no `.partial` file stays behind.
        let _ = self.finish_recording_inner();
    }
}

#[pymethods]
impl Simulation {
    /// Builds the simulation at the scene's start. `threads`: worker threads (None: all
    /// cores); the numbers do not depend on it.
    #[new]
    #[pyo3(signature = (scene, threads = None))]
    fn new(py: Python<'_>, scene: &Scene, threads: Option<usize>) -> PyResult<Simulation> {
        let opts = SimOptions::threads(threads_arg(threads)?);
        let owned = scene.inner.clone();
        let mut sim = py
            .detach(move || RsSimulation::new(&owned, &opts))
            .map_err(scene_err)?;
        let dt = sim.scene.simulation.dt;
        let mut q = sim.world.query::<(&Collider, &Control)>();
        let mut limits: Vec<(usize, ToolLimit)> = q
            .iter(&sim.world)
            .filter(|(c, _)| c.kind == ColliderKind::Tool)
            .map(|(c, u)| {
                let radius = c.shape.bounding_radius();
                let max_speed = u
                    .per_step
                    .iter()
                    .map(|u| control_speed(*u, dt, radius))
                    .fold(0.0, f64::max);
                (
                    c.index,
                    ToolLimit {
                        name: c.name.clone(),
                        max_speed,
                        radius,
                    },
                )
            })
            .collect();
        limits.sort_by_key(|l| l.0);
        Ok(Simulation {
            sim,
            limits: limits.into_iter().map(|l| l.1).collect(),
            recorder: None,
        })
    }

    /// Advances `n` global steps (each the scene's substeps). The GIL is released meanwhile.
    /// Raises SimulationError on a non-finite value, naming the stage, particle and field.
    #[pyo3(signature = (n = 1))]
    fn step(&mut self, py: Python<'_>, n: usize) -> PyResult<()> {
        let this = &mut *self;
        py.detach(move || -> anyhow::Result<()> {
            for _ in 0..n {
                this.sim.step()?;
                if let Some(r) = this.recorder.as_mut() {
                    r.frame(&mut this.sim.world)?;
                }
            }
            Ok(())
        })
        .map_err(to_py)
    }

    /// Global steps taken so far.
    #[getter]
    fn step_index(&self) -> usize {
        self.sim.clock().step
    }

    /// Simulated time (s).
    #[getter]
    fn time(&self) -> f64 {
        self.sim.clock().step as f64 * self.sim.params().dt
    }

    /// The scene's horizon in global steps (its controls' length, or `steps`).
    #[getter]
    fn horizon(&self) -> usize {
        self.sim.horizon
    }

    /// Substeps per global step (the stability guard's choice).
    #[getter]
    fn substeps(&self) -> usize {
        self.sim.params().substeps
    }

    /// Worker threads in use.
    #[getter]
    fn threads(&self) -> usize {
        self.sim.threads()
    }

    /// Particles of all bodies.
    #[getter]
    fn particle_count(&mut self) -> usize {
        self.sim.particle_count()
    }

    /// {body name: (start, stop)}: each body's rows in `positions()` and `velocities()`.
    fn body_ranges<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        let mut start = 0;
        for b in self.sim.body_states() {
            d.set_item(&b.name, (start, start + b.x.len()))?;
            start += b.x.len();
        }
        Ok(d)
    }

    /// Particle positions (m), shape (N, 3), float64, bodies in scene order.
    fn positions<'py>(&mut self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        rows3(py, crate::particle_rows(&mut self.sim, false))
    }

    /// Particle velocities (m/s), shape (N, 3), float64, bodies in scene order.
    fn velocities<'py>(&mut self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        rows3(py, crate::particle_rows(&mut self.sim, true))
    }

    /// The pose of collider `name`: (position (3,), quaternion (4,) as x, y, z, w).
    #[allow(clippy::type_complexity)]
    fn tool_pose<'py>(
        &mut self,
        py: Python<'py>,
        name: &str,
    ) -> PyResult<(Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>)> {
        let poses = self.sim.collider_poses();
        let Some((_, _, _, pose)) = poses.iter().find(|p| p.0 == name) else {
            let names: Vec<&str> = poses.iter().map(|p| p.0.as_str()).collect();
            return Err(PyValueError::new_err(format!(
                "tool_pose('{name}'): the scene has no collider of that name; it has {names:?}"
            )));
        };
        Ok((
            pose.translation.to_array().to_vec().into_pyarray(py),
            pose.rotation.to_array().to_vec().into_pyarray(py),
        ))
    }

    /// Sets the per-step control of tool `tool` from the current step on: one displacement
    /// (6,) (translation in m, rotation vector in rad, over one global step) or several (k, 6)
    /// for the next k steps. A control faster than the scene's own controls for that tool is
    /// refused: the stability guard chose the substeps for those.
    fn set_controls(&mut self, tool: &str, controls: Bound<'_, PyAny>) -> PyResult<()> {
        let rows: Vec<[f64; 6]> = match controls.extract::<[f64; 6]>() {
            Ok(u) => vec![u],
            Err(_) => controls.extract::<Vec<[f64; 6]>>().map_err(|_| {
                PyValueError::new_err(format!(
                    "set_controls('{tool}', ...): expected 6 numbers or k rows of 6 (translation m, rotation vector rad, per step)"
                ))
            })?,
        };
        let dt = self.sim.params().dt;
        let Some(limit) = self.limits.iter().find(|l| l.name == tool) else {
            return Err(no_tool(tool, &self.limits));
        };
        for (k, u) in rows.iter().enumerate() {
            if u.iter().any(|x| !x.is_finite()) {
                return Err(PyValueError::new_err(format!(
                    "set_controls('{tool}', ...): row {k} is {u:?}: expected finite values"
                )));
            }
            let speed = control_speed(*u, dt, limit.radius);
            // The guard's bound with a relative margin of round-off.
            if speed > limit.max_speed * (1.0 + 1e-9) {
                return Err(PyValueError::new_err(format!(
                    "set_controls('{tool}', ...): row {k} moves the tool at {speed:.4} m/s, faster than the {:.4} m/s of the scene's own controls that the substeps were chosen for; scale it down, or give the tool a faster control in the scene",
                    limit.max_speed
                )));
            }
        }
        let step = self.sim.clock().step;
        let mut q = self.sim.world.query::<(&Collider, &mut Control)>();
        for (c, mut control) in q.iter_mut(&mut self.sim.world) {
            if c.name == tool {
                let need = step + rows.len();
                if control.per_step.len() < need {
                    control.per_step.resize(need, [0.0; 6]);
                }
                control.per_step[step..need].copy_from_slice(&rows);
            }
        }
        Ok(())
    }

    /// What the scene's balance shows now (mg), or None in a scene without a balance: the
    /// reading a weighing controller closes its loop on (0.1 mg steps, noise, a settling lag).
    fn balance_reading(&mut self) -> Option<f64> {
        self.sim.balance_reading_g().map(|g| g * 1e3)
    }

    /// The step counts of the six phases of tool `tool`'s skill (descend, scoop, lift,
    /// transport, pour, settle) at the scene's Θ; an error for a tool without a skill.
    fn skill_phases(&self, tool: &str) -> PyResult<Vec<usize>> {
        let scene = &self.sim.scene;
        let Some(c) = scene.colliders.iter().find(|c| c.name == tool) else {
            return Err(no_tool(tool, &self.limits));
        };
        match &c.control {
            Some(powderlab::scene::ControlSpec::Skill(sk)) => Ok(sk
                .controls(scene.simulation.dt, powderlab::scene::Scene::tool_bottom(c))
                .1
                .to_vec()),
            _ => Err(PyValueError::new_err(format!(
                "skill_phases('{tool}'): the tool has no Skill control"
            ))),
        }
    }

    /// (largest point speed in m/s, bounding radius in m) of tool `tool`: the speed of the
    /// scene's own controls, which `set_controls` may not exceed, and the radius that turns a
    /// rotation into a point speed.
    fn tool_limit(&self, tool: &str) -> PyResult<(f64, f64)> {
        self.limits
            .iter()
            .find(|l| l.name == tool)
            .map(|l| (l.max_speed, l.radius))
            .ok_or_else(|| no_tool(tool, &self.limits))
    }

    /// The scene's score in the current state: `loss` (the scene's loss on the positions now)
    /// and, with a task, `transported`, `indicator` (target − transported) and `dose_error`
    /// (its absolute value), in the task's unit.
    fn score<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        let xs: Vec<_> = self.sim.body_states().into_iter().map(|b| b.x).collect();
        d.set_item("loss", scene_loss(&self.sim.scene).eval(&xs).0)?;
        if let Some(task) = self.sim.scene.task.clone() {
            let (t, i) = task_indicator(&mut self.sim.world, &task);
            d.set_item("transported", t)?;
            d.set_item("indicator", i)?;
            d.set_item("dose_error", i.abs())?;
        }
        Ok(d)
    }

    /// Writes every particle's position and velocity as a binary PLY point cloud (atomically).
    fn save_ply(&mut self, path: PathBuf) -> PyResult<()> {
        powderlab::ply::write_ply(&path, &self.sim.body_states()).map_err(|e| {
            PyValueError::new_err(format!(
                "{}: cannot write the PLY: {e}; check the folder exists and is writable",
                path.display()
            ))
        })
    }

    /// Starts recording to a Rerun file: the current state now and every later step (by the
    /// scene's `record.every`). The file appears complete at `finish_recording()` (or when the
    /// simulation is dropped); until then it is written beside it as `.partial`.
    fn record(&mut self, path: PathBuf) -> PyResult<()> {
        self.finish_recording_inner().map_err(to_py)?;
        let mut r = powderlab::record::Recorder::for_scene(
            &path,
            &mut self.sim.world,
            &self.sim.scene.clone(),
        )
        .map_err(|e| PyValueError::new_err(format!("{}: cannot record: {e:#}", path.display())))?;
        r.frame(&mut self.sim.world).map_err(to_py)?;
        self.recorder = Some(r);
        Ok(())
    }

    /// Completes the recording started by `record()`; returns its path (None if none).
    fn finish_recording(&mut self) -> PyResult<Option<String>> {
        self.finish_recording_inner()
            .map(|p| p.map(|p| p.display().to_string()))
            .map_err(|e| SimulationError::new_err(format!("finishing the recording: {e:#}")))
    }
}
