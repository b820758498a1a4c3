//! Unit tests of the shapes: gradients and Hessians against central differences, thin walls
//! where expected, the cup's continuous normal, and the clearance test against the SDF.

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
        Shape::Spatula {
            blade_width: 0.04,
            blade_height: 0.02,
            thickness: 0.002,
            handle_length: 0.06,
            handle_radius: 0.003,
        },
    ]
}

/// The tests' fixed stream in [−1, 1) ([`crate::util::Lcg`]).
use crate::util::lcg_symmetric as lcg;

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

#[test]
fn spoon_shape_derivatives_match_central_differences() {
    let base = shapes()
        .iter()
        .find_map(Shape::spoon)
        .expect("the test shapes have a spoon");
    let with = |k: usize, d: f64| {
        let mut s = base;
        match k {
            0 => s.bowl_radius += d,
            1 => s.bowl_depth += d,
            _ => s.handle_length += d,
        }
        s
    };
    let mut seed = 11;
    let mut checked = [0; 3];
    for _ in 0..4000 {
        let p = 0.07 * DVec3::new(lcg(&mut seed), lcg(&mut seed), lcg(&mut seed));
        let g = base.sdf_dshape(p);
        assert_eq!((g.phi, g.grad), base.sdf(p));
        for (k, count) in checked.iter_mut().enumerate() {
            let (lo, hi) = (with(k, -H).sdf(p), with(k, H).sdf(p));
            // Skip points where the step changes branch (a kink between bowl and handle, or
            // between the rim and the sphere): the one-sided slopes differ there.
            let fwd = (hi.0 - g.phi) / H;
            let bwd = (g.phi - lo.0) / H;
            if (fwd - bwd).abs() > 1e-4 {
                continue;
            }
            let fd = (hi.0 - lo.0) / (2.0 * H);
            assert!(
                (fd - g.dshape[k]).abs() < GRAD_TOL,
                "parameter {k} at {p:?}: {} against {fd}",
                g.dshape[k]
            );
            *count += 1;
        }
    }
    assert!(checked.iter().all(|&c| c > 3000), "{checked:?}");
}
