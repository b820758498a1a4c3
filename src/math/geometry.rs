//! Pure geometry of the scene's shapes that is not an SDF: the cavity of a cup and its soft
//! indicator (with its gradient).

use crate::math::pose::Pose;
use crate::math::sdf::Shape;
use glam::DVec3;

/// The cavity of a cup in the world: a pose and the cavity's inner radius, floor and rim heights
/// (in the cup's frame, y up, the cup's base at 0), and its wall's thickness.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CupRegion {
    pub pose: Pose,
    pub inner_radius: f64,
    pub floor: f64,
    pub rim: f64,
    pub wall: f64,
}

/// The logistic function `1/(1 + e^(−z))`.
#[inline(always)]
pub fn logistic(z: f64) -> f64 {
    // Written so neither branch overflows: exp of a non-positive number only.
    if z >= 0.0 {
        1.0 / (1.0 + (-z).exp())
    } else {
        let e = z.exp();
        e / (1.0 + e)
    }
}

impl CupRegion {
    /// The cavity of a cup shape at a pose; `None` for other shapes.
    pub fn of(shape: &Shape, pose: Pose) -> Option<CupRegion> {
        match *shape {
            Shape::Cup {
                outer_radius,
                height,
                wall_thickness,
                floor_thickness,
                ..
            } => Some(CupRegion {
                pose,
                inner_radius: outer_radius - wall_thickness,
                floor: floor_thickness,
                rim: height,
                wall: wall_thickness,
            }),
            _ => None,
        }
    }

    /// The hard indicator: inside the cavity (above the floor, inside the inner wall, below
    /// the rim). What the transport metrics count.
    pub fn inside(&self, x: DVec3) -> bool {
        let p = self.pose.to_local(x);
        p.x.hypot(p.z) < self.inner_radius && p.y > self.floor && p.y < self.rim
    }

    /// The soft indicator `s(x) = σ((r_i + t_w/2 − ρ)/w)·σ((y − y_floor/2)/w)·σ((y_rim − y)/w)`
    /// in the cup's frame (`ρ` the distance from the axis, `t_w` the wall's thickness, `σ` the
    /// logistic function), and its world gradient. `s → 1` deep inside the cavity, `→ 0` far
    /// outside, `= 1/2` on a face.
    ///
    /// The wall's and the floor's faces lie in the middle of the solid, not on the cavity's
    /// surface: a settled grain rests half a particle spacing off a solid face, so faces on the
    /// surface counted every grain on the floor or against the wall as a fraction (about 0.6 at
    /// `w` = one spacing), and the soft mass of a settled dose was 15 % short of the hard count
    /// (`tests/dosing_soft_mass_counts_settled_grains.rs`). A grain cannot be inside the solid,
    /// so the middle of the wall and of the floor is the symmetric boundary between a grain
    /// resting inside and one resting outside. The rim is an open face and stays where it is.
    pub fn soft(&self, x: DVec3, w: f64) -> (f64, DVec3) {
        let p = self.pose.to_local(x);
        let rho = p.x.hypot(p.z);
        let a = logistic((self.inner_radius + 0.5 * self.wall - rho) / w);
        let b = logistic((p.y - 0.5 * self.floor) / w);
        let c = logistic((self.rim - p.y) / w);
        let s = a * b * c;
        // σ' = σ(1 − σ).
        let (da, db, dc) = (a * (1.0 - a) / w, b * (1.0 - b) / w, c * (1.0 - c) / w);
        let grad_rho = if rho > 0.0 {
            DVec3::new(p.x / rho, 0.0, p.z / rho)
        } else {
            DVec3::ZERO
        };
        let g_local = grad_rho * (-da * b * c) + DVec3::Y * (a * db * c - a * b * dc);
        (s, self.pose.rotation * g_local)
    }
}
