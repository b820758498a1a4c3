//! The calibration study's page: per case, the recovery table of every method with paired
//! tests against CMA-ES at several budgets and the compute each needs to settle; the joint fit's
//! curvature; the loss's grain; and the figure.

use super::{Outcome, Run, CASES, GRAIN, HEIGHT_NOISE, METHODS};
use crate::lab::calibrate::{self, plot::colour, plot::curves_svg, plot::Curve};
use crate::lab::stats::{mean_sd as mean_std, p_text, wilcoxon_less};
use std::path::Path;

/// How the page names a method.
pub(super) fn title(method: &str) -> &'static str {
    match method {
        "adam" => "Adam",
        "bfgs" => "BFGS",
        _ => "CMA-ES",
    }
}

/// A table's header cells and separators for `columns` of each method in [`METHODS`], each
/// named "METHOD COLUMN": the cells after the table's leading columns.
pub(super) fn method_columns(columns: &[&str]) -> (String, String) {
    let head = METHODS
        .iter()
        .flat_map(|m| columns.iter().map(move |c| format!(" {} {c} |", title(m))))
        .collect();
    (head, "---|".repeat(columns.len() * METHODS.len()))
}

/// Each method's error at `budgets`, read off each run's curve (compute, error of the best
/// rollout so far), with a one-sided Wilcoxon p that it is lower than CMA-ES's (the last method):
/// the header, then a row per budget. `curves[m]` are method `m`'s runs, paired in order.
pub(super) fn budgets_table(
    methods: &[&str],
    curves: &[Vec<&[(f64, f64)]>],
    budgets: &[f64],
    what: &str,
    digits: usize,
) -> String {
    let mut md = format!(
        "| compute (forward rollouts) |{}\n|---|{}\n",
        methods
            .iter()
            .map(|m| if *m == "cmaes" {
                format!(" {} {what} |", title(m))
            } else {
                format!(" {0} {what} | {0}: p |", title(m))
            })
            .collect::<String>(),
        "---|".repeat(2 * methods.len() - 1)
    );
    for &b in budgets {
        let at = |c: &[(f64, f64)]| {
            c.iter()
                .take_while(|p| p.0 <= b + 1e-9)
                .last()
                .map_or(f64::NAN, |p| p.1)
        };
        let cma = curves.last().expect("CMA-ES is the last method");
        let xc: Vec<f64> = cma.iter().map(|c| at(c)).collect();
        md.push_str(&format!("| {b} |"));
        for (m, runs) in methods.iter().zip(curves) {
            let x: Vec<f64> = runs.iter().map(|c| at(c)).collect();
            let (mean, sd) = mean_std(&x);
            md.push_str(&format!(" {mean:.digits$} ± {sd:.digits$} |"));
            if *m != "cmaes" {
                md.push_str(&format!(" {} |", p_text(wilcoxon_less(&x, &xc))));
            }
        }
        md.push('\n');
    }
    md
}

/// The compute after which a run's best-so-far error stays within `tol`: the first point of
/// `curve` (compute, error) from which every later error is within it; `None` if the last is not.
pub fn settled(curve: &[(f64, f64)], tol: f64) -> Option<f64> {
    let mut at = None;
    for &(c, e) in curve.iter().rev() {
        if e <= tol {
            at = Some(c);
        } else {
            break;
        }
    }
    at
}

/// What a sweep `(x, loss, dL/dx)` says of the loss's grain.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grain {
    /// Interior points lower than both neighbours.
    pub minima: usize,
    /// Interior points whose gradient has the sign of their neighbours' central difference.
    pub agree_local: usize,
    /// Points whose gradient has the sign of the secant over the whole sweep.
    pub agree_secant: usize,
    /// That secant, per unit of x.
    pub secant: f64,
    /// The largest rise a walk down the secant meets: `(rise, from x, to x)`, the loss going up
    /// from `from` to `to` although the sweep as a whole goes down.
    pub barrier: (f64, f64, f64),
}

