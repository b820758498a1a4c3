//! The material plug-ins a scene can name, and [`MaterialSpec`], a material as a scene holds it.
//!
//! The built-in materials are the `builtin_materials!` list below: one line each. A program that
//! uses powderlab as a library adds its own with [`register`]. A scene names a material by its
//! [`Material::TAG`], with its parameters: `DruckerPrager((youngs_modulus: 2e4))`. Built-in
//! parameters are read by their own serde code, so an error inside them keeps its line and
//! column; a registered material's are read through `erased_serde`, which keeps the message.
//!
//! This module sits above the constitutive stage and its adjoint: it is where a material type
//! meets the two generic systems (`constitutive_model::<M>` and its adjoint), so that neither
//! the stages nor the material files know each other's details.

use super::{Material, Param};
use crate::adjoint::constitutive::constitutive_model_adjoint;
use crate::error::FieldError;
use crate::plugin::{Registry, Seed, Tag};
use crate::systems::constitutive::constitutive_model;
use bevy_ecs::prelude::*;
use bevy_ecs::schedule::ScheduleConfigs;
use bevy_ecs::system::ScheduleSystem;
use serde::de::{self, EnumAccess, VariantAccess, Visitor};
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use std::any::{Any, TypeId};
use std::fmt;
use std::sync::Arc;

macro_rules! builtin_materials {
    ($($ty:ty),* $(,)?) => {
        /// The scene names of the built-in materials.
        const BUILTIN_TAGS: &[&str] = &[$(<$ty as Material>::TAG),*];

        /// Reads a built-in material's parameters with its own serde code.
        fn parse_builtin<'de, V: VariantAccess<'de>>(
            tag: &str,
            variant: V,
        ) -> Option<Result<MaterialSpec, V::Error>> {
            $(
                if tag == <$ty as Material>::TAG {
                    return Some(variant.newtype_variant::<$ty>().map(MaterialSpec::new));
                }
            )*
            let _ = variant;
            None
        }
    };
}

builtin_materials! {
    super::drucker_prager::DruckerPrager,
    super::cohesive_drucker_prager::CohesiveDruckerPrager,
    super::elastic::Elastic,
    super::mu_i::MuI,
}

/// A material behind a trait object: what the scene, the schedule and the gradient check need
/// of any [`Material`], without knowing its type.
pub trait DynMaterial: erased_serde::Serialize + fmt::Debug + Send + Sync + Any {
    fn name(&self) -> &'static str;
    fn tag(&self) -> &'static str;
    fn density(&self) -> f64;
    fn lame(&self) -> (f64, f64);
    fn hardens(&self) -> bool;
    fn validate(&self) -> Result<(), FieldError>;
    fn params(&self) -> &'static [Param];
    fn param(&self, i: usize) -> f64;
    /// A copy with parameter `i` set to `value`.
    fn with_param(&self, i: usize, value: f64) -> MaterialSpec;
    fn prepared(&self) -> MaterialSpec;
    /// Attaches the material component to a body entity that runs at substep `dt_sub` (s)
    /// ([`Material::with_substep`]).
    fn insert_into(&self, entity: &mut EntityWorldMut, dt_sub: f64);
    /// The constitutive system for this material.
    fn constitutive_system(&self) -> ScheduleConfigs<ScheduleSystem>;
    /// The adjoint of the constitutive system for this material.
    fn constitutive_adjoint_system(&self) -> ScheduleConfigs<ScheduleSystem>;
    fn eq_dyn(&self, other: &dyn DynMaterial) -> bool;
    fn as_any(&self) -> &dyn Any;
    fn as_any_mut(&mut self) -> &mut dyn Any;
}

erased_serde::serialize_trait_object!(DynMaterial);

impl<M: Material> DynMaterial for M {
    fn name(&self) -> &'static str {
        M::NAME
    }
    fn tag(&self) -> &'static str {
        M::TAG
    }
    fn density(&self) -> f64 {
        Material::density(self)
    }
    fn lame(&self) -> (f64, f64) {
        Material::lame(self)
    }
    fn hardens(&self) -> bool {
        Material::hardens(self)
    }
    fn validate(&self) -> Result<(), FieldError> {
        Material::validate(self)
    }
    fn params(&self) -> &'static [Param] {
        M::PARAMS
    }
    fn param(&self, i: usize) -> f64 {
        Material::param(self, i)
    }
    fn with_param(&self, i: usize, value: f64) -> MaterialSpec {
        let mut m = self.clone();
        m.set_param(i, value);
        MaterialSpec::new(m)
    }
    fn prepared(&self) -> MaterialSpec {
        MaterialSpec::new(Material::prepared(self))
    }
    fn insert_into(&self, entity: &mut EntityWorldMut, dt_sub: f64) {
        let mut m = self.clone();
        m.with_substep(dt_sub);
        entity.insert(m);
    }
    fn constitutive_system(&self) -> ScheduleConfigs<ScheduleSystem> {
        constitutive_model::<M>.into_configs()
    }
    fn constitutive_adjoint_system(&self) -> ScheduleConfigs<ScheduleSystem> {
        constitutive_model_adjoint::<M>.into_configs()
    }
    fn eq_dyn(&self, other: &dyn DynMaterial) -> bool {
        other.as_any().downcast_ref::<M>() == Some(self)
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
    fn as_any_mut(&mut self) -> &mut dyn Any {
        self
    }
}

