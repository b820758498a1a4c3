//! `ContactLoc` for scooping: where to put the spoon into a cup's powder next. A scoop leaves a
//! crater, so the next one goes where the surface is highest ([`cup_surface`]), clear of the
//! wall by the bowl's reach (a bowl against the wall jams and leaks) ([`entry_points`]).

use crate::math::geometry::CupRegion;
use crate::math::heightfield::{hard_heights, HeightGrid};
use glam::DVec3;

/// A cup's powder surface for choosing where to scoop: on a square grid of `pixel` over the
/// cup's cavity, the highest grain centre per pixel among the grains inside the cup, averaged
/// over the pixels within `footprint` (the spoon's bowl radius) that hold a grain (the cup's
/// floor where none does); `NaN` outside the cavity.
///
/// The average skips empty pixels rather than counting them at the floor: at half a cell a
/// disturbed surface leaves some pixels without a grain, and counting them at the floor put
/// the surface 6 mm low after one scoop, which sent the next scoop that much deeper. A pixel of
/// a cell holds about four columns of grains at 8 particles per cell.
pub fn cup_surface(
    cup: &CupRegion,
    xs: impl Iterator<Item = DVec3>,
    pixel: f64,
    footprint: f64,
) -> (HeightGrid, Vec<f64>) {
    let r = cup.inner_radius;
    let n = (2.0 * r / pixel).ceil() as usize + 1;
    let c = cup.pose.translation;
    let grid = HeightGrid {
        origin: [c.x - r, c.z - r],
        pixel,
        nx: n,
        nz: n,
    };
    let floor = cup.pose.to_world(DVec3::new(0.0, cup.floor, 0.0)).y;
    let inside: Vec<DVec3> = xs.filter(|x| cup.inside(*x)).collect();
    let hard = hard_heights(&grid, &inside, f64::NEG_INFINITY, 0.0);
    let at = |k: usize| {
        let (i, j) = (k % n, k / n);
        let x = grid.origin[0] + i as f64 * pixel;
        let z = grid.origin[1] + j as f64 * pixel;
        (x, z, (x - c.x).hypot(z - c.z) <= r)
    };
    let reach = (footprint / pixel).ceil() as isize;
    let smooth = (0..grid.len())
        .map(|k| {
            let (x, z, inside) = at(k);
            if !inside {
                return f64::NAN;
            }
            let (i, j) = ((k % n) as isize, (k / n) as isize);
            let (mut sum, mut count) = (0.0, 0.0);
            for dj in -reach..=reach {
                for di in -reach..=reach {
                    let (a, b) = (i + di, j + dj);
                    if a < 0 || b < 0 || a >= n as isize || b >= n as isize {
                        continue;
                    }
                    let q = b as usize * n + a as usize;
                    let (qx, qz, q_in) = at(q);
                    if q_in && hard[q].is_finite() && (qx - x).hypot(qz - z) <= footprint {
                        sum += hard[q];
                        count += 1.0;
                    }
                }
            }
            if count > 0.0 {
                sum / count
            } else {
                floor
            }
        })
        .collect();
    (grid, smooth)
}

