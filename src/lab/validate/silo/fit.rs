//! The two measurements of a silo discharge: the rate, read from the discharged fraction's trace
//! inside a window, and Beverloo's law `W = C·(D − D₀)^n` fitted to the rates.

use serde::Serialize;

/// The least-squares slope of `(t, fraction)` over the samples whose fraction lies within
/// `window`, times `scale`; `None` with fewer than three such samples, or where the trace never
/// passes the window's end (the flow arched and stopped inside it).
pub fn discharge_rate(trace: &[(f64, f64)], window: (f64, f64), scale: f64) -> Option<f64> {
    let pts: Vec<(f64, f64)> = trace
        .iter()
        .copied()
        .filter(|&(_, f)| f >= window.0 && f <= window.1)
        .collect();
    // A run that stopped short of the window's end arched: its early slope is not a rate.
    let reached = trace.last().is_some_and(|&(_, f)| f > window.1);
    if !reached || pts.len() < 3 {
        return None;
    }
    let (_, slope, _) = line(&pts);
    slope.is_finite().then_some(scale * slope)
}

/// `W = C·(D − D₀)^n` fitted to `(D, W)` points: `D₀` by a scan over `[−D_min, D_min)` in
/// thousandths of `D_min`, and at each `D₀` the least-squares line through
/// `(ln(D − D₀), ln W)`, keeping the `D₀` of least squared residual.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct BeverlooFit {
    pub exponent: f64,
    pub offset: f64,
    pub prefactor: f64,
    /// Root-mean-square residual of `ln W`.
    pub rms: f64,
}

/// The least-squares line `y = a + b·x` through `pts`: `(a, b, rms residual)`.
fn line(pts: &[(f64, f64)]) -> (f64, f64, f64) {
    let n = pts.len() as f64;
    let (mx, my) = (
        pts.iter().map(|p| p.0).sum::<f64>() / n,
        pts.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let b = sxy / sxx;
    let a = my - b * mx;
    let ss: f64 = pts.iter().map(|p| (p.1 - a - b * p.0).powi(2)).sum();
    (a, b, (ss / n).sqrt())
}

/// [`BeverlooFit`] of `(D, W)` points (at least three distinct `D`, every `W > 0`); `None`
/// otherwise. With `offset: false`, `D₀ = 0` (the plain log–log slope).
pub fn beverloo_fit(points: &[(f64, f64)], offset: bool) -> Option<BeverlooFit> {
    let mut ds: Vec<f64> = points.iter().map(|p| p.0).collect();
    ds.sort_by(f64::total_cmp);
    ds.dedup();
    if ds.len() < 3 || !points.iter().all(|p| p.0 > 0.0 && p.1 > 0.0) {
        return None;
    }
    let d_min = ds[0];
    let fit_at = |d0: f64| {
        let pts: Vec<(f64, f64)> = points
            .iter()
            .map(|&(d, w)| ((d - d0).ln(), w.ln()))
            .collect();
        let (a, b, rms) = line(&pts);
        BeverlooFit {
            exponent: b,
            offset: d0,
            prefactor: a.exp(),
            rms,
        }
    };
    if !offset {
        return Some(fit_at(0.0));
    }
    (-1000..1000)
        .map(|k| fit_at(d_min * k as f64 / 1000.0))
        .min_by(|a, b| a.rms.total_cmp(&b.rms))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lab::validate::silo::WINDOW;

    /// The fit recovers an exponent and offset it was given, on exact data (to the scan's step
    /// of a thousandth of the smallest D).
    #[test]
    fn the_fit_recovers_a_law_it_was_given() {
        let pts: Vec<(f64, f64)> = [6.0, 8.0, 10.0, 12.0, 16.0]
            .iter()
            .map(|&d: &f64| (d, 0.7 * (d - 1.5f64).powf(1.5)))
            .collect();
        let f = beverloo_fit(&pts, true).unwrap();
        assert!((f.offset - 1.5).abs() < 0.01, "{f:?}");
        assert!((f.exponent - 1.5).abs() < 0.01, "{f:?}");
        assert!((f.prefactor - 0.7).abs() < 0.02, "{f:?}");
        let plain = beverloo_fit(&pts, false).unwrap();
        assert!(
            plain.exponent > 1.6,
            "an offset steepens the plain slope: {plain:?}"
        );
        assert!(beverloo_fit(&pts[..2], true).is_none());
        assert!(beverloo_fit(&[(1.0, 1.0), (2.0, -1.0), (3.0, 1.0)], true).is_none());
    }

    #[test]
    fn the_rate_is_the_slope_inside_the_window() {
        // A start-up, then 0.5 of the fill a second, then a tail: only the middle counts.
        let trace: Vec<(f64, f64)> = (0..200)
            .map(|k| {
                let t = k as f64 * 0.01;
                (t, if t < 0.2 { 0.0 } else { 0.5 * (t - 0.2) })
            })
            .collect();
        let r = discharge_rate(&trace, WINDOW, 3.0).unwrap();
        assert!((r - 1.5).abs() < 1e-9, "{r}");
        assert!(discharge_rate(&trace[..30], WINDOW, 1.0).is_none());
        // Flowing to 0.2 of the fill and arching there: no rate, though the window holds samples.
        let arched: Vec<(f64, f64)> = trace.iter().map(|&(t, f)| (t, f.min(0.2))).collect();
        assert!(discharge_rate(&arched, WINDOW, 1.0).is_none());
    }
}