/// The [`Grain`] of a sweep of at least three points, in order of x.
pub fn grain_summary(pts: &[(f64, f64, f64)]) -> Grain {
    let minima = pts
        .windows(3)
        .filter(|w| w[1].1 < w[0].1 && w[1].1 < w[2].1)
        .count();
    let agree_local = pts
        .windows(3)
        .filter(|w| w[1].2.signum() == (w[2].1 - w[0].1).signum())
        .count();
    let (first, last) = (pts[0], pts[pts.len() - 1]);
    let secant = (last.1 - first.1) / (last.0 - first.0);
    let agree_secant = pts
        .iter()
        .filter(|p| p.2.signum() == secant.signum())
        .count();
    // Walk in the direction the loss falls overall; the rise above the lowest point so far.
    let walk: Vec<&(f64, f64, f64)> = if secant <= 0.0 {
        pts.iter().collect()
    } else {
        pts.iter().rev().collect()
    };
    let mut low = walk[0];
    let mut barrier = (0.0, low.0, low.0);
    for p in walk {
        if p.1 < low.1 {
            low = p;
        } else if p.1 - low.1 > barrier.0 {
            barrier = (p.1 - low.1, low.0, p.0);
        }
    }
    Grain {
        minima,
        agree_local,
        agree_secant,
        secant,
        barrier,
    }
}

