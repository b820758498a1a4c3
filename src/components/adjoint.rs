//! Adjoint state: the `…Adj` twins of the forward components. Only a backward pass allocates
//! them; a forward run never does.
//!
//! Convention: an adjoint holds `∂L/∂(current value)` of its forward field. A stage that
//! overwrites a field consumes the adjoint of the new value and leaves the adjoint of the old
//! one; stages that only read a field accumulate into its adjoint with `+=`.

use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3};

/// `∂L/∂x`.
#[derive(Component, Clone, Debug, Default)]
pub struct PositionAdj(pub Vec<DVec3>);

/// `∂L/∂v`.
#[derive(Component, Clone, Debug, Default)]
pub struct VelocityAdj(pub Vec<DVec3>);

/// `∂L/∂C`.
#[derive(Component, Clone, Debug, Default)]
pub struct AffineVelocityAdj(pub Vec<DMat3>);

/// `∂L/∂F`.
#[derive(Component, Clone, Debug, Default)]
pub struct DeformationGradientAdj(pub Vec<DMat3>);

/// `∂L/∂F_tmp`.
#[derive(Component, Clone, Debug, Default)]
pub struct TrialDeformationAdj(pub Vec<DMat3>);

/// `∂L/∂U`, `∂L/∂σ`, `∂L/∂V`.
#[derive(Component, Clone, Debug, Default)]
pub struct SvdFactorsAdj {
    pub u: Vec<DMat3>,
    pub s: Vec<DVec3>,
    pub v: Vec<DMat3>,
}

/// `∂L/∂A` of the P2G affine term.
#[derive(Component, Clone, Debug, Default)]
pub struct P2gAffineAdj(pub Vec<DMat3>);

/// The particle state at the start of the substep being reversed (x, v, C, F). The forward
/// stages overwrite these in place, so the backward pass keeps a copy for the adjoints that
/// need the old values (deformation update, P2G, G2P).
#[derive(Component, Clone, Debug, Default)]
pub struct SubstepStart {
    pub x: Vec<DVec3>,
    pub v: Vec<DVec3>,
    pub c: Vec<DMat3>,
    pub f: Vec<DMat3>,
}

impl SubstepStart {
    /// Zeroed buffers for `n` particles (the backward pass swaps them with the world's, so
    /// they must have the body's length from the start).
    pub fn zeroed(n: usize) -> Self {
        Self {
            x: vec![DVec3::ZERO; n],
            v: vec![DVec3::ZERO; n],
            c: vec![DMat3::ZERO; n],
            f: vec![DMat3::ZERO; n],
        }
    }
}

/// The most differentiable parameters a material declares (`Material::PARAMS`).
pub const MAX_MATERIAL_PARAMS: usize = 4;

/// The gradient with respect to a body's material parameters, in the order the material
/// declares them (`Material::PARAMS`; Drucker–Prager: `∂L/∂E`, `∂L/∂ν`, `∂L/∂φ` per degree).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct MaterialAdj(pub [f64; MAX_MATERIAL_PARAMS]);

impl std::ops::Add for MaterialAdj {
    type Output = MaterialAdj;
    /// Entry by entry.
    fn add(self, other: MaterialAdj) -> MaterialAdj {
        MaterialAdj(std::array::from_fn(|i| self.0[i] + other.0[i]))
    }
}

/// Adjoints of the grid fields. `mass` and `momentum` are set by the P2G adjoint from
/// `velocity` (`v = p/m`); `velocity` accumulates from G2P's adjoint and grid collision's.
#[derive(Resource, Clone, Debug, Default)]
pub struct GridAdj {
    pub mass: Vec<f64>,
    pub momentum: Vec<DVec3>,
    pub velocity: Vec<DVec3>,
}

impl GridAdj {
    pub fn new(len: usize) -> Self {
        Self {
            mass: vec![0.0; len],
            momentum: vec![DVec3::ZERO; len],
            velocity: vec![DVec3::ZERO; len],
        }
    }
}
