//! The round silo's floor: a flat annulus, a plate with a round hole, as a shape of the lab's
//! own through the [`ShapePlugin`] extension point (the core's shapes have no hole in a plate,
//! and a validation case needs no more than a scene plug-in).
//!
//! In its local frame the plate is `r ≤ ρ ≤ R`, `|y| ≤ h` with `ρ = √(x² + z²)`: a rectangle in
//! the `(ρ, y)` half-plane turned about the y axis, so its signed distance is the rectangle's,
//! exactly. It takes no part in a gradient (the case runs forward only), so it has no Hessian
//! and a scene with it refuses a tool gradient through it with the extension point's message.

use crate::error::FieldError;
use crate::math::sdf::{register_shape, ShapePlugin};
use glam::DVec3;
use serde::{Deserialize, Serialize};

/// A flat annulus about the local y axis: hole radius `r`, outer radius `R`, half thickness `h`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct OrificePlate {
    pub hole_radius: f64,
    pub outer_radius: f64,
    pub half_thickness: f64,
}

impl OrificePlate {
    /// The name a scene gives it: `Custom(OrificePlate((...)))`.
    pub const TAG_NAME: &'static str = "OrificePlate";
}

/// Makes the plate available to scenes (registering again is harmless).
pub fn register() {
    register_shape::<OrificePlate>();
}

impl ShapePlugin for OrificePlate {
    const TAG: &'static str = OrificePlate::TAG_NAME;

    fn sdf(&self, p: DVec3) -> (f64, DVec3) {
        let rho = p.x.hypot(p.z);
        // The radial direction; on the axis (inside the hole, where no grain's contact depends
        // on it) any horizontal direction.
        let (ex, ez) = if rho > 0.0 {
            (p.x / rho, p.z / rho)
        } else {
            (1.0, 0.0)
        };
        let mid = 0.5 * (self.hole_radius + self.outer_radius);
        let half_w = 0.5 * (self.outer_radius - self.hole_radius);
        let s_rho = if rho < mid { -1.0 } else { 1.0 };
        let s_y = if p.y < 0.0 { -1.0 } else { 1.0 };
        // The rectangle's distance in (ρ, y): a = |ρ − mid| − w, b = |y| − h.
        let (a, b) = ((rho - mid).abs() - half_w, p.y.abs() - self.half_thickness);
        let (ga, gb, d) = if a > 0.0 || b > 0.0 {
            let (qa, qb) = (a.max(0.0), b.max(0.0));
            let d = qa.hypot(qb);
            (qa / d, qb / d, d)
        } else if a > b {
            (1.0, 0.0, a)
        } else {
            (0.0, 1.0, b)
        };
        let n = DVec3::new(ga * s_rho * ex, gb * s_y, ga * s_rho * ez);
        (d, n)
    }

    fn bounding_radius(&self) -> f64 {
        self.outer_radius.hypot(self.half_thickness)
    }

    fn min_wall(&self) -> f64 {
        2.0 * self.half_thickness
    }

    fn lowest_local_point(&self) -> DVec3 {
        DVec3::new(self.hole_radius, -self.half_thickness, 0.0)
    }

