//! Material plug-ins.
//!
//! A material is a component type implementing [`Material`]: its parameters (with serde, as a
//! scene writes them), its constitutive update in principal space and that update's adjoint,
//! and the list of its differentiable parameters. The constitutive stage is generic over it
//! (`systems::constitutive::constitutive_model::<M>`) and one instance is scheduled per material
//! that a scene uses, so a scene with only elastic bodies runs no return mapping.
//!
//! To add a material to powderlab: write `src/materials/<name>.rs` with a type implementing
//! [`Material`], then add one line to the `builtin_materials!` list in [`registry`]. A program
//! that uses powderlab as a library calls [`register`]`::<M>()` instead, and its scenes name
//! the material by [`Material::TAG`] (`tests/extension_points.rs` does this with a Neo-Hookean
//! solid).

pub mod cohesive_drucker_prager;
pub mod drucker_prager;
pub mod elastic;
pub mod mu_i;
pub mod registry;

pub use registry::{register, MaterialSpec};

use crate::components::MaterialAdj;
use crate::error::FieldError;
use bevy_ecs::prelude::*;
use glam::DVec3;
use serde::de::DeserializeOwned;
use serde::Serialize;

/// How a gradient check perturbs a parameter: by a fraction of its value, or by an amount.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FdStep {
    Relative(f64),
    Absolute(f64),
}

impl FdStep {
    /// The step at `value`.
    pub fn at(self, value: f64) -> f64 {
        match self {
            FdStep::Relative(r) => r * value,
            FdStep::Absolute(a) => a,
        }
    }
}

/// A differentiable parameter of a material: its field name in the scene and its
/// finite-difference step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Param {
    pub name: &'static str,
    pub fd_step: FdStep,
}

/// `(∂(μ, λ)/∂E, ∂(μ, λ)/∂ν)` at `(E, ν)`: a parameter gradient is linear in `(∂L/∂μ, ∂L/∂λ)`,
/// so a material's per-particle adjoint applies these instead of evaluating `lame_adj`.
pub(crate) fn lame_derivatives(youngs: f64, poisson: f64) -> [(f64, f64); 2] {
    use crate::math::return_map::lame_adj;
    let (d_mu_de, d_mu_dnu) = lame_adj(youngs, poisson, 1.0, 0.0);
    let (d_lambda_de, d_lambda_dnu) = lame_adj(youngs, poisson, 0.0, 1.0);
    [(d_mu_de, d_lambda_de), (d_mu_dnu, d_lambda_dnu)]
}

/// Young's modulus `youngs_modulus` (Pa), perturbed by a millionth of its value.
pub const YOUNGS_MODULUS: Param = Param {
    name: "youngs_modulus",
    fd_step: FdStep::Relative(1e-6),
};

/// Poisson's ratio `poisson_ratio`, perturbed by 1e-6.
pub const POISSON_RATIO: Param = Param {
    name: "poisson_ratio",
    fd_step: FdStep::Absolute(1e-6),
};

