//! The calibration's figures: curves of a quantity against compute (forward-rollout
//! equivalents), log-scaled in y.

use crate::lab::chart;
use plotters::coord::combinators::IntoLogRange;
use plotters::prelude::*;
use std::path::Path;

/// A named curve and its colour.
pub struct Curve {
    pub label: String,
    pub colour: RGBColor,
    pub points: Vec<(f64, f64)>,
    /// Drawn thin and pale (one seed of many).
    pub faint: bool,
}

/// The colours of the methods in every calibration figure.
pub const ADAM: RGBColor = RGBColor(31, 119, 180);
pub const BFGS: RGBColor = RGBColor(214, 39, 40);
pub const CMAES: RGBColor = RGBColor(44, 160, 44);

/// A method's colour by its name (`adam`, `bfgs`, `cmaes`).
pub fn colour(method: &str) -> RGBColor {
    match method {
        "adam" => ADAM,
        "bfgs" => BFGS,
        _ => CMAES,
    }
}

/// Draws the curves (non-positive values are left out of the log axis) and writes the SVG
/// atomically.
pub fn curves_svg(
    path: &Path,
    title: &str,
    x_desc: &str,
    y_desc: &str,
    curves: &[Curve],
) -> anyhow::Result<()> {
    let pts = curves.iter().flat_map(|c| c.points.iter());
    let (mut x1, mut y0, mut y1) = (1.0f64, f64::INFINITY, 0.0f64);
    for &(x, y) in pts {
        if y > 0.0 && y.is_finite() {
            x1 = x1.max(x);
            y0 = y0.min(y);
            y1 = y1.max(y);
        }
    }
    if !y0.is_finite() {
        (y0, y1) = (1e-12, 1.0);
    }
    chart::write_svg(path, (820, 520), |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(title, ("sans-serif", 16))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(0f64..x1 * 1.02, (y0 * 0.8..y1 * 1.25).log_scale())?;
        chart
            .configure_mesh()
            .x_desc(x_desc)
            .y_desc(y_desc)
            .y_label_formatter(&|v| format!("{v:.1e}"))
            .draw()?;
        let mut labelled = std::collections::BTreeSet::new();
        for c in curves {
            let col = c.colour;
            let style = if c.faint {
                col.mix(0.35).stroke_width(1)
            } else {
                col.stroke_width(2)
            };
            let s = chart.draw_series(LineSeries::new(
                c.points.iter().copied().filter(|p| p.1 > 0.0),
                style,
            ))?;
            if labelled.insert(c.label.clone()) {
                s.label(c.label.clone())
                    .legend(chart::key(col.stroke_width(2)));
            }
        }
        chart::legend(&mut chart, SeriesLabelPosition::UpperRight, None)?;
        Ok(())
    })
}
