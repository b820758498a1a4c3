//! Analytic signed distance functions in a shape's local frame, with their gradients.
//!
//! Every function returns `(φ, ∇φ)`: `φ < 0` inside the solid, `|∇φ| = 1` wherever the
//! gradient is defined. Composite shapes (cup, spoon) combine primitives with `min`/`max`; the
//! gradient is that of the active branch (a kink where branches tie, documented for the adjoint).
//!
//! One place per shape: each built-in shape's SDF, Hessian, clearance test, bounding radius,
//! validation and mesh sit together in its file ([`primitives`], [`cup`], [`spoon`]), and
//! [`Shape`] dispatches to them here. A program adds a shape of its own by implementing
//! [`ShapePlugin`] and calling [`register_shape`]; a scene then writes it
//! `Custom(Tag((parameters...)))` (`tests/extension_points.rs` does this with a torus).

pub mod cup;
pub mod custom;
pub mod primitives;
pub mod spatula;
pub mod spoon;
#[cfg(test)]
mod tests;

pub use cup::{cup_fillet, cup_hessian, cup_sdf, Cup};
pub use custom::{register_shape, CustomShape, ShapePlugin};
pub use primitives::{
    circle_distance_hessian, cylinder_hessian, sd_box, sd_capsule, sd_capsule_y, sd_cylinder_y,
    sd_sphere,
};
pub use spatula::Spatula;
pub use spoon::{sd_cut_hollow_sphere, spoon_rim_and_handle, Spoon};

use crate::error::FieldError;
use crate::math::mesh::Mesh;
use glam::{DMat3, DVec3};
use primitives::positive;
use serde::{Deserialize, Serialize};

/// A rigid shape, in SI units, described in its local frame.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub enum Shape {
    /// Half-space below the plane through the origin with the given outward normal.
    Plane { normal: [f64; 3] },
    /// Axis-aligned box centred at the origin.
    Box { half_extents: [f64; 3] },
    /// Sphere centred at the origin.
    Sphere { radius: f64 },
    /// Capsule along local y: segment from `-half_length` to `+half_length`.
    Capsule { half_length: f64, radius: f64 },
    /// Capped cylinder along local y, centred at the origin.
    Cylinder { radius: f64, half_height: f64 },
    /// Hollow cylinder with a floor; origin at the centre of the bottom face, open at `y = height`.
    /// The cavity's bottom edge is rounded with radius `fillet_radius` (default: the wall
    /// thickness; see [`cup_sdf`] for why a cup needs one).
    Cup {
        outer_radius: f64,
        height: f64,
        wall_thickness: f64,
        floor_thickness: f64,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        fillet_radius: Option<f64>,
    },
    /// Spherical-cap bowl shell plus a capsule handle. Origin at the sphere centre; the bowl
    /// opens towards +y and reaches `bowl_depth` up from its lowest point at `y = -bowl_radius`;
    /// the handle leaves the rim along +x, rising by `handle_rise` over `handle_length`.
    Spoon {
        bowl_radius: f64,
        bowl_depth: f64,
        thickness: f64,
        handle_length: f64,
        handle_radius: f64,
        #[serde(default)]
        handle_rise: f64,
    },
    /// A thin rectangular blade and a capsule handle rising from the middle of its top edge,
    /// for pushing and pulling powder. Origin at the middle of the blade's bottom edge; the
    /// blade spans local x and y, its faces look along ±z.
    Spatula {
        blade_width: f64,
        blade_height: f64,
        thickness: f64,
        handle_length: f64,
        handle_radius: f64,
    },
    /// A shape a program registered ([`register_shape`]), with its parameters.
    Custom(CustomShape),
}

/// Slack of [`Shape::surely_clear`], in metres: many orders of magnitude above the round-off of
/// lengths of order 0.1 m in f64 (1e-17 m), and far below any physical clearance.
pub const CLEAR_SLACK: f64 = 1e-12;

#[inline(always)]
fn sign(x: f64) -> f64 {
    if x < 0.0 {
        -1.0
    } else {
        1.0
    }
}

impl Shape {
    /// The spoon's dimensions, if it is one.
    #[inline(always)]
    pub fn spoon(&self) -> Option<Spoon> {
        match *self {
            Shape::Spoon {
                bowl_radius,
                bowl_depth,
                thickness,
                handle_length,
                handle_radius,
                handle_rise,
            } => Some(Spoon {
                bowl_radius,
                bowl_depth,
                thickness,
                handle_length,
                handle_radius,
                handle_rise,
            }),
            _ => None,
        }
    }