/// Entry points: the highest pixels of `heights` (on `grid`) whose centres lie within
/// `radius − clearance` of the cup's axis at `centre` (x, z), each at least `spacing` from
/// those chosen before it; at most `k`, highest first, as (x, z, height). Ties go to the pixel
/// nearer the axis, then to the lower index, so the choice is deterministic.
pub fn entry_points(
    grid: &HeightGrid,
    heights: &[f64],
    centre: [f64; 2],
    radius: f64,
    clearance: f64,
    k: usize,
    spacing: f64,
) -> Vec<[f64; 3]> {
    let reach = radius - clearance;
    let mut candidates: Vec<(f64, f64, usize, [f64; 3])> = (0..grid.len())
        .filter_map(|c| {
            let (i, j) = (c % grid.nx, c / grid.nx);
            let x = grid.origin[0] + i as f64 * grid.pixel;
            let z = grid.origin[1] + j as f64 * grid.pixel;
            let d = (x - centre[0]).hypot(z - centre[1]);
            let h = heights[c];
            (d <= reach && h.is_finite()).then_some((h, d, c, [x, z, h]))
        })
        .collect();
    candidates.sort_by(|a, b| {
        b.0.total_cmp(&a.0)
            .then(a.1.total_cmp(&b.1))
            .then(a.2.cmp(&b.2))
    });
    let mut out: Vec<[f64; 3]> = Vec::new();
    for (_, _, _, p) in candidates {
        if out.len() == k {
            break;
        }
        if out
            .iter()
            .all(|q| (p[0] - q[0]).hypot(p[1] - q[1]) >= spacing)
        {
            out.push(p);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 21×21 field of 2 mm pixels over a cup of 20 mm radius at the origin: a crater in the
    /// middle, the highest heap against the wall (not admissible with 6 mm of clearance), a
    /// lower heap inside at (8, −4) mm and a third at (−6, 6) mm.
    #[test]
    fn picks_the_highest_admissible_points() {
        let grid = HeightGrid {
            origin: [-0.02, -0.02],
            pixel: 0.002,
            nx: 21,
            nz: 21,
        };
        let bump = |x: f64, z: f64, cx: f64, cz: f64, h: f64| {
            h * (-((x - cx).powi(2) + (z - cz).powi(2)) / (2.0 * 0.003f64.powi(2))).exp()
        };
        let heights: Vec<f64> = (0..grid.len())
            .map(|c| {
                let x = grid.origin[0] + (c % 21) as f64 * grid.pixel;
                let z = grid.origin[1] + (c / 21) as f64 * grid.pixel;
                0.03 - bump(x, z, 0.0, 0.0, 0.006)
                    + bump(x, z, 0.018, 0.0, 0.01)
                    + bump(x, z, 0.008, -0.004, 0.004)
                    + bump(x, z, -0.006, 0.006, 0.003)
            })
            .collect();
        let p = entry_points(&grid, &heights, [0.0, 0.0], 0.02, 0.006, 2, 0.006);
        assert_eq!(p.len(), 2);
        assert!(
            (p[0][0] - 0.008).abs() < 1e-9 && (p[0][1] + 0.004).abs() < 1e-9,
            "{p:?}"
        );
        assert!(
            (p[1][0] + 0.006).abs() < 1e-9 && (p[1][1] - 0.006).abs() < 1e-9,
            "{p:?}"
        );
        // Without clearance the heap against the wall wins.
        let q = entry_points(&grid, &heights, [0.0, 0.0], 0.02, 0.0, 1, 0.006);
        assert!((q[0][0] - 0.018).abs() < 1e-9, "{q:?}");
    }

    /// Grains on a 2.5 mm lattice fill a cup of 20 mm inner radius up to about 28 mm, with a
    /// crater 8 mm deep and 14 mm wide at (10, 0) mm, and the columns of one 5 mm pixel
    /// missing at (−10, 0) mm (a disturbed surface). The surface stays at the lattice's top away from the
    /// crater, the gap does not pull it down, and the crater does.
    #[test]
    fn the_cup_surface_skips_empty_pixels_and_sees_craters() {
        use crate::math::pose::Pose;
        let cup = CupRegion {
            pose: Pose::default(),
            inner_radius: 0.02,
            floor: 0.003,
            rim: 0.05,
            wall: 0.002,
        };
        let s = 0.0025;
        let mut xs = Vec::new();
        for i in -8..=8 {
            for k in -8..=8 {
                let (x, z) = (i as f64 * s, k as f64 * s);
                if (x + 0.01).abs() < 0.003 && z.abs() < 0.003 {
                    continue;
                }
                let top = if (x - 0.01).hypot(z) < 0.007 {
                    0.02
                } else {
                    0.028
                };
                let mut y = 0.004;
                while y <= top + 1e-12 {
                    xs.push(DVec3::new(x, y, z));
                    y += s;
                }
            }
        }
        let top = xs.iter().map(|p| p.y).fold(0.0, f64::max);
        let (grid, h) = cup_surface(&cup, xs.into_iter(), 0.005, 0.006);
        let at = |x: f64, z: f64| {
            let i = ((x - grid.origin[0]) / grid.pixel).round() as usize;
            let j = ((z - grid.origin[1]) / grid.pixel).round() as usize;
            h[j * grid.nx + i]
        };
        assert!((at(0.0, 0.01) - top).abs() < 1e-12, "{}", at(0.0, 0.01));
        assert!(
            (at(-0.01, 0.0) - top).abs() < 1e-12,
            "the gap: {}",
            at(-0.01, 0.0)
        );
        assert!(at(0.01, 0.0) < top - 0.002, "the crater: {}", at(0.01, 0.0));
        assert!(at(0.03, 0.0).is_nan() || at(0.02, 0.02).is_nan());
    }
}