/// A constitutive model, evaluated per particle in principal (singular-value) space.
pub trait Material:
    Component
    + Clone
    + PartialEq
    + std::fmt::Debug
    + Serialize
    + DeserializeOwned
    + Send
    + Sync
    + 'static
{
    /// Name used in logs and in the schedule listing.
    const NAME: &'static str;
    /// Name a scene file gives it: `TAG((parameters...))`.
    const TAG: &'static str;
    /// The differentiable parameters, in the order of [`MaterialAdj`]'s entries (at most
    /// [`MAX_MATERIAL_PARAMS`]).
    const PARAMS: &'static [Param];
    /// The value of parameter `i` of [`Material::PARAMS`].
    fn param(&self, i: usize) -> f64;
    /// Sets parameter `i` of [`Material::PARAMS`].
    fn set_param(&mut self, i: usize, value: f64);
    /// The material ready to run: what it derives from its parameters computed once, when a
    /// body is built. By default the material itself.
    fn prepared(&self) -> Self {
        self.clone()
    }
    /// Takes the substep `Δt` (s) the body runs at, once, when its body is built (after
    /// [`Material::prepared`]): a rate-dependent material (μ(I)) derives its shear rate from
    /// it. By default nothing.
    fn with_substep(&mut self, dt_sub: f64) {
        let _ = dt_sub;
    }
    /// Density (kg/m³).
    fn density(&self) -> f64;
    /// Lamé parameters (μ, λ) in Pa, for the stability guard.
    fn lame(&self) -> (f64, f64);
    /// Whether the material keeps a hardening variable per particle.
    fn hardens(&self) -> bool {
        false
    }
    /// Checks the parameters; an error names the field, its value and the valid range.
    fn validate(&self) -> Result<(), FieldError>;
    /// Constitutive update of one particle from the singular values `σ` of the trial `F`.
    /// Returns the projected singular values (`None` when `F` stays the trial `F`, i.e. no
    /// plasticity) and the principal Kirchhoff stresses. `q` is the hardening variable.
    fn update(&self, sigma: DVec3, q: &mut f64) -> (Option<DVec3>, DVec3);
    /// Adjoint of [`Material::update`] at `σ` (hardening not differentiated): given `∂L/∂σ′`
    /// (ignored when the update returns `None`) and `∂L/∂τ_p`, returns `∂L/∂σ` and the
    /// material-parameter gradient, together with the update itself (the adjoint stage needs
    /// both, and one evaluation of the forward maths serves both).
    fn update_adj(&self, sigma: DVec3, q: f64, g_sigma_new: DVec3, g_tau: DVec3) -> UpdateAdj;
    /// [`Material::update`], also writing into `saved` what [`Material::update_adj_saved`]
    /// reads back. By default nothing is saved.
    fn update_saving(&self, sigma: DVec3, q: &mut f64, saved: &mut Saved) -> Updated {
        let _ = saved;
        self.update(sigma, q)
    }
    /// [`Material::update`] of each particle of a [`Group`], or [`Material::update_saving`]
    /// where it has `saved`: the same results, bit for bit, as one particle at a time, which is
    /// what this default does. A material whose maths runs several particles to a vector
    /// register overrides it.
    fn update_many(&self, g: Group<'_>) {
        match g.saved {
            Some(saved) => {
                for (((s, q), sv), o) in g.sigma.iter().zip(g.q).zip(saved).zip(g.out) {
                    *o = self.update_saving(*s, q, sv);
                }
            }
            None => {
                for ((s, q), o) in g.sigma.iter().zip(g.q).zip(g.out) {
                    *o = self.update(*s, q);
                }
            }
        }
    }
    /// [`Material::update_adj`] at the `sigma` and `q` that [`Material::update_saving`] saw,
    /// from what it saved: the same result bit for bit, without recomputing the update.
    fn update_adj_saved(
        &self,
        sigma: DVec3,
        q: f64,
        saved: &Saved,
        g_sigma_new: DVec3,
        g_tau: DVec3,
    ) -> UpdateAdj {
        let _ = saved;
        self.update_adj(sigma, q, g_sigma_new, g_tau)
    }
}

/// A group of particles for [`Material::update_many`]: the singular values, the hardening
/// variables, where to save what the adjoint reads (or `None`) and the results, of one length.
pub struct Group<'a> {
    pub sigma: &'a [DVec3],
    pub q: &'a mut [f64],
    pub saved: Option<&'a mut [Saved]>,
    pub out: &'a mut [Updated],
}

/// What a material's update keeps for its adjoint (see `components::UpdateSaved`).
pub type Saved = [DVec3; 3];

/// A material update's projected singular values (if plastic) and principal Kirchhoff stresses.
pub type Updated = (Option<DVec3>, DVec3);

/// What [`Material::update_adj`] returns.
#[derive(Clone, Copy, Debug)]
pub struct UpdateAdj {
    /// The projected singular values, as [`Material::update`] returns them.
    pub sigma_new: Option<DVec3>,
    /// The principal Kirchhoff stresses, as [`Material::update`] returns them.
    pub tau: DVec3,
    /// `∂L/∂σ`.
    pub g_sigma: DVec3,
    /// The material-parameter gradient, in the order of [`Material::PARAMS`].
    pub g_material: MaterialAdj,
}

/// Largest density (kg/m³): above osmium's 22,590, with room to spare.
pub const MAX_DENSITY: f64 = 1e5;
/// Largest Young's modulus (Pa): ten times diamond's. Stiffer materials only make the stable
/// substep vanish.
pub const MAX_YOUNGS_MODULUS: f64 = 1e13;

