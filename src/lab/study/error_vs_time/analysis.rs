//! The analysis of `study error-vs-time`'s results: each quantity's error against the case's
//! finest grid, the sweep's finest configuration and the published law, the gradient against
//! its central difference, the Pareto front of run time against error, and the CSV and
//! Markdown tables.

use super::{quantities, Case, ConfigResult, Sweep, COLLAPSE_ASPECT};
use crate::lab::stats::norm;
use crate::lab::validate::lube_runout;
use serde::Serialize;

/// One row of the analysis: one quantity of one configuration.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Row {
    pub case: Case,
    pub sweep: Sweep,
    pub label: String,
    pub dx_m: f64,
    pub particles_per_cell: usize,
    pub substeps_per_step: usize,
    pub particles: usize,
    pub quantity: String,
    /// The value (for the gradient: the norm of `∂L/∂Θ` per particle).
    pub value: f64,
    /// The case's reference value: its finest resolution.
    pub reference_value: Option<f64>,
    /// Relative error against the reference (for the gradient: `‖g − g_ref‖/‖g_ref‖`).
    pub error_vs_reference: Option<f64>,
    /// Relative error against the finest configuration of the same sweep.
    pub error_vs_sweep_finest: Option<f64>,
    pub law_value: Option<f64>,
    pub error_vs_law: Option<f64>,
    /// Gradient only: `|g·u − FD|/max(|g·u|, |FD|)` along the direction `u`.
    pub error_vs_fd: Option<f64>,
    /// Wall time of what produced the value (s): the forward run, or forward + backward.
    pub wall_s: f64,
    pub peak_rss_bytes: u64,
    /// This configuration is the case's reference.
    pub is_reference: bool,
    /// On the Pareto front of error against the reference versus wall time.
    pub pareto: bool,
    /// On the Pareto front of error against the law versus wall time.
    pub pareto_vs_law: bool,
}

/// `|a − b|/|b|`; against a reference of zero, 0 if `a` is zero too and ∞ otherwise (a run
/// that moved powder where the reference moved none has no finite relative error).
fn rel(a: f64, b: f64) -> f64 {
    if b == 0.0 {
        if a == 0.0 {
            0.0
        } else {
            f64::INFINITY
        }
    } else {
        (a - b).abs() / b.abs()
    }
}

/// Relative distance between two gradients, `‖a − b‖/‖b‖`.
pub fn gradient_error(a: &[f64; 5], b: &[f64; 5]) -> f64 {
    let d: Vec<f64> = a.iter().zip(b).map(|(a, b)| a - b).collect();
    norm(&d) / norm(b).max(1e-300)
}

/// The finest result of each (case, sweep), and each case's reference (the finest resolution).
fn finest(results: &[ConfigResult], case: Case, sweep: Sweep) -> Option<&ConfigResult> {
    results
        .iter()
        .filter(|r| r.failed.is_none() && r.config.case == case && r.config.sweep == sweep)
        .max_by(|a, b| a.config.fineness().total_cmp(&b.config.fineness()))
}

fn value_of(r: &ConfigResult, q: &str) -> Option<f64> {
    if q == "gradient" {
        r.gradient.as_ref().map(|g| norm(&g.per_particle))
    } else {
        r.values.get(q).copied()
    }
}

fn error_of(r: &ConfigResult, reference: &ConfigResult, q: &str) -> Option<f64> {
    if q == "gradient" {
        Some(gradient_error(
            &r.gradient.as_ref()?.per_particle,
            &reference.gradient.as_ref()?.per_particle,
        ))
    } else {
        Some(rel(value_of(r, q)?, value_of(reference, q)?))
    }
}

/// Marks the Pareto front: the points that no faster point matches or beats on error.
/// `points` are (wall time, error); the answer has one flag per point.
pub fn pareto_front(points: &[(f64, f64)]) -> Vec<bool> {
    let mut order: Vec<usize> = (0..points.len()).collect();
    order.sort_by(|&a, &b| {
        points[a]
            .0
            .total_cmp(&points[b].0)
            .then(points[a].1.total_cmp(&points[b].1))
    });
    let mut flags = vec![false; points.len()];
    let mut best = f64::INFINITY;
    for i in order {
        if points[i].1 < best {
            flags[i] = true;
            best = points[i].1;
        }
    }
    flags
}