/// The page: per case, the recovery table with each adjoint method against CMA-ES in a paired
/// test, the joint fit's curvature and the loss's grain; and the figure `calibration.svg` in
/// `results`.
pub fn report(
    o: &Outcome,
    command: &str,
    machine: &str,
    budget: f64,
    results: &Path,
) -> anyhow::Result<String> {
    let (runs, joint, costs) = (&o.runs, &o.joint, &o.costs);
    let grain = grain_summary(&o.grain);
    let mut md = format!(
        "# Calibration from observations\n\nRegenerate with `{command}` ({machine}).\n\n\
Synthetic observations: each scene is run at a true parameter value and its final surface is seen \
as a height map (a pixel per particle spacing, 1.25 mm) with {:.0} mm of Gaussian noise on every height. Each \
(true value, start) pair gives three methods the same compute: Adam on the adjoint gradient (normalised \
gradient descent, as DPSI uses), BFGS (a bounded trust-region quasi-Newton method on the adjoint gradient, after a scan of \
four forward rollouts per parameter; `src/lab/calibrate/trust.rs`) and CMA-ES on the forward loss: \
{budget} forward rollouts (a gradient rollout counts 1 + the backward pass's cost); each is scored \
by the parameter error of its rollout of lowest loss. p is a one-sided Wilcoxon signed-rank test \
over the pairs that a gradient method's error is lower than CMA-ES's. The backward pass's cost was measured on each scene \
(one thread, median of three): {} forward rollouts.\n",
        HEIGHT_NOISE * 1e3,
        costs.iter().zip(&CASES).map(|(c, k)| format!("{c:.2} on `{}`", k.scene)).collect::<Vec<_>>().join(", ")
    );
    let mut curves: Vec<(usize, &Run)> = Vec::new();
    for (ci, case) in CASES.iter().enumerate() {
        let of = |m: &str| -> Vec<&Run> {
            let mut v: Vec<&Run> = runs
                .iter()
                .filter(|r| r.case == ci && r.method == m)
                .collect();
            v.sort_by(|a, b| a.truth.total_cmp(&b.truth).then(a.seed.cmp(&b.seed)));
            v
        };
        let by: Vec<Vec<&Run>> = METHODS.iter().map(|m| of(m)).collect();
        if by.iter().any(|v| v.is_empty()) {
            continue;
        }
        let (head, rule) = method_columns(&["fitted", "error"]);
        md.push_str(&format!(
            "\n## {} (`{}`, `--fit {}`)\n\n| true | start |{head}\n|---|---|{rule}\n",
            case.name, case.scene, case.param,
        ));
        for (k, a) in by[0].iter().enumerate() {
            md.push_str(&format!("| {} | {:.3} |", a.truth, a.start));
            for runs in &by {
                md.push_str(&format!(" {:.3} | {:.3} |", runs[k].fitted, runs[k].error));
            }
            md.push('\n');
        }
        // Pairs within the tolerance, and true values with every start within it.
        let recovered = |runs: &[&Run]| {
            let pairs = runs.iter().filter(|r| r.error <= case.tolerance).count();
            let truths = case
                .truths
                .iter()
                .filter(|t| {
                    runs.iter()
                        .filter(|r| r.truth == **t)
                        .all(|r| r.error <= case.tolerance)
                })
                .count();
            (pairs, truths)
        };
        let cma = by.last().expect("CMA-ES is the last method");
        let ec: Vec<f64> = cma.iter().map(|r| r.error).collect();
        md.push('\n');
        for (m, runs) in METHODS.iter().zip(&by) {
            let e: Vec<f64> = runs.iter().map(|r| r.error).collect();
            let (mean, sd) = mean_std(&e);
            let (pairs, truths) = recovered(runs);
            md.push_str(&format!(
                "- {}: error {mean:.3} ± {sd:.3}{u}, {pairs}/{n} pairs within {tol}{u}, {truths}/5 true values with every start within it",
                title(m),
                n = e.len(),
                tol = case.tolerance,
                u = case.unit
            ));
            if *m != "cmaes" {
                let p = p_text(wilcoxon_less(&e, &ec));
                md.push_str(&format!("; lower than CMA-ES's: p = {p}"));
            }
            md.push_str(".\n");
        }
        md.push_str("\nAt smaller budgets (the error of the best rollout so far, read off each run's curve; p: lower than CMA-ES's):\n\n");
        let of_method: Vec<Vec<&[(f64, f64)]>> = by
            .iter()
            .map(|runs| runs.iter().map(|r| r.curve.as_slice()).collect())
            .collect();
        md.push_str(&budgets_table(
            &METHODS,
            &of_method,
            &[10.0, 20.0, budget],
            "error",
            3,
        ));
        md.push_str(&format!(
            "\nCompute until the best rollout stays within {tol}{u} of the truth, median over the pairs that get there:",
            tol = case.tolerance,
            u = case.unit
        ));
        for (k, (m, runs)) in METHODS.iter().zip(&by).enumerate() {
            let reached: Vec<f64> = runs
                .iter()
                .filter_map(|r| settled(&r.curve, case.tolerance))
                .collect();
            md.push_str(&format!(
                "{} {} {} ({}/{} pairs)",
                if k == 0 { "" } else { ";" },
                title(m),
                if reached.is_empty() {
                    "–".to_string()
                } else {
                    format!("{:.1}", crate::lab::stats::median(&reached))
                },
                reached.len(),
                runs.len()
            ));
        }
        md.push_str(".\n");
        for runs in &by {
            for r in runs {
                curves.push((ci, *r));
            }
        }
    }
    if let Some((cal, best, id)) = joint {
        md.push_str(&format!(
            "\n## Which parameters one pile pins down\n\nThe collapse at friction_deg 30, youngs_modulus 5e4 and floor.friction 0.5, fitted jointly by BFGS from 36, 1.5e5 and 0.35 ({} forward rollouts of compute; its best loss {:.4e} against {:.4e} at the truth). The curvature is taken at the truth (what the observation can pin down, whatever an optimiser reaches), by central second differences of the loss at {} % of each range, where the loss's roughness averages out. Standard errors from `Cov(u) ≈ (2L*/n) H⁻¹` with n = {} pixels, infinite where the curvature is not positive definite; pinned down when under {} % of the range (of the value, for Young's modulus, searched in decades).\n\n| parameter | true | BFGS's fit | std. error | share | pinned down |\n|---|---|---|---|---|---|\n",
            2.0 * budget,
            best.loss,
            id.loss,
            id.step * 100.0,
            cal.residuals,
            calibrate::PINNED_SHARE * 100.0
        ));
        for (i, p) in cal.params.iter().enumerate() {
            md.push_str(&format!(
                "| {} | {:.4} | {:.4} | {:.3e} | {:.1} % | {} |\n",
                p.label,
                p.from_unit(id.at[i]),
                best.values[i],
                id.std_error[i],
                id.relative[i] * 100.0,
                id.pinned_text(i)
            ));
        }
        md.push_str(&format!(
            "\nEigenvalues of the curvature in unit coordinates: {}; the eigenvector of the smallest is ({}) in the order above.\n",
            id.eigenvalues.iter().map(|l| format!("{l:.3e}")).collect::<Vec<_>>().join(", "),
            id.eigenvectors.last().map(|v| v.iter().map(|x| format!("{x:.2}")).collect::<Vec<_>>().join(", ")).unwrap_or_default()
        ));
    }
    let mut figure = Vec::new();
    for (ci, r) in &curves {
        let scale = (CASES[*ci].starts.1 - CASES[*ci].starts.0).max(1e-12);
        figure.push(Curve {
            label: format!(
                "{} ({})",
                r.method,
                if *ci == 0 {
                    "friction angle"
                } else {
                    "floor friction"
                }
            ),
            colour: colour(&r.method),
            points: r.curve.iter().map(|&(c, e)| (c, e / scale)).collect(),
            faint: *ci == 1,
        });
    }
    curves_svg(
        &results.join("calibration.svg"),
        "parameter error of the best rollout so far, as a share of the start range",
        "compute (forward rollouts)",
        "error / start range",
        &figure,
    )?;
    md.push_str(&format!(
        "\n## The loss's grain\n\nThe collapse's loss for a true {:.0}° (the pairs' observation), a gradient rollout every {:.1}° from {:.0}° to {:.0}°. Over the sweep the loss falls by {:.1} % (secant {:.3e} per degree), but not monotonically: it has {} interior local minima, and walking down the secant a local method meets a rise of {:.1} % of the loss there, from {:.1}° to {:.1}°. The adjoint gradient follows the loss it differentiates: it has the sign of its neighbours' central difference at {} of {} interior points, and the secant's sign at {} of {}. A descent stops at the first such rise wider than its region; a search that spreads its rollouts over degrees does not see it. This is why the trust region stops shrinking at [`MIN_RADIUS`](../../src/calibrate/trust.rs) (0.5°) and spends what is left in another basin.\n\n| friction (°) | loss | ∂L/∂φ (per degree) |\n|---|---|---|\n",
        GRAIN.0,
        (GRAIN.2 - GRAIN.1) / (GRAIN.3 - 1) as f64,
        GRAIN.1,
        GRAIN.2,
        100.0 * (o.grain[0].1 - o.grain[o.grain.len() - 1].1) / o.grain[0].1,
        grain.secant,
        grain.minima,
        100.0 * grain.barrier.0
            / o.grain
                .iter()
                .find(|p| p.0 == grain.barrier.1)
                .map_or(f64::NAN, |p| p.1),
        grain.barrier.1,
        grain.barrier.2,
        grain.agree_local,
        o.grain.len() - 2,
        grain.agree_secant,
        o.grain.len()
    ));
    for (v, l, g) in &o.grain {
        md.push_str(&format!("| {v:.1} | {l:.4e} | {g:.3e} |\n"));
    }
    md.push_str("\n![parameter error against compute](calibration.svg)\n\nBold lines: friction angle; pale lines: floor friction. One line per (true value, start) pair.\n");
    Ok(md)
}

