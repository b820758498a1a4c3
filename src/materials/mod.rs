//! Material plug-ins.
//!
//! A material is a component type implementing [`Material`]. The constitutive stage is generic
//! over it (`systems::constitutive::constitutive_model::<M>`) and one instance is scheduled per
//! material that a scene uses, so a scene with only elastic bodies runs no return mapping.
//!
//! To add a material: write `src/materials/<name>.rs` with a type implementing [`Material`]
//! (and `Serialize`/`Deserialize` for its parameters), then add one line to the
//! `register_materials!` list below. Nothing else changes.

pub mod drucker_prager;
pub mod elastic;

use crate::error::FieldError;
use bevy_ecs::prelude::*;
use bevy_ecs::schedule::ScheduleConfigs;
use bevy_ecs::system::ScheduleSystem;
use glam::DVec3;
use serde::{Deserialize, Serialize};

/// A constitutive model, evaluated per particle in principal (singular-value) space.
pub trait Material: Component + Clone + Send + Sync + 'static {
    /// Name used in logs and in the schedule listing.
    const NAME: &'static str;
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
    /// The material-parameter gradient.
    pub g_material: crate::components::MaterialAdj,
}

macro_rules! register_materials {
    ($($variant:ident => $ty:ty),* $(,)?) => {
        /// A material as written in a scene file: the plug-in's name and its parameters.
        #[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
        pub enum MaterialSpec {
            $($variant($ty),)*
        }

        impl MaterialSpec {
            pub fn name(&self) -> &'static str {
                match self { $(Self::$variant(_) => <$ty as Material>::NAME,)* }
            }
            pub fn density(&self) -> f64 {
                match self { $(Self::$variant(m) => m.density(),)* }
            }
            pub fn lame(&self) -> (f64, f64) {
                match self { $(Self::$variant(m) => m.lame(),)* }
            }
            pub fn hardens(&self) -> bool {
                match self { $(Self::$variant(m) => m.hardens(),)* }
            }
            pub fn validate(&self) -> Result<(), FieldError> {
                match self { $(Self::$variant(m) => m.validate(),)* }
            }
            /// Attaches the material component to a body entity.
            pub fn insert_into(&self, entity: &mut EntityWorldMut) {
                match self { $(Self::$variant(m) => { entity.insert(m.clone()); })* }
            }
            /// The constitutive system for this material.
            pub fn constitutive_system(&self) -> ScheduleConfigs<ScheduleSystem> {
                match self {
                    $(Self::$variant(_) => {
                        crate::systems::constitutive::constitutive_model::<$ty>.into_configs()
                    })*
                }
            }
            /// The adjoint of the constitutive system for this material.
            pub fn constitutive_adjoint_system(&self) -> ScheduleConfigs<ScheduleSystem> {
                match self {
                    $(Self::$variant(_) => {
                        crate::adjoint::constitutive::constitutive_model_adjoint::<$ty>.into_configs()
                    })*
                }
            }
            /// A key that is equal for two specs exactly when they use the same plug-in.
            pub fn plugin_index(&self) -> usize {
                let mut i = 0usize;
                $(
                    if matches!(self, Self::$variant(_)) { return i; }
                    i += 1;
                )*
                i
            }
        }
    };
}

register_materials! {
    DruckerPrager => drucker_prager::DruckerPrager,
    Elastic => elastic::Elastic,
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
        Err(FieldError::new(field, value.to_string(), expected))
    }
}
