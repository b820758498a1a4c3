//! Error types at each boundary. Every message is one line that names where the problem is
//! and what to do about it.

use std::path::PathBuf;
use thiserror::Error;

/// A number as an error message shows it: plain between 1e-4 and 1e6, else in scientific
/// notation (`1e300`, not its 301 digits).
pub fn num(v: f64) -> String {
    if v == 0.0 || !v.is_finite() || (1e-4..1e6).contains(&v.abs()) {
        v.to_string()
    } else {
        format!("{v:e}")
    }
}

/// A field whose value is out of range, before the file position is known.
#[derive(Clone, Debug, PartialEq)]
pub struct FieldError {
    /// Dotted path of the field, e.g. `materials.sand.friction_deg`.
    pub field: String,
    pub value: String,
    /// What a valid value looks like.
    pub expected: String,
}

impl FieldError {
    pub fn new(
        field: impl Into<String>,
        value: impl Into<String>,
        expected: impl Into<String>,
    ) -> Self {
        Self {
            field: field.into(),
            value: value.into(),
            expected: expected.into(),
        }
    }
    /// Prefixes the field path with its parent, e.g. `bodies[0]` + `fill.min`.
    pub fn within(mut self, parent: &str) -> Self {
        self.field = format!("{parent}.{}", self.field);
        self
    }
}

/// Problems with a scene file.
#[derive(Debug, Error)]
pub enum SceneError {
    /// The cause is part of the message and deliberately not the error's `source()`: the CLI
    /// prints the whole chain, which stated the OS error twice.
    #[error("{file}: cannot read the scene file: {cause}; check the path")]
    Io {
        file: PathBuf,
        cause: std::io::Error,
    },
    #[error("{name}: no such scene file, and no shipped scene of that name; give the path to a .ron file, or one of the shipped scenes: {shipped}")]
    Unknown { name: String, shipped: String },
    #[error("{file}:{line}:{col}: {message}; fix the scene file (all fields are documented in scenes/README.md)")]
    Parse {
        file: PathBuf,
        line: usize,
        col: usize,
        message: String,
    },
    #[error("{file}:{line}:{col}: field `{field}` = {value} is out of range: expected {expected}")]
    Invalid {
        file: PathBuf,
        line: usize,
        col: usize,
        field: String,
        value: String,
        expected: String,
    },
    #[error("{file}:{line}:{col}: field `{field}`: unstable time step: Δt_sub = {dt_sub:.3e} s exceeds the stable {dt_max:.3e} s ({reason_and_advice}")]
    Unstable {
        file: PathBuf,
        line: usize,
        col: usize,
        /// The field that sets the step's limit: the stiffest material, the fastest tool or
        /// body, or `simulation.substeps` under `stability: Strict`.
        field: String,
        dt_sub: f64,
        dt_max: f64,
        /// Why, a closing parenthesis, and what to change in the scene (one string, so that
        /// the error stays small enough to return by value).
        reason_and_advice: String,
    },
}

/// Failures while simulating.
#[derive(Debug, Error)]
pub enum SimError {
    #[error("non-finite value at step {step}, substep {substep}: {fault}; most likely responsible: {suspects} (a time step too large for the material or the tool speed: try stability: Auto or more substeps)", suspects = fault.suspects())]
    NonFinite {
        step: usize,
        substep: usize,
        fault: crate::components::Fault,
    },
    #[error(transparent)]
    Scene(#[from] SceneError),
    #[error("{0}")]
    Other(String),
}

/// Failures of the backward pass. A gradient is never returned zeroed or clipped silently.
#[derive(Debug, Error)]
pub enum AdjointError {
    #[error("the scene cannot be differentiated yet: {0}")]
    NotDifferentiable(String),
    #[error("non-finite adjoint at step {step}, substep {substep}, after stage '{stage}': field '{field}' of {owner} index {index} is {value}")]
    NonFinite {
        step: usize,
        substep: usize,
        stage: &'static str,
        field: &'static str,
        owner: String,
        index: usize,
        value: String,
    },
    #[error("the smallest tape for {steps} steps (a checkpoint every {every} steps) needs {need} bytes ({need_mb:.1} MB), over the memory budget of {budget} bytes ({budget_mb:.1} MB): raise --budget-mb to at least {need_mb_ceil} or shorten the horizon", need_mb = *need as f64 / 1048576.0, budget_mb = *budget as f64 / 1048576.0, need_mb_ceil = need.div_ceil(1 << 20))]
    OverBudget {
        steps: usize,
        every: usize,
        need: usize,
        budget: usize,
    },
    #[error(transparent)]
    Sim(#[from] SimError),
}
