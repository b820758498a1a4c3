//! The spoon: a spherical-cap bowl shell and a capsule handle. Its SDF, Hessian, clearance
//! test, validation and mesh.

use super::primitives::{circle_distance_hessian, curvature, positive, sd_capsule};
use super::{sign, CLEAR_SLACK};
use crate::error::FieldError;
use crate::math::mesh::{arc, capsule_profile, revolve, Mesh};
use glam::{DMat3, DQuat, DVec3};

/// A spoon's dimensions (m), as the scene gives them.
#[derive(Clone, Copy, Debug)]
pub struct Spoon {
    pub bowl_radius: f64,
    pub bowl_depth: f64,
    pub thickness: f64,
    pub handle_length: f64,
    pub handle_radius: f64,
    pub handle_rise: f64,
}

/// Spherical shell of radius `r`, half thickness `t`, cut by the plane `y = h`, keeping `y < h`.
/// After Quílez's "cut hollow sphere".
#[inline]
pub fn sd_cut_hollow_sphere(p: DVec3, r: f64, h: f64, t: f64) -> (f64, DVec3) {
    let w = (r * r - h * h).max(0.0).sqrt();
    let rho = (p.x * p.x + p.z * p.z).sqrt();
    let radial = if rho > 0.0 {
        DVec3::new(p.x / rho, 0.0, p.z / rho)
    } else {
        DVec3::X
    };
    let (g_rho, g_y, d) = if h * rho < w * p.y {
        let (a, b) = (rho - w, p.y - h);
        let l = (a * a + b * b).sqrt().max(1e-300);
        (a / l, b / l, l)
    } else {
        let l = (rho * rho + p.y * p.y).sqrt().max(1e-300);
        let s = sign(l - r);
        (s * rho / l, s * p.y / l, (l - r).abs())
    };
    (d - t, radial * g_rho + DVec3::new(0.0, g_y, 0.0))
}

/// A spoon's rim and handle, in the spoon's frame: the height `h = bowl_depth − r` of the cut
/// plane above the sphere centre, the rim point `a = (√(r² − h²), h, 0)` where the handle
/// leaves, and the handle's run `d = (handle_length, handle_rise, 0)`: the handle's axis is the
/// segment `a → a + d`.
#[inline(always)]
pub fn spoon_rim_and_handle(
    bowl_radius: f64,
    bowl_depth: f64,
    handle_length: f64,
    handle_rise: f64,
) -> (f64, DVec3, DVec3) {
    let h = bowl_depth - bowl_radius;
    let w = (bowl_radius * bowl_radius - h * h).max(0.0).sqrt();
    (
        h,
        DVec3::new(w, h, 0.0),
        DVec3::new(handle_length, handle_rise, 0.0),
    )
}

/// What [`Spoon::sdf_dshape`] gives.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SdfShapeGrad {
    pub phi: f64,
    /// `∂φ/∂p` in the spoon's frame.
    pub grad: DVec3,
    /// `∂φ/∂(bowl_radius, bowl_depth, handle_length)`.
    pub dshape: [f64; 3],
    pub shell_interior: bool,
}

impl Spoon {
    /// The bowl's and the handle's SDFs; the spoon is the nearer.
    #[inline]
    fn parts(&self, p: DVec3) -> ((f64, DVec3), (f64, DVec3), f64, DVec3, DVec3) {
        let (h, a, d) = spoon_rim_and_handle(
            self.bowl_radius,
            self.bowl_depth,
            self.handle_length,
            self.handle_rise,
        );
        let bowl = sd_cut_hollow_sphere(p, self.bowl_radius, h, 0.5 * self.thickness);
        let b = a + d;
        let handle = sd_capsule(p, a, b, self.handle_radius);
        (bowl, handle, h, a, b)
    }

    #[inline]
    pub fn sdf(&self, p: DVec3) -> (f64, DVec3) {
        let (bowl, handle, ..) = self.parts(p);
        if bowl.0 <= handle.0 {
            bowl
        } else {
            handle
        }
    }

    /// The bowl's φ is at least |p| − r − t/2 (its rim circle and its sphere both lie on the
    /// sphere of radius r); the handle's at least |p − m| − ℓ/2 − r_h with m the middle of its
    /// segment and ℓ its length. The spoon is their minimum.
    #[inline(always)]
    pub fn surely_clear(&self, p: DVec3, s: f64) -> bool {
        let s = s + CLEAR_SLACK;
        let bowl = self.bowl_radius + 0.5 * self.thickness + s;
        if p.length_squared() <= bowl * bowl {
            return false;
        }
        let (_, a, d) = spoon_rim_and_handle(
            self.bowl_radius,
            self.bowl_depth,
            self.handle_length,
            self.handle_rise,
        );
        let half = 0.5 * d;
        let m = a + half;
        let handle = half.length() + self.handle_radius + s;
        (p - m).length_squared() > handle * handle
    }

