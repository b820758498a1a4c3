//! `ContactLoc` for scooping: where to put the spoon into a cup's powder next. A scoop leaves a
//! crater, so the next one goes where the surface is highest, clear of the wall by the bowl's
//! reach (a bowl against the wall jams and leaks).

use crate::math::heightfield::HeightGrid;

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
}
