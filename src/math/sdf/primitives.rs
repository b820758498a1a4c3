//! The primitive shapes, each with its SDF, Hessian, bounding radius, lowest point, validation
//! and mesh: plane, box, sphere, capsule and cylinder. The capsule and cylinder functions also
//! build the cup and the spoon.

use super::sign;
use crate::error::FieldError;
use crate::math::mesh::{arc, box_mesh, capsule_profile, revolve, Mesh};
use glam::{DMat3, DQuat, DVec3};

/// Box of half extents `h`. Inside, the normal is the nearest face (ties: x, then y, then z),
/// matching the Taichi reference benchmark.
#[inline]
pub fn sd_box(p: DVec3, h: DVec3) -> (f64, DVec3) {
    let d = p.abs() - h;
    let o = d.max(DVec3::ZERO);
    let dmax = d.max_element();
    if dmax > 0.0 {
        let len = o.length();
        let s = DVec3::new(sign(p.x), sign(p.y), sign(p.z));
        (len, o * s / len)
    } else if d.x >= d.y && d.x >= d.z {
        (d.x, DVec3::new(sign(p.x), 0.0, 0.0))
    } else if d.y >= d.z {
        (d.y, DVec3::new(0.0, sign(p.y), 0.0))
    } else {
        (d.z, DVec3::new(0.0, 0.0, sign(p.z)))
    }
}

#[inline]
pub fn sd_sphere(p: DVec3, r: f64) -> (f64, DVec3) {
    let l = p.length();
    let n = if l > 0.0 { p / l } else { DVec3::Y };
    (l - r, n)
}

#[inline]
pub fn sd_capsule_y(p: DVec3, half_length: f64, r: f64) -> (f64, DVec3) {
    let c = DVec3::new(0.0, p.y.clamp(-half_length, half_length), 0.0);
    sd_sphere(p - c, r)
}

/// Capsule between two points `a` and `b`.
#[inline]
pub fn sd_capsule(p: DVec3, a: DVec3, b: DVec3, r: f64) -> (f64, DVec3) {
    let ab = b - a;
    let t = ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0);
    sd_sphere(p - (a + t * ab), r)
}

/// Capped cylinder along y, centred at `(0, cy, 0)`.
#[inline]
pub fn sd_cylinder_y(p: DVec3, cy: f64, r: f64, hh: f64) -> (f64, DVec3) {
    let rho = (p.x * p.x + p.z * p.z).sqrt();
    let radial = if rho > 0.0 {
        DVec3::new(p.x / rho, 0.0, p.z / rho)
    } else {
        DVec3::X
    };
    let y = p.y - cy;
    let axial = DVec3::new(0.0, sign(y), 0.0);
    let (dx, dy) = (rho - r, y.abs() - hh);
    if dx > 0.0 && dy > 0.0 {
        let l = (dx * dx + dy * dy).sqrt();
        (l, (radial * dx + axial * dy) / l)
    } else if dx > dy {
        (dx, radial)
    } else {
        (dy, axial)
    }
}

/// The distance `ρ` of `p` from the y axis, and the radial and azimuthal unit vectors there
/// (`None` on the axis, where both are undefined).
#[inline]
fn cylindrical_frame(p: DVec3) -> Option<(f64, DVec3, DVec3)> {
    let rho = (p.x * p.x + p.z * p.z).sqrt();
    if rho == 0.0 {
        return None;
    }
    let radial = DVec3::new(p.x / rho, 0.0, p.z / rho);
    Some((rho, radial, DVec3::new(-radial.z, 0.0, radial.x)))
}

/// The outer product `a·bᵀ`.
#[inline]
fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

/// Hessian of the distance from `p` to the horizontal circle of radius `r` at height `y0` (about
/// the y axis): `(P − n·nᵀ)/d + (ρ − r)/(d·ρ)·θ̂θ̂ᵀ`, `P` the projector on the (ρ̂, ŷ) plane.
pub fn circle_distance_hessian(p: DVec3, r: f64, y0: f64) -> DMat3 {
    let Some((rho, radial, theta)) = cylindrical_frame(p) else {
        return DMat3::ZERO;
    };
    let (dx, dy) = (rho - r, p.y - y0);
    let d = (dx * dx + dy * dy).sqrt();
    if d == 0.0 {
        return DMat3::ZERO;
    }
    let n = (radial * dx + DVec3::Y * dy) / d;
    (outer(radial, radial) + outer(DVec3::Y, DVec3::Y) - outer(n, n)) * (1.0 / d)
        + outer(theta, theta) * (dx / (d * rho))
}