/// The checks every StVK-in-Hencky material makes: density and Young's modulus in their ranges
/// ([`check_density_and_stiffness`]) and Poisson's ratio in (−1, 0.5).
pub(crate) fn check_elastic(density: f64, youngs: f64, poisson: f64) -> Result<(), FieldError> {
    check_density_and_stiffness(density, youngs)?;
    check_range(
        "poisson_ratio",
        poisson,
        poisson > -1.0 && poisson < 0.5,
        "in (-1, 0.5)",
    )
}

/// The density and Young's modulus every material has: positive and within what a material
/// can be.
pub(crate) fn check_density_and_stiffness(density: f64, youngs: f64) -> Result<(), FieldError> {
    check_range(
        "density",
        density,
        density > 0.0 && density <= MAX_DENSITY,
        &format!("in (0, {MAX_DENSITY:e}] kg/m³"),
    )?;
    check_range(
        "youngs_modulus",
        youngs,
        youngs > 0.0 && youngs <= MAX_YOUNGS_MODULUS,
        &format!("in (0, {MAX_YOUNGS_MODULUS:e}] Pa"),
    )
}

/// Checks `lo <= value <= hi` (or the open variants the closure encodes) for a field.
pub(crate) fn check_range(
    field: &'static str,
    value: f64,
    ok: bool,
    expected: &str,
) -> Result<(), FieldError> {
    if ok && value.is_finite() {
        Ok(())
    } else {
        Err(FieldError::new(field, crate::error::num(value), expected))
    }
}

/// `MaterialAdj` with the given leading entries (the rest zero).
pub fn material_adj(values: &[f64]) -> MaterialAdj {
    let mut m = MaterialAdj::default();
    m.0[..values.len()].copy_from_slice(values);
    m
}

/// The central-difference check the materials' tests share.
#[cfg(test)]
pub(crate) mod fd {
    use super::{Material, UpdateAdj};
    use glam::DVec3;

    /// Weights of the check's loss `w_σ·σ′ + w_τ·τ_p`: O(1) on the stretches, and on the
    /// stresses the inverse of the tests' E = 1e5 Pa, so both terms are of order one.
    pub const W_SIGMA: DVec3 = DVec3::new(0.3, -0.8, 0.5);
    pub const W_TAU: DVec3 = DVec3::new(1e-5, 2e-5, -1.5e-5);
    /// Step of the difference in σ.
    pub const SIGMA_STEP: f64 = 1e-7;

    /// Checks `update_adj` of `base` (made ready by `ready`: `prepared`, and the substep for a
    /// rate-dependent material) at `sigma` against central differences in σ and in every
    /// parameter of [`Material::PARAMS`] at its own step: each within `rel_tol` of the larger
    /// of the two, or `floor` where both are round-off. Also checks that the update it returns is
    /// the forward's. Returns the adjoint.
    pub fn check_update_adjoint<M: Material>(
        base: &M,
        ready: &dyn Fn(&M) -> M,
        sigma: DVec3,
        rel_tol: f64,
        floor: f64,
    ) -> UpdateAdj {
        let loss = |m: &M, s: DVec3| {
            let (sn, t) = ready(m).update(s, &mut 0.0);
            sn.unwrap_or(s).dot(W_SIGMA) + t.dot(W_TAU)
        };
        let m = ready(base);
        let out = m.update_adj(sigma, 0.0, W_SIGMA, W_TAU);
        assert_eq!((out.sigma_new, out.tau), m.update(sigma, &mut 0.0));
        let close = |fd: f64, ad: f64, what: &str| {
            assert!(
                (fd - ad).abs() <= (rel_tol * fd.abs().max(ad.abs())).max(floor),
                "σ {sigma:?} {what}: fd {fd} ad {ad}"
            );
        };
        let h = SIGMA_STEP;
        for a in 0..3 {
            let mut e = DVec3::ZERO;
            e[a] = h;
            close(
                (loss(base, sigma + e) - loss(base, sigma - e)) / (2.0 * h),
                out.g_sigma[a],
                "σ",
            );
        }
        for (i, p) in M::PARAMS.iter().enumerate() {
            let step = p.fd_step.at(base.param(i));
            let at = |d: f64| {
                let mut x = base.clone();
                x.set_param(i, base.param(i) + d);
                loss(&x, sigma)
            };
            close(
                (at(step) - at(-step)) / (2.0 * step),
                out.g_material.0[i],
                p.name,
            );
        }
        out
    }
}