    fn validate(&self) -> Result<(), FieldError> {
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !positive(self.hole_radius) {
            return Err(FieldError::new(
                "hole_radius",
                self.hole_radius.to_string(),
                "> 0 m",
            ));
        }
        if !(self.outer_radius.is_finite() && self.outer_radius > self.hole_radius) {
            return Err(FieldError::new(
                "outer_radius",
                self.outer_radius.to_string(),
                "> hole_radius",
            ));
        }
        if !positive(self.half_thickness) {
            return Err(FieldError::new(
                "half_thickness",
                self.half_thickness.to_string(),
                "> 0 m",
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PLATE: OrificePlate = OrificePlate {
        hole_radius: 0.01,
        outer_radius: 0.05,
        half_thickness: 0.0025,
    };

    /// Distances at points whose nearest surface point is known: in the hole, above the plate,
    /// beyond its rims and inside it.
    #[test]
    fn the_distance_is_the_rectangles_turned_about_the_axis() {
        let cases = [
            // On the axis in the plate's plane: the hole's rim is r away, outward is -ρ.
            (DVec3::new(0.0, 0.0, 0.0), 0.01, DVec3::new(-1.0, 0.0, 0.0)),
            (
                DVec3::new(0.0, 0.0, 0.004),
                0.006,
                DVec3::new(0.0, 0.0, -1.0),
            ),
            // Above the plate's middle, and below it.
            (DVec3::new(0.02, 0.01, 0.02), 0.0075, DVec3::Y),
            (DVec3::new(0.03, -0.005, 0.0), 0.0025, DVec3::NEG_Y),
            // Beyond the outer rim, and off the hole's upper edge (a corner: the diagonal).
            (DVec3::new(0.0, 0.0, 0.06), 0.01, DVec3::Z),
            (
                DVec3::new(0.007, 0.0065, 0.0),
                0.005,
                DVec3::new(-0.6, 0.8, 0.0),
            ),
            // Inside, nearer the top face than the hole's rim.
            (DVec3::new(0.0, 0.002, 0.02), -0.0005, DVec3::Y),
        ];
        for (p, d, n) in cases {
            let (phi, g) = PLATE.sdf(p);
            assert!((phi - d).abs() < 1e-15, "{p}: {phi} against {d}");
            assert!((g - n).length() < 1e-12, "{p}: {g} against {n}");
        }
    }

    /// The gradient is the distance's own (central differences off the medial surfaces), and a
    /// unit vector.
    #[test]
    fn the_normal_is_the_distances_gradient() {
        let mut rng = crate::util::SplitMix64(17);
        let mut r = |a: f64, b: f64| rng.uniform_in(a, b);
        let h = 1e-7;
        let mut checked = 0;
        for _ in 0..4000 {
            let p = DVec3::new(r(-0.07, 0.07), r(-0.02, 0.02), r(-0.07, 0.07));
            let (_, n) = PLATE.sdf(p);
            assert!((n.length() - 1.0).abs() < 1e-12, "{p}: {n}");
            let fd = DVec3::new(
                PLATE.sdf(p + DVec3::X * h).0 - PLATE.sdf(p - DVec3::X * h).0,
                PLATE.sdf(p + DVec3::Y * h).0 - PLATE.sdf(p - DVec3::Y * h).0,
                PLATE.sdf(p + DVec3::Z * h).0 - PLATE.sdf(p - DVec3::Z * h).0,
            ) / (2.0 * h);
            // Inside, the distance has ridges where two faces are equally near: skip those.
            let (rho, y) = (p.x.hypot(p.z), p.y.abs());
            let (a, b) = ((rho - 0.03).abs() - 0.02, y - 0.0025);
            if a < 0.0 && b < 0.0 && (a - b).abs() < 1e-5 || rho < 1e-5 {
                continue;
            }
            checked += 1;
            assert!((fd - n).length() < 1e-6, "{p}: fd {fd}, n {n}");
        }
        assert!(checked > 3900, "{checked}");
    }

    #[test]
    fn bad_dimensions_are_refused_with_their_field() {
        for (plate, field) in [
            (
                OrificePlate {
                    hole_radius: 0.0,
                    ..PLATE
                },
                "hole_radius",
            ),
            (
                OrificePlate {
                    outer_radius: 0.005,
                    ..PLATE
                },
                "outer_radius",
            ),
            (
                OrificePlate {
                    half_thickness: f64::NAN,
                    ..PLATE
                },
                "half_thickness",
            ),
        ] {
            let e = plate.validate().unwrap_err();
            assert_eq!(e.field, field, "{e:?}");
        }
        assert!(PLATE.validate().is_ok());
    }
}