/// Hessian of [`sd_cylinder_y`]: on the side branch `θ̂θ̂ᵀ/ρ`, on the flat caps 0, and outside
/// the rim the Hessian of the distance to a circle, `(P − n·nᵀ)/d + (ρ − r)/(d·ρ)·θ̂θ̂ᵀ` with `P`
/// the projector on the (ρ̂, ŷ) plane.
pub fn cylinder_hessian(p: DVec3, cy: f64, r: f64, hh: f64) -> DMat3 {
    let Some((rho, radial, theta)) = cylindrical_frame(p) else {
        return DMat3::ZERO;
    };
    let y = p.y - cy;
    let (dx, dy) = (rho - r, y.abs() - hh);
    if dx > 0.0 && dy > 0.0 {
        let d = (dx * dx + dy * dy).sqrt();
        let axial = DVec3::new(0.0, y.signum(), 0.0);
        let n = (radial * dx + axial * dy) / d;
        (outer(radial, radial) + outer(DVec3::Y, DVec3::Y) - outer(n, n)) * (1.0 / d)
            + outer(theta, theta) * (dx / (d * rho))
    } else if dx > dy {
        outer(theta, theta) * (1.0 / rho)
    } else {
        DMat3::ZERO
    }
}

/// `(P − n·nᵀ)/dist`: the Hessian of a distance `dist` from a point, line or plane, `P` the
/// projector onto the directions along which the distance varies.
#[inline]
pub(super) fn curvature(proj: DMat3, n: DVec3, dist: f64) -> DMat3 {
    if dist > 0.0 {
        (proj - outer(n, n)) * (1.0 / dist)
    } else {
        DMat3::ZERO
    }
}

/// The plane's SDF: the half-space below the plane through the origin with outward `normal`.
#[inline]
pub fn plane_sdf(p: DVec3, normal: [f64; 3]) -> (f64, DVec3) {
    let n = DVec3::from(normal).normalize();
    (p.dot(n), n)
}

/// Hessian of [`sd_box`]: 0 inside, the distance to an edge or corner outside.
pub fn box_hessian(p: DVec3, half_extents: [f64; 3]) -> DMat3 {
    let h = DVec3::from(half_extents);
    let d = p.abs() - h;
    if d.max_element() <= 0.0 {
        return DMat3::ZERO;
    }
    let (phi, n) = sd_box(p, h);
    let act = DVec3::select(d.cmpgt(DVec3::ZERO), DVec3::ONE, DVec3::ZERO);
    curvature(DMat3::from_diagonal(act), n, phi)
}

/// Hessian of [`sd_sphere`].
pub fn sphere_hessian(p: DVec3, radius: f64) -> DMat3 {
    let (phi, n) = sd_sphere(p, radius);
    curvature(DMat3::IDENTITY, n, phi + radius)
}

/// Hessian of [`sd_capsule_y`].
pub fn capsule_hessian(p: DVec3, half_length: f64, radius: f64) -> DMat3 {
    let (phi, n) = sd_capsule_y(p, half_length, radius);
    let proj = if p.y.abs() < half_length {
        DMat3::from_diagonal(DVec3::new(1.0, 0.0, 1.0))
    } else {
        DMat3::IDENTITY
    };
    curvature(proj, n, phi + radius)
}

/// `> 0 m` check of a length field.
/// Largest length of a shape's dimension (m): a lab's tools and containers, with room to
/// spare; a larger one is a unit slip, and at 1e308 m the shape's bounds overflow.
pub const MAX_SHAPE_LENGTH: f64 = 100.0;

pub(super) fn positive(field: &'static str, v: f64) -> Result<(), FieldError> {
    if v > 0.0 && v <= MAX_SHAPE_LENGTH {
        Ok(())
    } else {
        Err(FieldError::new(
            field,
            crate::error::num(v),
            format!("in (0, {MAX_SHAPE_LENGTH}] m"),
        ))
    }
}

/// A plane's normal must be a non-zero vector.
pub fn plane_validate(normal: [f64; 3]) -> Result<(), FieldError> {
    let n = DVec3::from(normal);
    if n.length() <= 0.0 || !n.is_finite() {
        return Err(FieldError::new(
            "normal",
            format!("{normal:?}"),
            "a non-zero vector",
        ));
    }
    Ok(())
}

/// A thin slab standing for the plane in recordings.
pub fn plane_mesh(normal: [f64; 3]) -> Mesh {
    let n = DVec3::from(normal).normalize();
    let rot = DQuat::from_rotation_arc(DVec3::Y, n);
    box_mesh(DVec3::new(1.0, 1e-4, 1.0)).transformed(rot, DVec3::ZERO)
}

pub fn sphere_mesh(radius: f64) -> Mesh {
    use std::f64::consts::FRAC_PI_2;
    revolve(&arc(radius, 0.0, -FRAC_PI_2, FRAC_PI_2, 16))
}

pub fn capsule_mesh(half_length: f64, radius: f64) -> Mesh {
    revolve(&capsule_profile(half_length, radius))
}

pub fn cylinder_mesh(radius: f64, half_height: f64) -> Mesh {
    revolve(&[
        (0.0, -half_height),
        (radius, -half_height),
        (radius, half_height),
        (0.0, half_height),
    ])
}
