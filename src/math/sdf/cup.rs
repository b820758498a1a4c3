//! The cup: a hollow cylinder with a floor, its cavity's bottom edge rounded. Its SDF, Hessian,
//! clearance test, validation and mesh.

use super::primitives::{circle_distance_hessian, cylinder_hessian, positive, sd_cylinder_y};
use super::CLEAR_SLACK;
use crate::error::FieldError;
use crate::math::mesh::{revolve, Mesh};
use glam::{DMat3, DVec3};

/// A cup's dimensions (m), as the scene gives them.
#[derive(Clone, Copy, Debug)]
pub struct Cup {
    pub outer_radius: f64,
    pub height: f64,
    pub wall_thickness: f64,
    pub floor_thickness: f64,
    pub fillet_radius: Option<f64>,
}

/// The radius of a cup's fillet: the one given, or the wall thickness.
#[inline(always)]
pub fn cup_fillet(wall_thickness: f64, fillet_radius: Option<f64>) -> f64 {
    fillet_radius.unwrap_or(wall_thickness)
}

/// A cup's SDF: the cup is the solid cylinder of radius `R` and height `H` less an open
/// cylindrical cavity of radius `r = R − wall` above the floor `y = f`, and the cavity's bottom
/// edge is rounded with radius `k`. With `a = r − ρ` (distance to the inner wall), `b = y − f`
/// (height above the floor) and `c = y − H` (height above the rim):
///
/// - above the cavity (`a > 0`, `c > 0`) the nearest point is the rim's inner edge, `φ = √(a² + c²)`;
/// - in the cavity's corner (`a < k`, `b < k`) the nearest point is on the fillet, a quarter
///   circle of radius `k` about `(a, b) = (k, k)`: `ψ = k − √((k − a)² + (k − b)²)`;
/// - elsewhere in the cavity `ψ = min(a, b)`, and the cup is `max(outer cylinder, ψ)`.
///
/// Why: without the fillet and the rim edge the cup is `max(outer, −cavity)`, whose normal
/// jumps between the wall's and the floor's on the corner's bisector (and between the rim's
/// top and the wall's above the rim). A particle resting in the corner was projected against
/// the wall in one substep and the floor in the next, a chatter whose phase the last bit of
/// the state decided: two rollouts 1e-7 apart in Θ parted by a whole particle velocity. With
/// both, the normal is continuous wherever `φ < k` outside the solid (farther out, the corner's
/// bisector is the cavity's medial axis, a crease of any distance field, and beyond the reach
/// of particle contact).
#[inline]
pub fn cup_sdf(cup: &Cup, p: DVec3) -> (f64, DVec3) {
    let (outer_radius, height, wall, floor, k) = cup.dims();
    let rho = (p.x * p.x + p.z * p.z).sqrt();
    let radial = if rho > 0.0 {
        DVec3::new(p.x / rho, 0.0, p.z / rho)
    } else {
        DVec3::X
    };
    let (a, b, c) = (outer_radius - wall - rho, p.y - floor, p.y - height);
    if a > 0.0 && c > 0.0 {
        let l = a.hypot(c);
        return (l, (DVec3::Y * c - radial * a) / l);
    }
    let cavity = if a < k && b < k {
        let (u, v) = (k - a, k - b);
        let l = u.hypot(v);
        (k - l, (DVec3::Y * v - radial * u) / l)
    } else if a <= b {
        (a, -radial)
    } else {
        (b, DVec3::Y)
    };
    let outer = sd_cylinder_y(p, 0.5 * height, outer_radius, 0.5 * height);
    if outer.0 >= cavity.0 {
        outer
    } else {
        cavity
    }
}