    /// The spoon's SDF at `p` with its spatial gradient and `∂φ/∂(bowl_radius, bowl_depth,
    /// handle_length)`, of the branch [`Spoon::sdf`] takes. `shell_interior` says `p` is inside
    /// the bowl's shell on its sphere part, where `φ = |‖p‖ − r| − t/2` has a kink at the
    /// mid-surface: a minimum of φ there is `−t/2` whatever the shape and pose.
    pub fn sdf_dshape(&self, p: DVec3) -> SdfShapeGrad {
        let (bowl, handle, h, a, b) = self.parts(p);
        let r = self.bowl_radius;
        let w = a.x;
        // The rim point (w, h) moves with r and the depth D: h = D − r, w² = r² − h².
        let (dh, dw) = if w > 0.0 {
            ([-1.0, 1.0], [(r + h) / w, -h / w])
        } else {
            ([-1.0, 1.0], [0.0, 0.0])
        };
        if bowl.0 <= handle.0 {
            let rho = (p.x * p.x + p.z * p.z).sqrt();
            let mut d = [0.0; 3];
            let mut shell_interior = false;
            if h * rho < w * p.y {
                // Distance to the rim circle.
                let (ra, rb) = (rho - w, p.y - h);
                let l = (ra * ra + rb * rb).sqrt().max(1e-300);
                for k in 0..2 {
                    d[k] = (-ra * dw[k] - rb * dh[k]) / l;
                }
            } else {
                let l = p.length();
                d[0] = -sign(l - r);
                shell_interior = bowl.0 < 0.0;
            }
            SdfShapeGrad {
                phi: bowl.0,
                grad: bowl.1,
                dshape: d,
                shell_interior,
            }
        } else {
            // Distance to the axis segment a → b: only the nearest point c = a + s·(b − a)
            // moves (the envelope theorem), with a and b − a = (handle_length, rise, 0).
            let ab = b - a;
            let s = ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0);
            let n = handle.1;
            let da = [DVec3::new(dw[0], dh[0], 0.0), DVec3::new(dw[1], dh[1], 0.0)];
            SdfShapeGrad {
                phi: handle.0,
                grad: n,
                dshape: [-n.dot(da[0]), -n.dot(da[1]), -n.x * s],
                shell_interior: false,
            }
        }
    }

    /// The Hessian of the branch [`Spoon::sdf`] takes at `p`.
    pub fn hessian(&self, p: DVec3) -> DMat3 {
        let (bowl, handle, h, a, b) = self.parts(p);
        if bowl.0 <= handle.0 {
            let rho = (p.x * p.x + p.z * p.z).sqrt();
            if h * rho < a.x * p.y {
                circle_distance_hessian(p, a.x, h)
            } else {
                let l = p.length();
                let s = if l < self.bowl_radius { -1.0 } else { 1.0 };
                curvature(DMat3::IDENTITY, p / l, l) * s
            }
        } else {
            let ab = b - a;
            let t = (p - a).dot(ab) / ab.length_squared();
            let c = a + t.clamp(0.0, 1.0) * ab;
            let proj = if t > 0.0 && t < 1.0 {
                let e = ab.normalize();
                DMat3::IDENTITY - DMat3::from_cols(e * e.x, e * e.y, e * e.z)
            } else {
                DMat3::IDENTITY
            };
            curvature(proj, handle.1, (p - c).length())
        }
    }

    pub fn bounding_radius(&self) -> f64 {
        self.bowl_radius
            + self.handle_length.hypot(self.handle_rise)
            + self.handle_radius
            + self.thickness
    }

    pub fn validate(&self) -> Result<(), FieldError> {
        positive("bowl_radius", self.bowl_radius)?;
        positive("bowl_depth", self.bowl_depth)?;
        positive("thickness", self.thickness)?;
        positive("handle_length", self.handle_length)?;
        positive("handle_radius", self.handle_radius)?;
        if self.bowl_depth > 2.0 * self.bowl_radius {
            return Err(FieldError::new(
                "bowl_depth",
                self.bowl_depth.to_string(),
                format!("<= 2·bowl_radius = {} m", 2.0 * self.bowl_radius),
            ));
        }
        if !self.handle_rise.is_finite() {
            return Err(FieldError::new(
                "handle_rise",
                self.handle_rise.to_string(),
                "a finite number",
            ));
        }
        Ok(())
    }

    /// The bowl revolved from its profile, and the handle as a capsule.
    pub fn mesh(&self) -> Mesh {
        use std::f64::consts::FRAC_PI_2;
        let (h, a, d) = spoon_rim_and_handle(
            self.bowl_radius,
            self.bowl_depth,
            self.handle_length,
            self.handle_rise,
        );
        let rim = (h / self.bowl_radius).clamp(-1.0, 1.0).asin();
        let t = 0.5 * self.thickness;
        let mut profile = arc(self.bowl_radius + t, 0.0, -FRAC_PI_2, rim, 12);
        profile.extend(arc(self.bowl_radius - t, 0.0, rim, -FRAC_PI_2, 12));
        let mut m = revolve(&profile);
        let handle = revolve(&capsule_profile(0.5 * d.length(), self.handle_radius)).transformed(
            DQuat::from_rotation_arc(DVec3::Y, d.normalize()),
            a + 0.5 * d,
        );
        m.append(handle);
        m
    }
}
