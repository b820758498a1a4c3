//! Simulation-wide resources.

use bevy_ecs::prelude::*;
use glam::DVec3;
use std::fmt;

/// Time stepping and global physics parameters.
#[derive(Resource, Clone, Debug)]
pub struct SimParams {
    /// Global step Δt (s).
    pub dt: f64,
    /// Substeps per global step, after the stability guard.
    pub substeps: usize,
    /// Δt_sub = Δt/N_sub (s).
    pub dt_sub: f64,
    /// Gravity (m/s²).
    pub gravity: DVec3,
    /// Nodes with mass at or below this (kg) are empty: their velocity is zero.
    pub empty_node_mass: f64,
    /// The precision of the SVD stage.
    pub svd: Precision,
}

/// The floating-point precision of a stage that offers two (`simulation.svd` in a scene).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Precision {
    /// f64, as every other stage: the finite-difference checks need it.
    #[default]
    F64,
    /// f32: twice the lanes of a SIMD register and fewer Jacobi sweeps, factors good to about
    /// 1e-7 of ‖F‖ (`crate::math::svd::svd3_warm_lanes_f32`).
    F32,
}

impl Precision {
    pub fn is_f64(&self) -> bool {
        *self == Precision::F64
    }
}

/// Where the simulation is in time.
#[derive(Resource, Clone, Copy, Debug, Default)]
pub struct Clock {
    /// Global step being computed (0-based).
    pub step: usize,
    /// Substep within the step (0-based).
    pub substep: usize,
    /// Substeps completed since the start.
    pub total_substeps: u64,
}

/// The first non-finite value a stage met, if any. Stages record; the driver stops.
#[derive(Resource, Clone, Debug, Default)]
pub struct Health {
    pub fault: Option<Fault>,
}

/// A non-finite value: which stage, what, where.
#[derive(Clone, Debug, PartialEq)]
pub struct Fault {
    pub stage: &'static str,
    pub field: &'static str,
    /// Body name, or "grid".
    pub owner: String,
    /// Particle or node index.
    pub index: usize,
    pub value: String,
}

impl Fault {
    /// A particle's non-finite `value` of `field`, found by `stage` in the body `body`.
    pub fn particle(
        stage: &'static str,
        field: &'static str,
        body: &str,
        index: usize,
        value: impl fmt::Debug,
    ) -> Self {
        Self {
            stage,
            field,
            owner: format!("body '{body}' particle"),
            index,
            value: format!("{value:?}"),
        }
    }
}

impl fmt::Display for Fault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "stage '{}': field '{}' of {} index {} is non-finite ({})",
            self.stage, self.field, self.owner, self.index, self.value
        )
    }
}

impl Fault {
    /// The scene fields most likely responsible for a non-finite value in this stage.
    pub fn suspects(&self) -> &'static str {
        match self.stage {
            "constitutive" => {
                "materials.*.youngs_modulus and poisson_ratio (stiffness), simulation.substeps"
            }
            "p2g" => "materials.*.youngs_modulus and density, simulation.gravity, simulation.substeps",
            "g2p" => {
                "colliders.*.control (tool speed), simulation.gravity, bodies.*.velocity, simulation.substeps"
            }
            _ => "bodies.*.velocity, colliders.*.control (tool speed), simulation.dt and substeps",
        }
    }
}

impl Health {
    /// Records a fault unless one is already recorded (the first one wins).
    pub fn report(&mut self, fault: Fault) {
        if self.fault.is_none() {
            self.fault = Some(fault);
        }
    }
}

/// Counters the driver and `bench` report: per-stage wall time.
#[derive(Resource, Clone, Debug, Default)]
pub struct StageTimers {
    pub seconds: Vec<(&'static str, f64)>,
    pub enabled: bool,
}

impl StageTimers {
    pub fn add(&mut self, stage: &'static str, secs: f64) {
        if let Some(e) = self.seconds.iter_mut().find(|e| e.0 == stage) {
            e.1 += secs;
        } else {
            self.seconds.push((stage, secs));
        }
    }
}