#[cfg(test)]
mod tests {
    use super::settled;

    #[test]
    fn the_grain_summary_counts_minima_agreement_and_the_barrier() {
        // Falls overall, with a bump from x = 1 (4.0) to x = 2 (4.5).
        let pts = [
            (0.0, 5.0, -1.0),
            (1.0, 4.0, 0.5),
            (2.0, 4.5, -2.0),
            (3.0, 3.0, -1.0),
            (4.0, 1.0, -0.1),
        ];
        let g = super::grain_summary(&pts);
        assert_eq!((g.minima, g.agree_secant, g.secant), (1, 4, -1.0));
        // Central differences at 1, 2, 3: −0.5, −0.5, −1.75; gradients 0.5, −2, −1.
        assert_eq!(g.agree_local, 2);
        assert_eq!(g.barrier, (0.5, 1.0, 2.0));
    }

    #[test]
    fn a_run_settles_where_its_error_enters_the_tolerance_for_good() {
        let c = [(1.0, 5.0), (2.0, 0.5), (3.0, 2.0), (4.0, 0.8), (5.0, 0.3)];
        assert_eq!(settled(&c, 1.0), Some(4.0));
        assert_eq!(settled(&c, 0.1), None);
        assert_eq!(settled(&c, 10.0), Some(1.0));
    }
}
