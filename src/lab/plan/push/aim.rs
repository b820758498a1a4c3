//! Where the next stroke aims, and how many strokes are still needed at least: pure functions
//! of the powder still outside the region, each grain given as its z (across the stroke) and a
//! weight.
//!
//! - [`bands`]: the z-extent of the powder outside is cut into the fewest equal bands no wider
//!   than the blade, so a patch wider than the blade is covered by side-by-side strokes; each
//!   band is scored by the weight of its grains (their push-loss distance, so the grains
//!   farthest from the region count most), and the bands come highest score first.
//! - [`strokes_bound`]: a lower bound on the strokes still needed, from the largest share of
//!   the mass that one stroke's swept band can hold.

/// Band centres across `z` for grains `(z, weight)`: the extent `[min z, max z]` of the grains
/// with a positive weight cut into `max(⌈extent/reach⌉, at_least)` equal bands, highest total
/// weight first (ties to the lower z). Empty when no grain has a weight.
pub fn bands(grains: &[(f64, f64)], reach: f64, at_least: usize) -> Vec<f64> {
    let live = grains.iter().filter(|(_, w)| *w > 0.0);
    let (lo, hi) = live
        .clone()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), (z, _)| {
            (lo.min(*z), hi.max(*z))
        });
    if lo > hi {
        return Vec::new();
    }
    let extent = hi - lo;
    let m = ((extent / reach).ceil() as usize).max(at_least).max(1);
    let width = extent / m as f64;
    let mut score = vec![0.0; m];
    for (z, w) in live {
        let j = if width > 0.0 {
            (((z - lo) / width) as usize).min(m - 1)
        } else {
            0
        };
        score[j] += w;
    }
    let mut order: Vec<usize> = (0..m).collect();
    order.sort_by(|&a, &b| score[b].total_cmp(&score[a]).then(a.cmp(&b)));
    order
        .into_iter()
        .map(|j| lo + width * (j as f64 + 0.5))
        .collect()
}

/// A lower bound on the strokes still needed to bring `needed` (a share of the total mass) into
/// the region, when one stroke sweeps a band `sweep` wide across z and moves at most the grains
/// in it: `needed / G`, with `G` the largest share of the total mass (`total` grains, the ones
/// outside at `zs`) in any window of width `sweep`. 0 when nothing is needed; infinite when no
/// grain is outside but some mass is needed (no stroke can help).
///
/// It is admissible (never above the strokes really needed) as long as a stroke moves no grain
/// from outside its swept band; powder that the blade shoves sideways breaks that, so it is a
/// heuristic, checked against the old one by the expansions A* makes.
pub fn strokes_bound(zs: &[f64], total: usize, sweep: f64, needed: f64) -> f64 {
    if needed <= 0.0 {
        return 0.0;
    }
    let mut z = zs.to_vec();
    z.sort_by(f64::total_cmp);
    let (mut best, mut j) = (0usize, 0usize);
    for i in 0..z.len() {
        while z[i] - z[j] > sweep {
            j += 1;
        }
        best = best.max(i + 1 - j);
    }
    if best == 0 {
        return f64::INFINITY;
    }
    needed / (best as f64 / total.max(1) as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A patch 60 mm across with a 40 mm blade is split into two bands of 30 mm, and the one
    /// holding the grains farthest from the region comes first; a 30 mm patch is one band.
    #[test]
    fn a_patch_wider_than_the_blade_is_split() {
        let wide: Vec<(f64, f64)> = (0..=60)
            .map(|i| {
                let z = 0.03 + 0.001 * i as f64;
                (z, if z > 0.06 { 2.0 } else { 1.0 })
            })
            .collect();
        let b = bands(&wide, 0.04, 1);
        assert_eq!(b.len(), 2, "{b:?}");
        assert!(
            (b[0] - 0.075).abs() < 1e-12 && (b[1] - 0.045).abs() < 1e-12,
            "{b:?}"
        );
        let narrow: Vec<(f64, f64)> = wide.iter().copied().filter(|(z, _)| *z < 0.0605).collect();
        let n = bands(&narrow, 0.04, 1);
        assert_eq!(n.len(), 1);
        assert!((n[0] - 0.045).abs() < 1e-12);
        // At least two, for the relocations: the narrow patch's halves.
        assert_eq!(bands(&narrow, 0.04, 2).len(), 2);
        // Grains already in the region weigh nothing.
        assert!(bands(&[(0.05, 0.0)], 0.04, 1).is_empty());
    }

    /// Two height fields of the same powder (a synthetic heap of 40 × 40 columns, 1 mm apart,
    /// one grain per millimetre of height): the heap whole outside the region, and the same with
    /// a 20 mm stripe already moved in. The second needs fewer strokes by the bound, a heap
    /// wider than the sweep needs more than one, and none are needed at success.
    #[test]
    fn the_bound_ranks_what_is_left_to_move() {
        let column = |i: usize, j: usize| -> usize {
            let (x, z) = (i as f64 - 19.5, j as f64 - 19.5);
            (12.0 - 0.02 * (x * x + z * z)).max(1.0) as usize
        };
        let mut all = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                for _ in 0..column(i, j) {
                    all.push((i, 0.001 * j as f64));
                }
            }
        }
        let total = all.len();
        let outside = |moved: usize| -> Vec<f64> {
            all.iter()
                .filter(|(i, _)| *i >= moved)
                .map(|(_, z)| *z)
                .collect()
        };
        let need = |zs: &[f64]| 0.9 - (1.0 - zs.len() as f64 / total as f64);
        let (a, b) = (outside(0), outside(20));
        let ha = strokes_bound(&a, total, 0.02, need(&a));
        let hb = strokes_bound(&b, total, 0.02, need(&b));
        assert!(ha > hb && hb > 0.0, "{ha} {hb}");
        assert!(
            ha > 1.0,
            "a heap twice the sweep needs two strokes at least: {ha}"
        );
        assert!(strokes_bound(&a, total, 0.1, need(&a)) <= 1.0);
        assert_eq!(strokes_bound(&[], total, 0.02, 0.0), 0.0);
        assert!(strokes_bound(&[], total, 0.02, 0.1).is_infinite());
    }
}