/// Hessian of [`cup_sdf`], branch by branch.
pub fn cup_hessian(cup: &Cup, p: DVec3) -> DMat3 {
    let (outer_radius, height, wall, floor, k) = cup.dims();
    let rho = (p.x * p.x + p.z * p.z).sqrt();
    let r = outer_radius - wall;
    let (a, b, c) = (r - rho, p.y - floor, p.y - height);
    if a > 0.0 && c > 0.0 {
        return circle_distance_hessian(p, r, height);
    }
    let (phi, _) = cup_sdf(cup, p);
    let outer = sd_cylinder_y(p, 0.5 * height, outer_radius, 0.5 * height);
    if outer.0 >= phi {
        return cylinder_hessian(p, 0.5 * height, outer_radius, 0.5 * height);
    }
    if a < k && b < k {
        // ψ = k − distance to the fillet's centre circle (radius r − k at height f + k).
        circle_distance_hessian(p, r - k, floor + k) * -1.0
    } else if a <= b && rho > 0.0 {
        // ψ = r − ρ: −θ̂θ̂ᵀ/ρ.
        let theta = DVec3::new(-p.z / rho, 0.0, p.x / rho);
        DMat3::from_cols(theta * theta.x, theta * theta.y, theta * theta.z) * (-1.0 / rho)
    } else {
        DMat3::ZERO
    }
}

impl Cup {
    /// The fillet's radius.
    #[inline(always)]
    fn fillet(&self) -> f64 {
        cup_fillet(self.wall_thickness, self.fillet_radius)
    }

    /// `(R, H, wall, floor, k)`: the outer radius, height, wall and floor thickness and fillet.
    #[inline(always)]
    fn dims(&self) -> (f64, f64, f64, f64, f64) {
        let (w, f) = (self.wall_thickness, self.floor_thickness);
        (self.outer_radius, self.height, w, f, self.fillet())
    }

    #[inline]
    pub fn sdf(&self, p: DVec3) -> (f64, DVec3) {
        cup_sdf(self, p)
    }

    pub fn hessian(&self, p: DVec3) -> DMat3 {
        cup_hessian(self, p)
    }

    /// A point inside the cavity and more than `s` from its wall, floor and open top is clear,
    /// since there `φ ≥ −φ_cavity = min(r_in − ρ, h_cavity − |y − y_c|)`.
    #[inline(always)]
    pub fn surely_clear(&self, p: DVec3, s: f64) -> bool {
        // In the cavity φ ≥ min(a, b) − (√2 − 1)·k (the fillet cuts at most that much off the
        // corner), and above it φ ≥ a.
        let k = self.fillet();
        let s = s + CLEAR_SLACK + (std::f64::consts::SQRT_2 - 1.0) * k;
        let r = self.outer_radius - self.wall_thickness - s;
        r > 0.0 && p.y - self.floor_thickness > s && p.x * p.x + p.z * p.z < r * r
    }

    /// Checks the dimensions.
    pub fn validate(&self) -> Result<(), FieldError> {
        let Cup {
            outer_radius,
            height,
            wall_thickness,
            floor_thickness,
            ..
        } = *self;
        positive("outer_radius", outer_radius)?;
        positive("height", height)?;
        positive("wall_thickness", wall_thickness)?;
        positive("floor_thickness", floor_thickness)?;
        if wall_thickness >= outer_radius {
            return Err(FieldError::new(
                "wall_thickness",
                wall_thickness.to_string(),
                format!("< outer_radius {outer_radius} m"),
            ));
        }
        if floor_thickness >= height {
            return Err(FieldError::new(
                "floor_thickness",
                floor_thickness.to_string(),
                format!("< height {height} m"),
            ));
        }
        let k = self.fillet();
        let room = (outer_radius - wall_thickness).min(height - floor_thickness);
        if !(k >= 0.0 && k < room) {
            return Err(FieldError::new(
                "fillet_radius",
                format!("{k}"),
                format!(
                    "≥ 0 m and < {room} m (the cavity's radius and depth); leave it out for the wall thickness, or 0 for a sharp edge"
                ),
            ));
        }
        Ok(())
    }

    /// The cup revolved from its profile, the fillet included.
    pub fn mesh(&self) -> Mesh {
        use std::f64::consts::FRAC_PI_2;
        let ri = self.outer_radius - self.wall_thickness;
        let k = self.fillet();
        let mut profile = vec![
            (0.0, 0.0),
            (self.outer_radius, 0.0),
            (self.outer_radius, self.height),
            (ri, self.height),
        ];
        // The fillet, from the wall down to the floor.
        profile.extend((0..=8).map(|j| {
            let t = -FRAC_PI_2 * j as f64 / 8.0;
            (ri - k + k * t.cos(), self.floor_thickness + k + k * t.sin())
        }));
        profile.push((0.0, self.floor_thickness));
        revolve(&profile)
    }
}
