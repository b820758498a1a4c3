//! The lab's statistics, one convention for every results page.
//!
//! - **"mean ± sd"**: the mean and the *sample* standard deviation (divided by n − 1), the
//!   estimate of the spread of the population the seeds were drawn from; a single value has no
//!   spread, and its sd is given as 0.
//! - **Paired comparisons**: the exact one-sided Wilcoxon signed-rank test on paired values
//!   ([`wilcoxon_less`]) and the exact one-sided sign test on paired successes ([`sign_test`]),
//!   at the level [`ALPHA`]; [`p_text`] prints a p-value as every page does.
//! - **Intervals**: a percentile bootstrap of the mean ([`bootstrap_mean`]), with its draws from
//!   a seed so that a page regenerates to the same figures.

use crate::util::SplitMix64;

/// The mean of `v`; 0 when it is empty.
pub fn mean(v: &[f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.iter().sum::<f64>() / v.len() as f64
}

/// The sample standard deviation of `v` (n − 1 in the denominator); 0 for fewer than two
/// values.
pub fn sd(v: &[f64]) -> f64 {
    if v.len() < 2 {
        return 0.0;
    }
    let m = mean(v);
    (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (v.len() - 1) as f64).sqrt()
}

/// [`mean`] and [`sd`]: what a page prints as "mean ± sd".
pub fn mean_sd(v: &[f64]) -> (f64, f64) {
    (mean(v), sd(v))
}

/// The median of `xs` (the mean of the two middle values for an even count); 0 when empty.
pub fn median(xs: &[f64]) -> f64 {
    let mut v = xs.to_vec();
    v.sort_by(f64::total_cmp);
    match v.len() {
        0 => 0.0,
        n if n % 2 == 1 => v[n / 2],
        n => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

/// The `q` quantile (0 ≤ q ≤ 1) of `sorted`, the nearest rank: `sorted[round((n − 1)·q)]`.
pub fn quantile_sorted(sorted: &[f64], q: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

/// Bootstrap resamples drawn by [`bootstrap_mean`].
pub const BOOTSTRAP_RESAMPLES: usize = 2000;

/// A percentile bootstrap interval of the mean of `v` at `level` (0.9 gives the 5th and 95th
/// percentiles of [`BOOTSTRAP_RESAMPLES`] resampled means), the resamples drawn from `seed`.
/// `None` for an empty `v`.
pub fn bootstrap_mean(v: &[f64], level: f64, seed: u64) -> Option<(f64, f64)> {
    if v.is_empty() {
        return None;
    }
    let mut rng = SplitMix64(seed);
    let mut means: Vec<f64> = (0..BOOTSTRAP_RESAMPLES)
        .map(|_| (0..v.len()).map(|_| v[rng.index(v.len())]).sum::<f64>() / v.len() as f64)
        .collect();
    means.sort_by(f64::total_cmp);
    let tail = 0.5 * (1.0 - level);
    Some((
        quantile_sorted(&means, tail),
        quantile_sorted(&means, 1.0 - tail),
    ))
}

/// The significance level of the verdicts.
pub const ALPHA: f64 = 0.05;

/// A p-value as the pages print it: three decimals, or "–" where the test has no non-zero
/// difference to rank.
pub fn p_text(p: Option<f64>) -> String {
    p.map_or("–".into(), |p| format!("{p:.3}"))
}

/// One-sided exact Wilcoxon signed-rank test of paired samples: the p-value of "a is smaller
/// than b". Zero differences are dropped (Wilcoxon's rule), tied magnitudes share their mean
/// rank, and the null distribution of the rank sum is enumerated exactly over the signs. `None`
/// when no difference is non-zero.
pub fn wilcoxon_less(a: &[f64], b: &[f64]) -> Option<f64> {
    let d: Vec<f64> = a
        .iter()
        .zip(b)
        .map(|(x, y)| x - y)
        .filter(|d| *d != 0.0)
        .collect();
    if d.is_empty() {
        return None;
    }
    let mut order: Vec<usize> = (0..d.len()).collect();
    order.sort_by(|&i, &j| d[i].abs().total_cmp(&d[j].abs()));
    // Doubled ranks (integers even where ties share a half rank).
    let mut rank2 = vec![0usize; d.len()];
    let mut i = 0;
    while i < order.len() {
        let mut j = i;
        while j + 1 < order.len() && d[order[j + 1]].abs() == d[order[i]].abs() {
            j += 1;
        }
        // Ranks i+1 ..= j+1 share their mean (i + j + 2)/2, doubled: i + j + 2.
        for &o in &order[i..=j] {
            rank2[o] = i + j + 2;
        }
        i = j + 1;
    }
    // Observed statistic: the sum of the (doubled) ranks of the positive differences; small
    // when a < b.
    let w: usize = d
        .iter()
        .zip(&rank2)
        .filter(|(d, _)| **d > 0.0)
        .map(|(_, r)| r)
        .sum();
    // counts[s] = number of sign assignments whose positive ranks sum to s.
    let total: usize = rank2.iter().sum();
    let mut counts = vec![0f64; total + 1];
    counts[0] = 1.0;
    for &r in &rank2 {
        for s in (r..=total).rev() {
            counts[s] += counts[s - r];
        }
    }
    let all = 2f64.powi(d.len() as i32);
    Some(counts[..=w].iter().sum::<f64>() / all)
}

/// The exact one-sided sign test over paired successes: the chance, under "the two succeed
/// equally often", of `a` succeeding alone at least as often as it did, among the pairs where
/// exactly one succeeded. `None` without such a pair.
pub fn sign_test(a: &[bool], b: &[bool]) -> Option<f64> {
    let only_a = a.iter().zip(b).filter(|(x, y)| **x && !**y).count();
    let only_b = a.iter().zip(b).filter(|(x, y)| !**x && **y).count();
    let n = only_a + only_b;
    if n == 0 {
        return None;
    }
    let choose = |n: usize, k: usize| -> f64 {
        (0..k).fold(1.0, |c, i| c * (n - i) as f64 / (i + 1) as f64)
    };
    let tail: f64 = (only_a..=n).map(|k| choose(n, k)).sum();
    Some(tail / 2f64.powi(n as i32))
}

/// Euclidean length.
pub fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// The cosine of the angle between `a` and `b` (NaN when either is zero).
pub fn cosine(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>() / (norm(a) * norm(b))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_spread_is_the_sample_standard_deviation() {
        // 2, 4, 4, 4, 5, 5, 7, 9: mean 5, squared deviations sum to 32; 32/7 under n − 1.
        let v = [2.0, 4.0, 4.0, 4.0, 5.0, 5.0, 7.0, 9.0];
        let (m, s) = mean_sd(&v);
        assert_eq!(m, 5.0);
        assert!((s - (32.0f64 / 7.0).sqrt()).abs() < 1e-15);
        assert_eq!(sd(&[3.0]), 0.0);
        assert_eq!(mean(&[]), 0.0);
        assert_eq!(median(&[3.0, 1.0, 2.0, 10.0]), 2.5);
    }

    #[test]
    fn the_bootstrap_interval_holds_the_mean_and_is_reproducible() {
        let v: Vec<f64> = (0..20).map(|i| (i * i % 7) as f64).collect();
        let (lo, hi) = bootstrap_mean(&v, 0.9, 1).unwrap();
        assert!(lo < mean(&v) && mean(&v) < hi, "{lo} {} {hi}", mean(&v));
        // About ±1.645 standard errors: the interval's width is within 25 % of that.
        let se = sd(&v) / (v.len() as f64).sqrt();
        assert!(
            ((hi - lo) / (2.0 * 1.645 * se) - 1.0).abs() < 0.25,
            "{lo} {hi} {se}"
        );
        assert_eq!(bootstrap_mean(&v, 0.9, 1), Some((lo, hi)));
        assert_eq!(bootstrap_mean(&[], 0.9, 1), None);
        // A constant sample has a point interval.
        assert_eq!(bootstrap_mean(&[2.0; 5], 0.9, 3), Some((2.0, 2.0)));
    }

    #[test]
    fn wilcoxon_matches_the_tables() {
        // All ten differences negative: p = 2^-10 (exact).
        let a: Vec<f64> = (0..10).map(|i| i as f64).collect();
        let b: Vec<f64> = (0..10).map(|i| i as f64 + 1.0 + 0.1 * i as f64).collect();
        assert!((wilcoxon_less(&a, &b).unwrap() - 1.0 / 1024.0).abs() < 1e-15);
        // The reverse is certain.
        assert!((wilcoxon_less(&b, &a).unwrap() - 1.0).abs() < 1e-15);
        // n = 5, ranks 1..5, W+ = 1 + 2 = 3 (the two smallest positive): P(W+ <= 3) = 5/32
        // (the subsets {}, {1}, {2}, {3}, {1,2}).
        let d = [1.0, 2.0, -3.0, -4.0, -5.0];
        let zero = [0.0; 5];
        assert!((wilcoxon_less(&d, &zero).unwrap() - 5.0 / 32.0).abs() < 1e-15);
        // Zero differences are dropped; nothing left gives no test.
        assert_eq!(wilcoxon_less(&[1.0, 2.0], &[1.0, 2.0]), None);
        // Ties share a rank: |d| = (1, 1), both positive: W+ = 3 of a total 3, p = 1.
        assert!((wilcoxon_less(&[1.0, 1.0], &[0.0, 0.0]).unwrap() - 1.0).abs() < 1e-15);
        // ... both negative: only the empty sum is <= 0, p = 1/4.
        assert!((wilcoxon_less(&[0.0, 0.0], &[1.0, 1.0]).unwrap() - 0.25).abs() < 1e-15);
    }

    #[test]
    fn the_sign_test_counts_the_discordant_pairs() {
        // A succeeds alone on 3 pairs, B alone on none: p = 1/8.
        let a = [true, true, true, true, false];
        let b = [false, false, false, true, false];
        assert!((sign_test(&a, &b).unwrap() - 0.125).abs() < 1e-12);
        assert!((sign_test(&b, &a).unwrap() - 1.0).abs() < 1e-12);
        assert_eq!(sign_test(&a, &a), None);
    }
}
