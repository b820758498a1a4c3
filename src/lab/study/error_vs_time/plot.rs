//! The studies' figures. `error_vs_time.svg`: error against wall time, log–log, one panel per
//! case and quantity, the sweeps in colour and the Pareto front as a black line.
//! `optimisation.svg` ([`optimisation_figure`]): each task's median best dose error against
//! compute and against rollouts.

use super::{Case, Row, Sweep};
use crate::lab::chart;
use plotters::coord::combinators::IntoLogRange;
use plotters::prelude::*;
use std::path::Path;

fn colour(s: Sweep) -> RGBColor {
    match s {
        Sweep::Resolution => RGBColor(31, 119, 180),
        Sweep::ParticlesPerCell => RGBColor(255, 127, 14),
        Sweep::Substeps => RGBColor(44, 160, 44),
    }
}

/// Which error a panel shows.
#[derive(Clone, Copy, PartialEq)]
enum Against {
    Reference,
    Law,
    FiniteDifference,
}

struct Panel {
    case: Case,
    quantity: &'static str,
    against: Against,
    title: &'static str,
}

const PANELS: [Panel; 8] = [
    Panel {
        case: Case::ColumnCollapse,
        quantity: "runout_ratio",
        against: Against::Reference,
        title: "collapse: run-out (⅛-cell layer front) vs finest",
    },
    Panel {
        case: Case::ColumnCollapse,
        quantity: "runout_ratio",
        against: Against::Law,
        title: "collapse: run-out (⅛-cell layer) vs Lube et al. 2005",
    },
    Panel {
        case: Case::ColumnCollapse,
        quantity: "runout_fixed_height_ratio",
        against: Against::Reference,
        title: "collapse: run-out (0.5 mm layer front) vs finest",
    },
    Panel {
        case: Case::ColumnCollapse,
        quantity: "runout_p99_ratio",
        against: Against::Reference,
        title: "collapse: run-out (99th percentile) vs finest",
    },
    Panel {
        case: Case::PowderTransport,
        quantity: "transported_g",
        against: Against::Reference,
        title: "transport: powder in target cup vs finest",
    },
    Panel {
        case: Case::PowderTransport,
        quantity: "mean_distance_m",
        against: Against::Reference,
        title: "transport: loss per particle vs finest",
    },
    Panel {
        case: Case::PowderTransport,
        quantity: "gradient",
        against: Against::Reference,
        title: "transport: dL/dΘ vs finest (fwd + bwd time)",
    },
    Panel {
        case: Case::PowderTransport,
        quantity: "gradient",
        against: Against::FiniteDifference,
        title: "transport: dL/dΘ·u vs central difference",
    },
];