/// A material as a scene holds it: a plug-in and its parameters.
#[derive(Clone, Debug)]
pub struct MaterialSpec(Arc<dyn DynMaterial>);

impl MaterialSpec {
    pub fn new<M: Material>(m: M) -> MaterialSpec {
        MaterialSpec(Arc::new(m))
    }

    /// The material as its type, if it is an `M`.
    pub fn get<M: Material>(&self) -> Option<&M> {
        self.0.as_any().downcast_ref::<M>()
    }

    /// The material as its type, to edit, if it is an `M`.
    pub fn get_mut<M: Material>(&mut self) -> Option<&mut M> {
        let m = self.get::<M>()?.clone();
        if Arc::get_mut(&mut self.0).is_none() {
            self.0 = Arc::new(m);
        }
        Arc::get_mut(&mut self.0)?.as_any_mut().downcast_mut::<M>()
    }

    /// A key equal for two specs exactly when they use the same plug-in.
    pub fn plugin(&self) -> TypeId {
        self.0.as_any().type_id()
    }
}

impl std::ops::Deref for MaterialSpec {
    type Target = dyn DynMaterial;
    fn deref(&self) -> &dyn DynMaterial {
        &*self.0
    }
}

impl PartialEq for MaterialSpec {
    fn eq(&self, other: &Self) -> bool {
        self.0.eq_dyn(&*other.0)
    }
}

/// The materials added with [`register`].
static REGISTERED: Registry<MaterialSpec> = Registry::new();

fn parse_registered<'a, 'de, M: Material>(
    d: &'a mut dyn erased_serde::Deserializer<'de>,
) -> Result<MaterialSpec, erased_serde::Error> {
    erased_serde::deserialize::<M>(d).map(MaterialSpec::new)
}

/// Makes material `M` available to scenes under its [`Material::TAG`]. Registering a tag again
/// replaces the earlier registration; a built-in tag cannot be replaced.
///
/// # Panics
/// When `M` declares more than [`crate::components::MAX_MATERIAL_PARAMS`] parameters, or takes
/// a built-in material's tag: both are mistakes in the calling program, not in a scene.
pub fn register<M: Material>() {
    assert!(
        M::PARAMS.len() <= crate::components::MAX_MATERIAL_PARAMS,
        "material {}: {} differentiable parameters, at most {}",
        M::TAG,
        M::PARAMS.len(),
        crate::components::MAX_MATERIAL_PARAMS
    );
    assert!(
        !BUILTIN_TAGS.contains(&M::TAG),
        "material tag {} is built in",
        M::TAG
    );
    REGISTERED.insert(M::TAG, parse_registered::<M>);
}

impl Serialize for MaterialSpec {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let index = BUILTIN_TAGS
            .iter()
            .position(|t| *t == self.0.tag())
            .unwrap_or(BUILTIN_TAGS.len());
        s.serialize_newtype_variant("MaterialSpec", index as u32, self.0.tag(), &*self.0)
    }
}

struct SpecVisitor;

impl<'de> Visitor<'de> for SpecVisitor {
    type Value = MaterialSpec;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a material: a plug-in name with its parameters")
    }
    fn visit_enum<A: EnumAccess<'de>>(self, data: A) -> Result<MaterialSpec, A::Error> {
        let (tag, variant) = data.variant_seed(Tag)?;
        if let Some(parse) = REGISTERED.get(&tag) {
            return variant.newtype_variant_seed(Seed(parse));
        }
        match parse_builtin(&tag, variant) {
            Some(r) => r,
            None => Err(de::Error::unknown_variant(
                &tag,
                REGISTERED.known(BUILTIN_TAGS),
            )),
        }
    }
}

impl<'de> Deserialize<'de> for MaterialSpec {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<MaterialSpec, D::Error> {
        d.deserialize_enum("MaterialSpec", BUILTIN_TAGS, SpecVisitor)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::materials::{drucker_prager::DruckerPrager, elastic::Elastic};

    #[test]
    fn builtins_declare_their_parameters_within_the_adjoint_s_room() {
        for (params, tag) in [
            (DruckerPrager::PARAMS, DruckerPrager::TAG),
            (Elastic::PARAMS, Elastic::TAG),
        ] {
            assert!(
                params.len() <= crate::components::MAX_MATERIAL_PARAMS,
                "{tag}"
            );
        }
    }

    #[test]
    fn a_spec_reads_back_what_it_writes() {
        let src = "DruckerPrager((youngs_modulus: 20000.0, friction_deg: 25.0))";
        let m: MaterialSpec = ron::from_str(src).unwrap();
        assert_eq!(m.get::<DruckerPrager>().unwrap().friction_deg, 25.0);
        let back: MaterialSpec = ron::from_str(&ron::to_string(&m).unwrap()).unwrap();
        assert_eq!(back, m);
        assert!(m.get::<Elastic>().is_none());
        let e: Result<MaterialSpec, _> = ron::from_str("Jelly((density: 1.0))");
        let msg = e.unwrap_err().to_string();
        assert!(
            msg.contains("Jelly") && msg.contains("DruckerPrager"),
            "{msg}"
        );
    }
}
