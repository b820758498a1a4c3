//! Analytic signed distance functions in a shape's local frame, with their gradients.
//!
//! Every function returns `(φ, ∇φ)`: `φ < 0` inside the solid, `|∇φ| = 1` wherever the
//! gradient is defined. Composite shapes (cup, spoon) combine primitives with `min`/`max`; the
//! gradient is that of the active branch (a kink where branches tie, documented for the adjoint).

use glam::{DMat3, DVec3};
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

/// Hessian of the distance from `p` to the horizontal circle of radius `r` at height `y0` (about
/// the y axis): `(P − n·nᵀ)/d + (ρ − r)/(d·ρ)·θ̂θ̂ᵀ`, `P` the projector on the (ρ̂, ŷ) plane.
pub fn circle_distance_hessian(p: DVec3, r: f64, y0: f64) -> DMat3 {
    let rho = (p.x * p.x + p.z * p.z).sqrt();
    if rho == 0.0 {
        return DMat3::ZERO;
    }
    let radial = DVec3::new(p.x / rho, 0.0, p.z / rho);
    let theta = DVec3::new(-radial.z, 0.0, radial.x);
    let outer = |a: DVec3, b: DVec3| DMat3::from_cols(a * b.x, a * b.y, a * b.z);
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
    let rho = (p.x * p.x + p.z * p.z).sqrt();
    if rho == 0.0 {
        return DMat3::ZERO;
    }
    let radial = DVec3::new(p.x / rho, 0.0, p.z / rho);
    let theta = DVec3::new(-radial.z, 0.0, radial.x);
    let outer = |a: DVec3, b: DVec3| DMat3::from_cols(a * b.x, a * b.y, a * b.z);
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
pub fn cup_sdf(
    p: DVec3,
    outer_radius: f64,
    height: f64,
    wall: f64,
    floor: f64,
    k: f64,
) -> (f64, DVec3) {
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
pub fn cup_hessian(
    p: DVec3,
    outer_radius: f64,
    height: f64,
    wall: f64,
    floor: f64,
    k: f64,
) -> DMat3 {
    let rho = (p.x * p.x + p.z * p.z).sqrt();
    let r = outer_radius - wall;
    let (a, b, c) = (r - rho, p.y - floor, p.y - height);
    if a > 0.0 && c > 0.0 {
        return circle_distance_hessian(p, r, height);
    }
    let (phi, _) = cup_sdf(p, outer_radius, height, wall, floor, k);
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

impl Shape {
    /// Signed distance and gradient at the local point `p`.
    pub fn sdf(&self, p: DVec3) -> (f64, DVec3) {
        match *self {
            Shape::Plane { normal } => {
                let n = DVec3::from(normal).normalize();
                (p.dot(n), n)
            }
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
            Shape::Cup {
                outer_radius,
                height,
                wall_thickness,
                floor_thickness,
                fillet_radius,
            } => cup_sdf(
                p,
                outer_radius,
                height,
                wall_thickness,
                floor_thickness,
                cup_fillet(wall_thickness, fillet_radius),
            ),
            Shape::Spoon {
                bowl_radius,
                bowl_depth,
                thickness,
                handle_length,
                handle_radius,
                handle_rise,
            } => {
                let (h, a, d) =
                    spoon_rim_and_handle(bowl_radius, bowl_depth, handle_length, handle_rise);
                let bowl = sd_cut_hollow_sphere(p, bowl_radius, h, 0.5 * thickness);
                let b = a + d;
                let handle = sd_capsule(p, a, b, handle_radius);
                if bowl.0 <= handle.0 {
                    bowl
                } else {
                    handle
                }
            }
        }
    }

    /// Whether `φ(p) > s` for certain at the local point `p`, by a test cheaper than
    /// [`Shape::sdf`]: `false` when the shape has no such test or the test cannot tell. For a
    /// cup, a point inside the cavity and more than `s` from its wall, floor and open top is
    /// clear, since there `φ ≥ −φ_cavity = min(r_in − ρ, h_cavity − |y − y_c|)`. The margin
    /// [`CLEAR_SLACK`] lies far above the round-off of either computation, so the test says
    /// "clear" only where `sdf` does too: callers that skip on it get the same bits.
    #[inline(always)]
    pub fn surely_clear(&self, p: DVec3, s: f64) -> bool {
        match *self {
            Shape::Cup {
                outer_radius,
                wall_thickness,
                floor_thickness,
                fillet_radius,
                ..
            } => {
                // In the cavity φ ≥ min(a, b) − (√2 − 1)·k (the fillet cuts at most that much
                // off the corner), and above it φ ≥ a.
                let k = cup_fillet(wall_thickness, fillet_radius);
                let s = s + CLEAR_SLACK + (std::f64::consts::SQRT_2 - 1.0) * k;
                let r = outer_radius - wall_thickness - s;
                r > 0.0 && p.y - floor_thickness > s && p.x * p.x + p.z * p.z < r * r
            }
            Shape::Spoon {
                bowl_radius,
                bowl_depth,
                thickness,
                handle_length,
                handle_radius,
                handle_rise,
            } => {
                // The bowl's φ is at least |p| − r − t/2 (its rim circle and its sphere both lie
                // on the sphere of radius r); the handle's at least |p − m| − ℓ/2 − r_h with m
                // the middle of its segment and ℓ its length. The spoon is their minimum.
                let s = s + CLEAR_SLACK;
                let bowl = bowl_radius + 0.5 * thickness + s;
                if p.length_squared() <= bowl * bowl {
                    return false;
                }
                let (_, a, d) =
                    spoon_rim_and_handle(bowl_radius, bowl_depth, handle_length, handle_rise);
                let half = 0.5 * d;
                let m = a + half;
                let handle = half.length() + handle_radius + s;
                (p - m).length_squared() > handle * handle
            }
            _ => false,
        }
    }

    /// Hessian `∂²φ/∂p²` at the local point `p` (the derivative of the normal), for the shapes
    /// whose adjoint w.r.t. a moving pose is implemented; `None` for the others. Piecewise: the
    /// Hessian of the branch `sdf` takes at `p` (kinks between branches are one-sided).
    pub fn sdf_hessian(&self, p: DVec3) -> Option<DMat3> {
        let curv = |proj: DMat3, n: DVec3, dist: f64| {
            if dist > 0.0 {
                (proj - DMat3::from_cols(n * n.x, n * n.y, n * n.z)) * (1.0 / dist)
            } else {
                DMat3::ZERO
            }
        };
        match *self {
            Shape::Plane { .. } => Some(DMat3::ZERO),
            Shape::Box { half_extents } => {
                let h = DVec3::from(half_extents);
                let d = p.abs() - h;
                if d.max_element() <= 0.0 {
                    return Some(DMat3::ZERO);
                }
                let (phi, n) = sd_box(p, h);
                let act = DVec3::select(d.cmpgt(DVec3::ZERO), DVec3::ONE, DVec3::ZERO);
                Some(curv(DMat3::from_diagonal(act), n, phi))
            }
            Shape::Sphere { radius } => {
                let (phi, n) = sd_sphere(p, radius);
                Some(curv(DMat3::IDENTITY, n, phi + radius))
            }
            Shape::Capsule {
                half_length,
                radius,
            } => {
                let (phi, n) = sd_capsule_y(p, half_length, radius);
                let proj = if p.y.abs() < half_length {
                    DMat3::from_diagonal(DVec3::new(1.0, 0.0, 1.0))
                } else {
                    DMat3::IDENTITY
                };
                Some(curv(proj, n, phi + radius))
            }
            Shape::Cylinder {
                radius,
                half_height,
            } => Some(cylinder_hessian(p, 0.0, radius, half_height)),
            Shape::Cup {
                outer_radius,
                height,
                wall_thickness,
                floor_thickness,
                fillet_radius,
            } => Some(cup_hessian(
                p,
                outer_radius,
                height,
                wall_thickness,
                floor_thickness,
                cup_fillet(wall_thickness, fillet_radius),
            )),
            Shape::Spoon {
                bowl_radius,
                bowl_depth,
                thickness,
                handle_length,
                handle_radius,
                handle_rise,
            } => {
                let (h, a, d) =
                    spoon_rim_and_handle(bowl_radius, bowl_depth, handle_length, handle_rise);
                let bowl = sd_cut_hollow_sphere(p, bowl_radius, h, 0.5 * thickness);
                let b = a + d;
                let handle = sd_capsule(p, a, b, handle_radius);
                if bowl.0 <= handle.0 {
                    let rho = (p.x * p.x + p.z * p.z).sqrt();
                    if h * rho < a.x * p.y {
                        Some(circle_distance_hessian(p, a.x, h))
                    } else {
                        let l = p.length();
                        let s = if l < bowl_radius { -1.0 } else { 1.0 };
                        Some(curv(DMat3::IDENTITY, p / l, l) * s)
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
                    Some(curv(proj, handle.1, (p - c).length()))
                }
            }
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
            Shape::Spoon {
                bowl_radius,
                handle_length,
                handle_radius,
                handle_rise,
                thickness,
                ..
            } => bowl_radius + handle_length.hypot(handle_rise) + handle_radius + thickness,
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
            _ => f64::INFINITY,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Finite-difference step and tolerance for gradient checks away from kinks (f64).
    const H: f64 = 1e-7;
    const GRAD_TOL: f64 = 1e-6;

    fn shapes() -> Vec<Shape> {
        vec![
            Shape::Plane {
                normal: [0.0, 1.0, 0.2],
            },
            Shape::Box {
                half_extents: [0.05, 0.01, 0.05],
            },
            Shape::Sphere { radius: 0.03 },
            Shape::Capsule {
                half_length: 0.02,
                radius: 0.005,
            },
            Shape::Cylinder {
                radius: 0.03,
                half_height: 0.02,
            },
            Shape::Cup {
                outer_radius: 0.04,
                height: 0.06,
                wall_thickness: 0.002,
                floor_thickness: 0.003,
                fillet_radius: Some(0.004),
            },
            Shape::Spoon {
                bowl_radius: 0.02,
                bowl_depth: 0.012,
                thickness: 0.0015,
                handle_length: 0.1,
                handle_radius: 0.003,
                handle_rise: 0.02,
            },
        ]
    }

    fn lcg(seed: &mut u64) -> f64 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*seed >> 11) as f64) / ((1u64 << 53) as f64) * 2.0 - 1.0
    }

    #[test]
    fn gradient_matches_central_difference_and_is_unit() {
        let mut seed = 3;
        for s in shapes() {
            let mut checked = 0;
            for _ in 0..4000 {
                let p = 0.08 * DVec3::new(lcg(&mut seed), lcg(&mut seed), lcg(&mut seed));
                let (_, g) = s.sdf(p);
                let fd = DVec3::new(
                    (s.sdf(p + DVec3::X * H).0 - s.sdf(p - DVec3::X * H).0) / (2.0 * H),
                    (s.sdf(p + DVec3::Y * H).0 - s.sdf(p - DVec3::Y * H).0) / (2.0 * H),
                    (s.sdf(p + DVec3::Z * H).0 - s.sdf(p - DVec3::Z * H).0) / (2.0 * H),
                );
                // Skip points within 1e-5 of a kink (branch switch), where FD straddles it.
                let smooth = (1..=3).all(|k| {
                    let e = 1e-5 * k as f64;
                    [DVec3::X, DVec3::Y, DVec3::Z].iter().all(|&a| {
                        ((s.sdf(p + a * e).1 - g).length() < 1e-3)
                            && ((s.sdf(p - a * e).1 - g).length() < 1e-3)
                    })
                });
                if !smooth {
                    continue;
                }
                checked += 1;
                assert!(
                    (fd - g).length() < GRAD_TOL,
                    "{s:?} at {p:?}: {g:?} vs {fd:?}"
                );
                assert!((g.length() - 1.0).abs() < 1e-12);
            }
            assert!(checked > 1000, "{s:?}: only {checked} smooth samples");
        }
    }

    fn max_abs(m: DMat3) -> f64 {
        m.to_cols_array().iter().fold(0.0, |a, x| a.max(x.abs()))
    }

    #[test]
    fn hessian_matches_central_difference_of_the_gradient() {
        let mut seed = 5;
        for s in shapes() {
            let mut checked = 0;
            for _ in 0..2000 {
                let p = 0.08 * DVec3::new(lcg(&mut seed), lcg(&mut seed), lcg(&mut seed));
                let Some(h) = s.sdf_hessian(p) else { break };
                // Away from branch switches (same test as for the gradient).
                let smooth = [DVec3::X, DVec3::Y, DVec3::Z].iter().all(|&a| {
                    (1..=3).all(|k| {
                        let e = 1e-5 * k as f64;
                        s.sdf_hessian(p + a * e)
                            .is_some_and(|q| max_abs(q - h) < 0.1 * (1.0 + max_abs(h)))
                            && (s.sdf(p + a * e).1 - s.sdf(p).1).length() < 1e-3
                    })
                });
                if !smooth {
                    continue;
                }
                checked += 1;
                for (k, a) in [DVec3::X, DVec3::Y, DVec3::Z].iter().enumerate() {
                    let fd = (s.sdf(p + *a * H).1 - s.sdf(p - *a * H).1) / (2.0 * H);
                    let col = h.col(k);
                    let scale = col.abs().max_element().max(fd.abs().max_element()).max(1.0);
                    assert!(
                        (fd - col).abs().max_element() <= 1e-5 * scale,
                        "{s:?} at {p:?}: column {k} {col:?} vs {fd:?}"
                    );
                }
            }
            if s.sdf_hessian(DVec3::ZERO).is_some() {
                assert!(checked > 500, "{s:?}: only {checked}");
            }
        }
    }

    #[test]
    fn cup_and_spoon_have_thin_walls_where_expected() {
        let cup = &shapes()[5];
        // Inside the wall (between inner and outer radius, above the floor).
        assert!(cup.sdf(DVec3::new(0.039, 0.03, 0.0)).0 < 0.0);
        // In the cavity, and outside.
        assert!(cup.sdf(DVec3::new(0.0, 0.03, 0.0)).0 > 0.0);
        assert!(cup.sdf(DVec3::new(0.05, 0.03, 0.0)).0 > 0.0);
        // In the floor.
        assert!(cup.sdf(DVec3::new(0.0, 0.001, 0.0)).0 < 0.0);
        let spoon = &shapes()[6];
        // Bottom of the bowl is solid, its centre of curvature is not.
        assert!(spoon.sdf(DVec3::new(0.0, -0.02, 0.0)).0 < 0.0);
        assert!(spoon.sdf(DVec3::new(0.0, -0.015, 0.0)).0 > 0.0);
        // Above the cut plane the sphere is open.
        assert!(spoon.sdf(DVec3::new(0.0, 0.019, 0.0)).0 > 0.0);
    }

    /// The cup's normal is continuous outside its solid: across the bisector of the cavity's
    /// bottom corner and of the rim's inner edge, where a sharp-edged cup switches between two
    /// faces' normals, and its gradient and Hessian match central differences in the fillet and
    /// above the rim (where random points around the whole cup seldom fall).
    #[test]
    fn cup_normal_is_continuous_at_its_corner_and_rim() {
        let (outer, height, wall, floor, k) = (0.04, 0.06, 0.002, 0.003, 0.004);
        let cup = Shape::Cup {
            outer_radius: outer,
            height,
            wall_thickness: wall,
            floor_thickness: floor,
            fillet_radius: Some(k),
        };
        let r = outer - wall;
        // Bisectors: points (ρ, y) = (r − t, floor + t) and (r − t, height + t), in a direction
        // round the axis, nudged by ±1e-9 m across the bisector. In the corner that is a crease
        // of every distance field from the fillet's centre on (t ≥ k, φ ≥ k: the medial axis
        // of the cavity), beyond any contact band; above the rim it is none.
        let mut seed = 17u64;
        for j in 1..400 {
            let t = 3.0 * k * j as f64 / 400.0;
            let az = std::f64::consts::PI * lcg(&mut seed);
            let at = |rho: f64, y: f64| DVec3::new(rho * az.cos(), y, rho * az.sin());
            for y0 in [floor, height] {
                if y0 == floor && t >= k {
                    continue;
                }
                let (_, n0) = cup.sdf(at(r - t - 1e-9, y0 + t + 1e-9));
                let (_, n1) = cup.sdf(at(r - t + 1e-9, y0 + t - 1e-9));
                assert!(
                    (n0 - n1).length() < 1e-6,
                    "y0 {y0}, t {t}: {n0:?} vs {n1:?}"
                );
            }
        }
        // A particle 0.25 mm off the fillet feels the fillet's normal, between the two faces'.
        let (phi, n) = cup.sdf(DVec3::new(r - 0.5 * k, floor + 0.5 * k, 0.0));
        assert!(phi < 0.5 * k && n.x < -0.1 && n.y > 0.1, "{phi} {n:?}");
        // Central differences near the corner and the rim.
        let mut checked = 0;
        for _ in 0..4000 {
            let y0 = if lcg(&mut seed) < 0.0 { floor } else { height };
            let p = DVec3::new(
                r + 2.0 * k * lcg(&mut seed),
                y0 + 2.0 * k * lcg(&mut seed),
                2.0 * k * lcg(&mut seed),
            );
            let (_, g) = cup.sdf(p);
            let hess = cup.sdf_hessian(p).expect("the cup has a Hessian");
            let smooth = [DVec3::X, DVec3::Y, DVec3::Z].iter().all(|&a| {
                (1..=3).all(|m| {
                    let e = 1e-5 * m as f64;
                    (cup.sdf(p + a * e).1 - g).length() < 1e-3
                        && (cup.sdf(p - a * e).1 - g).length() < 1e-3
                        && max_abs(cup.sdf_hessian(p + a * e).unwrap() - hess)
                            < 0.1 * (1.0 + max_abs(hess))
                })
            });
            if !smooth {
                continue;
            }
            checked += 1;
            for (m, a) in [DVec3::X, DVec3::Y, DVec3::Z].iter().enumerate() {
                let fd = (cup.sdf(p + *a * H).0 - cup.sdf(p - *a * H).0) / (2.0 * H);
                assert!((fd - g[m]).abs() < GRAD_TOL, "{p:?}: {g:?}, d/d{m} {fd}");
                let fdn = (cup.sdf(p + *a * H).1 - cup.sdf(p - *a * H).1) / (2.0 * H);
                let col = hess.col(m);
                let scale = col
                    .abs()
                    .max_element()
                    .max(fdn.abs().max_element())
                    .max(1.0);
                assert!(
                    (fdn - col).abs().max_element() <= 1e-5 * scale,
                    "{p:?}: column {m} {col:?} vs {fdn:?}"
                );
            }
            assert!((g.length() - 1.0).abs() < 1e-12);
        }
        assert!(checked > 2000, "only {checked} smooth samples");
    }

    /// `surely_clear(p, s)` claims `φ(p) > s` only where the SDF agrees, and it does claim it
    /// for a good share of the points around the shapes that have the test (so that skipping
    /// on it saves work), for clearances from zero to a centimetre. Points also come close to
    /// the claim's boundary: within 1e-6 m of the bound on a line through the cup's cavity.
    #[test]
    fn surely_clear_claims_only_what_the_sdf_says() {
        let mut seed = 11u64;
        // Each shape with its sampling box (centre, half-size): the cup's covers its wall and
        // cavity, the spoon's its bowl, handle and the space around them.
        let boxes = [
            (DVec3::new(0.0, 0.05, 0.0), DVec3::new(0.045, 0.06, 0.045)),
            (DVec3::ZERO, DVec3::splat(0.12)),
        ];
        for (shape, (centre, half)) in shapes()[5..].iter().zip(boxes) {
            let (mut claimed, mut total) = (0, 0);
            for _ in 0..200_000 {
                let p = centre + DVec3::new(lcg(&mut seed), lcg(&mut seed), lcg(&mut seed)) * half;
                let s = 0.005 * (lcg(&mut seed) + 1.0);
                total += 1;
                if shape.surely_clear(p, s) {
                    claimed += 1;
                    let phi = shape.sdf(p).0;
                    assert!(phi > s, "{shape:?} at {p}: φ {phi} ≤ s {s}");
                }
            }
            assert!(
                claimed * 10 > total,
                "{shape:?}: {claimed} of {total} claimed"
            );
        }
        // Along the cavity's floor, where φ = y − floor: the claim switches on just above s.
        let cup = &shapes()[5];
        let s = 0.001;
        for k in 0..2000 {
            let y = 0.003 + s - 1e-6 + k as f64 * 1e-9;
            let p = DVec3::new(0.001, y, 0.002);
            if cup.surely_clear(p, s) {
                assert!(cup.sdf(p).0 > s, "y {y}");
            }
        }
    }
}