/// Tick labels of a log axis: three significant digits, no float noise.
fn tick(v: &f64) -> String {
    if (1e-2..1e4).contains(&v.abs()) {
        let s = format!("{v:.3}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        format!("{v:.0e}")
    }
}

fn short(r: &Row) -> String {
    match r.sweep {
        Sweep::Resolution => format!("{:.2}mm", r.dx_m * 1e3),
        Sweep::ParticlesPerCell => format!("{}ppc", r.particles_per_cell),
        Sweep::Substeps => format!("{}sub", r.substeps_per_step),
    }
}

/// Draws the figure and writes it atomically. Errors of exactly zero (a quantity identical to
/// its reference) have no place on a log axis and are left out; the CSV has them.
pub fn error_vs_time_svg(path: &Path, rows: &[Row]) -> anyhow::Result<()> {
    chart::write_svg(path, (1100, 1560), |root| {
        let root = root.titled(
            "powderlab: error against run time (2 threads; Pareto front in black)",
            ("sans-serif", 20),
        )?;
        for (area, p) in root.split_evenly((4, 2)).iter().zip(PANELS.iter()) {
            let pts: Vec<(&Row, f64)> = rows
                .iter()
                .filter(|r| r.case == p.case && r.quantity == p.quantity)
                .filter_map(|r| {
                    let e = match p.against {
                        Against::Reference if r.is_reference => None,
                        Against::Reference => r.error_vs_reference,
                        Against::Law => r.error_vs_law,
                        Against::FiniteDifference => r.error_vs_fd,
                    }?;
                    (e.is_finite() && e > 0.0).then_some((r, e))
                })
                .collect();
            let mut chart = ChartBuilder::on(area);
            chart
                .caption(p.title, ("sans-serif", 15))
                .margin(10)
                .x_label_area_size(36)
                .y_label_area_size(56);
            if pts.is_empty() {
                area.draw(&Text::new(
                    format!("{}: no data yet", p.title),
                    (20, 40),
                    ("sans-serif", 14),
                ))?;
                continue;
            }
            let (mut tlo, mut thi, mut elo, mut ehi) = (f64::MAX, 0.0f64, f64::MAX, 0.0f64);
            for (r, e) in &pts {
                tlo = tlo.min(r.wall_s);
                thi = thi.max(r.wall_s);
                elo = elo.min(*e);
                ehi = ehi.max(*e);
            }
            let (xr, yr) = ((tlo / 1.6).max(1e-3)..thi * 1.6, elo / 2.0..ehi * 2.0);
            let legend_at = emptiest_corner(
                &pts.iter().map(|(r, e)| (r.wall_s, *e)).collect::<Vec<_>>(),
                (xr.start, xr.end),
                (yr.start, yr.end),
            );
            let mut chart = chart.build_cartesian_2d(xr.log_scale(), yr.log_scale())?;
            chart
                .configure_mesh()
                .x_desc("wall time (s)")
                .y_desc("relative error")
                .x_label_formatter(&tick)
                .y_label_formatter(&tick)
                .light_line_style(WHITE)
                .label_style(("sans-serif", 11))
                .draw()?;
            for sweep in [Sweep::Resolution, Sweep::ParticlesPerCell, Sweep::Substeps] {
                let c = colour(sweep);
                let mine: Vec<&(&Row, f64)> =
                    pts.iter().filter(|(r, _)| r.sweep == sweep).collect();
                if mine.is_empty() {
                    continue;
                }
                chart
                    .draw_series(
                        mine.iter()
                            .map(|(r, e)| Circle::new((r.wall_s, *e), 4, c.filled())),
                    )?
                    .label(sweep.name())
                    .legend(move |(x, y)| Circle::new((x + 8, y), 4, c.filled()));
                chart.draw_series(mine.iter().map(|(r, e)| {
                    EmptyElement::at((r.wall_s, *e))
                        + Text::new(short(r), (5, -12), ("sans-serif", 10).into_font().color(&c))
                }))?;
            }
            if p.against != Against::FiniteDifference {
                let mut front: Vec<(f64, f64)> = pts
                    .iter()
                    .filter(|(r, _)| {
                        if p.against == Against::Law {
                            r.pareto_vs_law
                        } else {
                            r.pareto
                        }
                    })
                    .map(|(r, e)| (r.wall_s, *e))
                    .collect();
                front.sort_by(|a, b| a.0.total_cmp(&b.0));
                chart
                    .draw_series(LineSeries::new(
                        front.iter().copied(),
                        BLACK.stroke_width(1),
                    ))?
                    .label("Pareto front")
                    .legend(chart::key(BLACK));
                chart.draw_series(
                    front
                        .iter()
                        .map(|&(t, e)| Circle::new((t, e), 7, BLACK.stroke_width(1))),
                )?;
            }
            chart::legend(&mut chart, legend_at, Some(("sans-serif", 11)))?;
        }
        Ok(())
    })
}

/// The corner of a log–log panel whose third (in each axis) holds the fewest points, for the
/// legend box: a fixed corner hid a point behind the box in some panels.
fn emptiest_corner(pts: &[(f64, f64)], x: (f64, f64), y: (f64, f64)) -> SeriesLabelPosition {
    let frac = |v: f64, (lo, hi): (f64, f64)| (v.ln() - lo.ln()) / (hi.ln() - lo.ln());
    let corners = [
        (SeriesLabelPosition::LowerLeft, false, false),
        (SeriesLabelPosition::UpperRight, true, true),
        (SeriesLabelPosition::LowerRight, true, false),
        (SeriesLabelPosition::UpperLeft, false, true),
    ];
    let count = |right: bool, upper: bool| {
        pts.iter()
            .filter(|&&(px, py)| {
                let (fx, fy) = (frac(px, x), frac(py, y));
                (if right {
                    fx > 2.0 / 3.0
                } else {
                    fx < 1.0 / 3.0
                }) && (if upper {
                    fy > 2.0 / 3.0
                } else {
                    fy < 1.0 / 3.0
                })
            })
            .count()
    };
    corners
        .into_iter()
        .min_by_key(|&(_, r, u)| count(r, u))
        .map_or(SeriesLabelPosition::LowerLeft, |c| c.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_legend_goes_to_a_corner_without_points() {
        // Errors falling with time: points upper left and lower right; plus one lower left.
        let pts = [
            (0.2, 0.5),
            (0.3, 0.4),
            (50.0, 0.002),
            (80.0, 0.001),
            (0.2, 0.002),
        ];
        let at = emptiest_corner(&pts, (0.1, 100.0), (0.0005, 1.0));
        assert!(matches!(at, SeriesLabelPosition::UpperRight), "{at:?}");
    }
}