/// The analysis: one row per configuration and quantity, errors and Pareto fronts.
pub fn analyse(results: &[ConfigResult]) -> Vec<Row> {
    let mut rows = Vec::new();
    for case in [Case::ColumnCollapse, Case::PowderTransport] {
        let reference = finest(results, case, Sweep::Resolution);
        for &q in quantities(case) {
            let start = rows.len();
            for r in results
                .iter()
                .filter(|r| r.failed.is_none() && r.config.case == case)
            {
                let Some(value) = value_of(r, q) else {
                    continue;
                };
                let is_reference = reference.is_some_and(|f| f.config == r.config);
                let sweep_finest = finest(results, case, r.config.sweep);
                // The published run-out is where the deposit ends: the fronts, not the percentile.
                let law = (case == Case::ColumnCollapse && q != "runout_p99_ratio")
                    .then(|| lube_runout(COLLAPSE_ASPECT));
                let g = if q == "gradient" {
                    r.gradient.as_ref()
                } else {
                    None
                };
                rows.push(Row {
                    case,
                    sweep: r.config.sweep,
                    label: r.config.label(),
                    dx_m: r.config.dx,
                    particles_per_cell: r.config.particles_per_cell,
                    substeps_per_step: r.substeps_per_step,
                    particles: r.particles,
                    quantity: q.to_string(),
                    value,
                    reference_value: reference.and_then(|f| value_of(f, q)),
                    error_vs_reference: reference.and_then(|f| error_of(r, f, q)),
                    error_vs_sweep_finest: sweep_finest.and_then(|f| error_of(r, f, q)),
                    law_value: law,
                    error_vs_law: law.map(|l| rel(value, l)),
                    error_vs_fd: g.map(|g| {
                        (g.directional_adjoint - g.directional_fd).abs()
                            / g.directional_adjoint
                                .abs()
                                .max(g.directional_fd.abs())
                                .max(1e-300)
                    }),
                    wall_s: g.map_or(r.wall_s, |g| g.wall_s),
                    peak_rss_bytes: g.map_or(r.peak_rss_bytes, |g| g.peak_rss_bytes),
                    is_reference,
                    pareto: false,
                    pareto_vs_law: false,
                });
            }
            let block = &mut rows[start..];
            for law in [false, true] {
                let error = |r: &Row| {
                    if law {
                        r.error_vs_law
                    } else {
                        r.error_vs_reference
                    }
                };
                // The reference's own error is zero by construction: it is not a point of the
                // trade-off against itself, but it is one against the law.
                let idx: Vec<usize> = (0..block.len())
                    .filter(|&i| law || !block[i].is_reference)
                    .filter(|&i| error(&block[i]).is_some_and(|e| e.is_finite() && e > 0.0))
                    .collect();
                let pts: Vec<(f64, f64)> = idx
                    .iter()
                    .map(|&i| (block[i].wall_s, error(&block[i]).unwrap_or(f64::NAN)))
                    .collect();
                for (k, on) in pareto_front(&pts).into_iter().enumerate() {
                    if law {
                        block[idx[k]].pareto_vs_law = on;
                    } else {
                        block[idx[k]].pareto = on;
                    }
                }
            }
        }
    }
    rows
}

fn opt(v: Option<f64>) -> String {
    v.map_or(String::new(), |v| format!("{v:.6e}"))
}

/// The analysis as CSV, one row per configuration and quantity.
pub fn csv(rows: &[Row]) -> String {
    let mut s = String::from(
        "case,sweep,dx_m,particles_per_cell,substeps_per_step,particles,quantity,value,\
         reference_value,error_vs_reference,error_vs_sweep_finest,law_value,error_vs_law,\
         error_vs_fd,wall_s,peak_rss_bytes,is_reference,pareto,pareto_vs_law\n",
    );
    for r in rows {
        s.push_str(&format!(
            "{},{},{},{},{},{},{},{:.6e},{},{},{},{},{},{},{:.3},{},{},{},{}\n",
            r.case.name(),
            r.sweep.name(),
            r.dx_m,
            r.particles_per_cell,
            r.substeps_per_step,
            r.particles,
            r.quantity,
            r.value,
            opt(r.reference_value),
            opt(r.error_vs_reference),
            opt(r.error_vs_sweep_finest),
            opt(r.law_value),
            opt(r.error_vs_law),
            opt(r.error_vs_fd),
            r.wall_s,
            r.peak_rss_bytes,
            r.is_reference,
            r.pareto,
            r.pareto_vs_law,
        ));
    }
    s
}

/// A Markdown table of the analysis (for `docs/results/error_vs_time.md` and the terminal).
pub fn markdown(rows: &[Row]) -> String {
    let pct = |v: Option<f64>| v.map_or(String::new(), crate::util::percent);
    let mut s = String::from(
        "| case | sweep | dx (mm) | ppc | substeps | particles | quantity | value | err vs finest | err vs law | err vs FD | wall (s) | peak RSS (MB) | Pareto |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        s.push_str(&format!(
            "| {} | {} | {:.3} | {} | {} | {} | {} | {:.4e} | {} | {} | {} | {:.1} | {:.0} | {} |\n",
            r.case.name(),
            r.sweep.name(),
            r.dx_m * 1e3,
            r.particles_per_cell,
            r.substeps_per_step,
            r.particles,
            r.quantity,
            r.value,
            if r.is_reference {
                "reference".to_string()
            } else {
                pct(r.error_vs_reference)
            },
            pct(r.error_vs_law),
            pct(r.error_vs_fd),
            r.wall_s,
            r.peak_rss_bytes as f64 / 1e6,
            if r.pareto { "●" } else { "" },
        ));
    }
    s
}
