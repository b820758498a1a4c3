//! Shapes a program adds: a type implementing [`ShapePlugin`] (its parameters with serde, its
//! SDF and, for a tool whose pose is differentiated, its Hessian), registered with
//! [`register_shape`]. A scene names it `Custom(Tag((parameters...)))`; its parameters are read
//! through `erased_serde`, which keeps serde's message.

use crate::error::FieldError;
use crate::math::mesh::Mesh;
use crate::plugin::{Registry, Seed, Tag};
use glam::{DMat3, DVec3};
use serde::de::{self, DeserializeOwned, EnumAccess, VariantAccess, Visitor};
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use std::any::Any;
use std::fmt;
use std::sync::Arc;

/// A shape of a program's own, in its local frame (SI units).
pub trait ShapePlugin:
    Clone + PartialEq + fmt::Debug + Serialize + DeserializeOwned + Send + Sync + 'static
{
    /// Name a scene gives it: `Custom(TAG((...)))`.
    const TAG: &'static str;
    /// Signed distance and its gradient at the local point `p` (`φ < 0` inside, `|∇φ| = 1`).
    fn sdf(&self, p: DVec3) -> (f64, DVec3);
    /// `∂²φ/∂p²`, which the adjoint of a moving tool and of particle contact needs; `None`
    /// (the default) makes such a scene refuse its gradient with a message.
    fn sdf_hessian(&self, p: DVec3) -> Option<DMat3> {
        let _ = p;
        None
    }
    /// Radius of a sphere about the local origin that contains the solid.
    fn bounding_radius(&self) -> f64;
    /// Thinnest wall, for the thin-wall checks. Default: none.
    fn min_wall(&self) -> f64 {
        f64::INFINITY
    }
    /// Lowest point in the local frame (where a skill's descent is measured from).
    fn lowest_local_point(&self) -> DVec3 {
        DVec3::ZERO
    }
    /// Checks the parameters; an error names the field, its value and the valid range.
    fn validate(&self) -> Result<(), FieldError> {
        Ok(())
    }
    /// Triangle mesh for recordings. Default: none (the shape is not drawn).
    fn mesh(&self) -> Mesh {
        Mesh::default()
    }
}

/// [`ShapePlugin`] behind a trait object.
pub trait DynShape: erased_serde::Serialize + fmt::Debug + Send + Sync + Any {
    fn tag(&self) -> &'static str;
    fn sdf(&self, p: DVec3) -> (f64, DVec3);
    fn sdf_hessian(&self, p: DVec3) -> Option<DMat3>;
    fn bounding_radius(&self) -> f64;
    fn min_wall(&self) -> f64;
    fn lowest_local_point(&self) -> DVec3;
    fn validate(&self) -> Result<(), FieldError>;
    fn mesh(&self) -> Mesh;
    fn eq_dyn(&self, other: &dyn DynShape) -> bool;
    fn as_any(&self) -> &dyn Any;
}

erased_serde::serialize_trait_object!(DynShape);

impl<S: ShapePlugin> DynShape for S {
    fn tag(&self) -> &'static str {
        S::TAG
    }
    fn sdf(&self, p: DVec3) -> (f64, DVec3) {
        ShapePlugin::sdf(self, p)
    }
    fn sdf_hessian(&self, p: DVec3) -> Option<DMat3> {
        ShapePlugin::sdf_hessian(self, p)
    }
    fn bounding_radius(&self) -> f64 {
        ShapePlugin::bounding_radius(self)
    }
    fn min_wall(&self) -> f64 {
        ShapePlugin::min_wall(self)
    }
    fn lowest_local_point(&self) -> DVec3 {
        ShapePlugin::lowest_local_point(self)
    }
    fn validate(&self) -> Result<(), FieldError> {
        ShapePlugin::validate(self)
    }
    fn mesh(&self) -> Mesh {
        ShapePlugin::mesh(self)
    }
    fn eq_dyn(&self, other: &dyn DynShape) -> bool {
        other.as_any().downcast_ref::<S>() == Some(self)
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
}

/// A registered shape with its parameters: `Shape::Custom`'s content.
#[derive(Clone, Debug)]
pub struct CustomShape(Arc<dyn DynShape>);

impl CustomShape {
    pub fn new<S: ShapePlugin>(s: S) -> CustomShape {
        CustomShape(Arc::new(s))
    }

    /// The shape as its type, if it is an `S`.
    pub fn get<S: ShapePlugin>(&self) -> Option<&S> {
        self.0.as_any().downcast_ref::<S>()
    }
}

impl std::ops::Deref for CustomShape {
    type Target = dyn DynShape;
    fn deref(&self) -> &dyn DynShape {
        &*self.0
    }
}

impl PartialEq for CustomShape {
    fn eq(&self, other: &Self) -> bool {
        self.0.eq_dyn(&*other.0)
    }
}

/// The shapes added with [`register_shape`].
static REGISTERED: Registry<CustomShape> = Registry::new();

fn parse<'a, 'de, S: ShapePlugin>(
    d: &'a mut dyn erased_serde::Deserializer<'de>,
) -> Result<CustomShape, erased_serde::Error> {
    erased_serde::deserialize::<S>(d).map(CustomShape::new)
}

/// Makes shape `S` available to scenes as `Custom(S::TAG((...)))`; registering a tag again
/// replaces the earlier registration.
pub fn register_shape<S: ShapePlugin>() {
    REGISTERED.insert(S::TAG, parse::<S>);
}

impl Serialize for CustomShape {
    fn serialize<Z: Serializer>(&self, s: Z) -> Result<Z::Ok, Z::Error> {
        s.serialize_newtype_variant("CustomShape", 0, self.0.tag(), &*self.0)
    }
}

struct ShapeVisitor;

impl<'de> Visitor<'de> for ShapeVisitor {
    type Value = CustomShape;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a registered shape: its name with its parameters")
    }
    fn visit_enum<A: EnumAccess<'de>>(self, data: A) -> Result<CustomShape, A::Error> {
        let (tag, variant) = data.variant_seed(Tag)?;
        match REGISTERED.get(&tag) {
            Some(p) => variant.newtype_variant_seed(Seed(p)),
            None => Err(de::Error::unknown_variant(&tag, REGISTERED.known(&[]))),
        }
    }
}

impl<'de> Deserialize<'de> for CustomShape {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<CustomShape, D::Error> {
        d.deserialize_enum("CustomShape", &[], ShapeVisitor)
    }
}