    /// The spatula's dimensions, if it is one.
    #[inline(always)]
    pub fn spatula(&self) -> Option<Spatula> {
        match *self {
            Shape::Spatula {
                blade_width,
                blade_height,
                thickness,
                handle_length,
                handle_radius,
            } => Some(Spatula {
                blade_width,
                blade_height,
                thickness,
                handle_length,
                handle_radius,
            }),
            _ => None,
        }
    }

    /// The spoon shape of these dimensions.
    pub fn from_spoon(s: &Spoon) -> Shape {
        Shape::Spoon {
            bowl_radius: s.bowl_radius,
            bowl_depth: s.bowl_depth,
            thickness: s.thickness,
            handle_length: s.handle_length,
            handle_radius: s.handle_radius,
            handle_rise: s.handle_rise,
        }
    }

    /// The cup's dimensions, if it is one.
    #[inline(always)]
    fn cup(&self) -> Option<Cup> {
        match *self {
            Shape::Cup {
                outer_radius,
                height,
                wall_thickness,
                floor_thickness,
                fillet_radius,
            } => Some(Cup {
                outer_radius,
                height,
                wall_thickness,
                floor_thickness,
                fillet_radius,
            }),
            _ => None,
        }
    }

    /// The shape's name in messages.
    pub fn name(&self) -> &'static str {
        match self {
            Shape::Plane { .. } => "plane",
            Shape::Box { .. } => "box",
            Shape::Sphere { .. } => "sphere",
            Shape::Capsule { .. } => "capsule",
            Shape::Cylinder { .. } => "cylinder",
            Shape::Cup { .. } => "cup",
            Shape::Spoon { .. } => "spoon",
            Shape::Spatula { .. } => "spatula",
            Shape::Custom(c) => c.tag(),
        }
    }

    /// Signed distance and gradient at the local point `p`.
    pub fn sdf(&self, p: DVec3) -> (f64, DVec3) {
        match *self {
            Shape::Plane { normal } => primitives::plane_sdf(p, normal),
            Shape::Box { half_extents } => sd_box(p, half_extents.into()),
            Shape::Sphere { radius } => sd_sphere(p, radius),
            Shape::Capsule {
                half_length,
                radius,
            } => sd_capsule_y(p, half_length, radius),
            Shape::Cylinder {
                radius,
                half_height,
            } => sd_cylinder_y(p, 0.0, radius, half_height),
            Shape::Cup { .. } => self.cup().expect("a cup").sdf(p),
            Shape::Spoon { .. } => self.spoon().expect("a spoon").sdf(p),
            Shape::Spatula { .. } => self.spatula().expect("a spatula").sdf(p),
            Shape::Custom(ref c) => c.sdf(p),
        }
    }

    /// Whether `φ(p) > s` for certain at the local point `p`, by a test cheaper than
    /// [`Shape::sdf`]: `false` when the shape has no such test or the test cannot tell. The
    /// margin [`CLEAR_SLACK`] lies far above the round-off of either computation, so the test
    /// says "clear" only where `sdf` does too: callers that skip on it get the same bits.
    #[inline(always)]
    pub fn surely_clear(&self, p: DVec3, s: f64) -> bool {
        match *self {
            Shape::Cup { .. } => self.cup().expect("a cup").surely_clear(p, s),
            Shape::Spoon { .. } => self.spoon().expect("a spoon").surely_clear(p, s),
            _ => false,
        }
    }

    /// Hessian `∂²φ/∂p²` at the local point `p` (the derivative of the normal), for the shapes
    /// whose adjoint w.r.t. a moving pose is implemented; `None` for the others. Piecewise: the
    /// Hessian of the branch `sdf` takes at `p` (kinks between branches are one-sided).
    pub fn sdf_hessian(&self, p: DVec3) -> Option<DMat3> {
        match *self {
            Shape::Plane { .. } => Some(DMat3::ZERO),
            Shape::Box { half_extents } => Some(primitives::box_hessian(p, half_extents)),
            Shape::Sphere { radius } => Some(primitives::sphere_hessian(p, radius)),
            Shape::Capsule {
                half_length,
                radius,
            } => Some(primitives::capsule_hessian(p, half_length, radius)),
            Shape::Cylinder {
                radius,
                half_height,
            } => Some(cylinder_hessian(p, 0.0, radius, half_height)),
            Shape::Cup { .. } => Some(self.cup().expect("a cup").hessian(p)),
            Shape::Spoon { .. } => Some(self.spoon().expect("a spoon").hessian(p)),
            Shape::Spatula { .. } => Some(self.spatula().expect("a spatula").hessian(p)),
            Shape::Custom(ref c) => c.sdf_hessian(p),
        }
    }

    /// Radius of a sphere about the local origin that contains the solid (infinite for a plane).
    pub fn bounding_radius(&self) -> f64 {
        match *self {
            Shape::Plane { .. } => f64::INFINITY,
            Shape::Box { half_extents } => DVec3::from(half_extents).length(),
            Shape::Sphere { radius } => radius,
            Shape::Capsule {
                half_length,
                radius,
            } => half_length + radius,
            Shape::Cylinder {
                radius,
                half_height,
            } => radius.hypot(half_height),
            Shape::Cup {
                outer_radius,
                height,
                ..
            } => outer_radius.hypot(height),
            Shape::Spoon { .. } => self.spoon().expect("a spoon").bounding_radius(),
            Shape::Spatula { .. } => self.spatula().expect("a spatula").bounding_radius(),
            Shape::Custom(ref c) => c.bounding_radius(),
        }
    }

    /// Thinnest wall of the shape, for the leak check of the stability guard.
    pub fn min_wall(&self) -> f64 {
        match *self {
            Shape::Cup {
                wall_thickness,
                floor_thickness,
                ..
            } => wall_thickness.min(floor_thickness),
            Shape::Spoon {
                thickness,
                handle_radius,
                ..
            } => thickness.min(2.0 * handle_radius),
            Shape::Spatula { .. } => self.spatula().expect("a spatula").min_wall(),
            Shape::Custom(ref c) => c.min_wall(),
            _ => f64::INFINITY,
        }
    }

    /// The lowest point of the shape in its local frame (where a skill's descent is measured
    /// from).
    pub fn lowest_local_point(&self) -> DVec3 {
        match *self {
            Shape::Spoon {
                bowl_radius,
                thickness,
                ..
            } => DVec3::new(0.0, -bowl_radius - 0.5 * thickness, 0.0),
            Shape::Sphere { radius } => DVec3::new(0.0, -radius, 0.0),
            Shape::Box { half_extents } => DVec3::new(0.0, -half_extents[1], 0.0),
            Shape::Capsule {
                half_length,
                radius,
            } => DVec3::new(0.0, -half_length - radius, 0.0),
            Shape::Cylinder { half_height, .. } => DVec3::new(0.0, -half_height, 0.0),
            Shape::Cup { .. } | Shape::Plane { .. } | Shape::Spatula { .. } => DVec3::ZERO,
            Shape::Custom(ref c) => c.lowest_local_point(),
        }
    }

    /// Checks the shape's dimensions; an error names the field, its value and the valid range.
    pub fn validate(&self) -> Result<(), FieldError> {
        match *self {
            Shape::Plane { normal } => primitives::plane_validate(normal),
            Shape::Box { half_extents } => {
                for h in half_extents {
                    positive("half_extents", h)?;
                }
                Ok(())
            }
            Shape::Sphere { radius } => positive("radius", radius),
            Shape::Capsule {
                half_length,
                radius,
            } => {
                positive("half_length", half_length)?;
                positive("radius", radius)
            }
            Shape::Cylinder {
                radius,
                half_height,
            } => {
                positive("radius", radius)?;
                positive("half_height", half_height)
            }
            Shape::Cup { .. } => self.cup().expect("a cup").validate(),
            Shape::Spoon { .. } => self.spoon().expect("a spoon").validate(),
            Shape::Spatula { .. } => self.spatula().expect("a spatula").validate(),
            Shape::Custom(ref c) => c.validate(),
        }
    }

    /// Triangle mesh of the shape in its local frame, for recordings.
    pub fn mesh(&self) -> Mesh {
        match *self {
            Shape::Plane { normal } => primitives::plane_mesh(normal),
            Shape::Box { half_extents } => crate::math::mesh::box_mesh(half_extents.into()),
            Shape::Sphere { radius } => primitives::sphere_mesh(radius),
            Shape::Capsule {
                half_length,
                radius,
            } => primitives::capsule_mesh(half_length, radius),
            Shape::Cylinder {
                radius,
                half_height,
            } => primitives::cylinder_mesh(radius, half_height),
            Shape::Cup { .. } => self.cup().expect("a cup").mesh(),
            Shape::Spoon { .. } => self.spoon().expect("a spoon").mesh(),
            Shape::Spatula { .. } => self.spatula().expect("a spatula").mesh(),
            Shape::Custom(ref c) => c.mesh(),
        }
    }
}
