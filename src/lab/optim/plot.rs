//! `indicator.svg`: the indicator of each method's best rollout so far against the number of
//! rollouts, mean ± one standard deviation over seeds (the paper's Fig. 3).

use super::journal::Record;
use super::report::curve;
use super::Method;
use crate::lab::chart;
use crate::lab::stats::mean_sd as mean_std;
use plotters::coord::combinators::IntoLogRange;
use plotters::prelude::*;
use std::collections::BTreeMap;
use std::path::Path;

/// The colour of a method in every figure.
pub fn colour(m: Method) -> RGBColor {
    match m {
        Method::Grad => RGBColor(31, 119, 180),
        Method::Cmaes => RGBColor(44, 160, 44),
        Method::Sac => RGBColor(214, 39, 40),
        Method::Random => RGBColor(127, 127, 127),
        Method::Smoothed => RGBColor(148, 103, 189),
        Method::Hybrid => RGBColor(140, 86, 75),
        Method::Carry => RGBColor(23, 190, 207),
        Method::Line => RGBColor(255, 127, 14),
        Method::Ray => RGBColor(188, 189, 34),
    }
}

/// Per method: (epoch, mean, std) of the best-so-far indicator over seeds.
pub fn band(
    all: &BTreeMap<(Method, usize), Vec<Record>>,
) -> BTreeMap<Method, Vec<(usize, f64, f64)>> {
    let mut out: BTreeMap<Method, Vec<Vec<f64>>> = BTreeMap::new();
    let bc = super::report::backward_cost(all);
    for ((m, _), list) in all {
        let c = curve(list, bc);
        let slot = out.entry(*m).or_default();
        for p in c {
            if slot.len() < p.epoch {
                slot.resize(p.epoch, Vec::new());
            }
            slot[p.epoch - 1].push(p.best_indicator);
        }
    }
    out.into_iter()
        .map(|(m, per_epoch)| {
            let v = per_epoch
                .iter()
                .enumerate()
                .filter(|(_, v)| !v.is_empty())
                .map(|(i, v)| {
                    let (mean, std) = mean_std(v);
                    (i + 1, mean, std)
                })
                .collect();
            (m, v)
        })
        .collect()
}

/// Draws the figure and writes it atomically.
pub fn indicator_svg(
    path: &Path,
    all: &BTreeMap<(Method, usize), Vec<Record>>,
    epochs: usize,
    unit: &str,
    target: f64,
) -> anyhow::Result<()> {
    let bands = band(all);
    let (mut lo, mut hi) = (0.0f64, target);
    for v in bands.values() {
        for &(_, m, s) in v {
            lo = lo.min(m - s);
            hi = hi.max(m + s);
        }
    }
    let pad = 0.05 * (hi - lo).max(1e-9);
    chart::write_svg(path, (800, 520), |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(
                format!("Indicator (target − transported, {unit}): best rollout so far, mean ± std over seeds"),
                ("sans-serif", 16),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(1f64..epochs.max(2) as f64, (lo - pad)..(hi + pad))?;
        chart
            .configure_mesh()
            .x_desc("epoch (rollouts per seed)")
            .y_desc(format!("indicator ({unit})"))
            .draw()?;
        for (m, v) in &bands {
            let c = colour(*m);
            let upper: Vec<(f64, f64)> = v.iter().map(|&(e, m, s)| (e as f64, m + s)).collect();
            let lower: Vec<(f64, f64)> =
                v.iter().rev().map(|&(e, m, s)| (e as f64, m - s)).collect();
            let poly: Vec<(f64, f64)> = upper.into_iter().chain(lower).collect();
            chart.draw_series(std::iter::once(Polygon::new(poly, c.mix(0.18).filled())))?;
            chart
                .draw_series(LineSeries::new(
                    v.iter().map(|&(e, m, _)| (e as f64, m)),
                    c.stroke_width(2),
                ))?
                .label(m.name())
                .legend(chart::key(c.stroke_width(2)));
        }
        chart::legend(&mut chart, SeriesLabelPosition::UpperRight, None)?;
        Ok(())
    })
}

/// A task's curves, for the figure.
pub struct Curves {
    pub title: String,
    pub unit: String,
    pub by_compute: std::collections::BTreeMap<Method, Vec<(f64, f64)>>,
    pub by_rollouts: std::collections::BTreeMap<Method, Vec<(f64, f64)>>,
}

/// `optimisation.svg`: per task, the median best-so-far dose error against particle-substeps
/// (left) and against rollouts (right), log scale.
pub fn optimisation_figure(path: &std::path::Path, tasks: &[Curves]) -> anyhow::Result<()> {
    chart::write_svg(path, (1100, 380 * tasks.len().max(1) as u32), |root| {
        let rows = root.split_evenly((tasks.len().max(1), 2));
        for (i, t) in tasks.iter().enumerate() {
            for (j, (curves, xdesc)) in [
                (&t.by_compute, "particle-substeps per seed (G)"),
                (&t.by_rollouts, "rollouts per seed"),
            ]
            .into_iter()
            .enumerate()
            {
                let area = &rows[2 * i + j];
                let xs = if j == 0 { 1e-9 } else { 1.0 };
                let x_hi = curves
                    .values()
                    .flatten()
                    .map(|p| p.0 * xs)
                    .fold(0.0, f64::max);
                let x_hi = if x_hi > 0.0 { x_hi } else { 1.0 };
                let ys: Vec<f64> = curves
                    .values()
                    .flatten()
                    .map(|p| p.1)
                    .filter(|y| *y > 0.0)
                    .collect();
                let y_lo = ys.iter().copied().fold(f64::INFINITY, f64::min).min(0.01) * 0.8;
                let y_hi = ys.iter().copied().fold(0.0, f64::max).max(0.1) * 1.25;
                let mut chart = ChartBuilder::on(area)
                    .caption(
                        format!("{}: median best dose error ({})", t.title, t.unit),
                        ("sans-serif", 14),
                    )
                    .margin(10)
                    .x_label_area_size(36)
                    .y_label_area_size(52)
                    .build_cartesian_2d(0f64..x_hi, (y_lo..y_hi).log_scale())?;
                chart
                    .configure_mesh()
                    .x_desc(xdesc)
                    .y_desc(format!("dose error ({})", t.unit))
                    .draw()?;
                for (m, v) in curves {
                    let c = colour(*m);
                    chart
                        .draw_series(LineSeries::new(
                            v.iter().map(|&(x, y)| (x * xs, y.max(y_lo))),
                            c.stroke_width(2),
                        ))?
                        .label(m.name())
                        .legend(chart::key(c.stroke_width(2)));
                }
                chart::legend(&mut chart, SeriesLabelPosition::UpperRight, None)?;
            }
        }
        Ok(())
    })
}
