//! One chart setup for every figure of the results pages (plotters, SVG): a white canvas
//! written atomically, and one legend style (a boxed key of short lines in the series'
//! colours).

use crate::util::write_atomic;
use plotters::coord::{CoordTranslate, Shift};
use plotters::prelude::*;
use std::path::Path;

/// The canvas a figure draws on.
pub type Canvas<'a> = DrawingArea<SVGBackend<'a>, Shift>;

/// Draws a figure of `size` pixels on a white SVG canvas and writes it to `path` atomically
/// (a temporary file, then a rename), so that a failed figure leaves no half-written file.
pub fn write_svg(
    path: &Path,
    size: (u32, u32),
    draw: impl FnOnce(&Canvas<'_>) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        root.fill(&WHITE)?;
        draw(&root)?;
        root.present()?;
    }
    write_atomic(path, svg.as_bytes())?;
    Ok(())
}

/// A series' key in the legend: a short line in `style`.
pub fn key<S: Into<ShapeStyle>>(style: S) -> impl Fn((i32, i32)) -> PathElement<(i32, i32)> {
    let style: ShapeStyle = style.into();
    move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], style)
}

/// The legend, boxed, at `at`; `font` overrides the default label font.
pub fn legend<'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, SVGBackend<'a>, CT>,
    at: SeriesLabelPosition,
    font: Option<(&str, u32)>,
) -> anyhow::Result<()> {
    let mut labels = chart.configure_series_labels();
    labels
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(at);
    if let Some(f) = font {
        labels.label_font(f);
    }
    labels.draw()?;
    Ok(())
}
