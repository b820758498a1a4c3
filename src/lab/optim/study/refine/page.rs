//! The page of `powderlab study refine`: the table of methods by dimension at equal compute,
//! and the verdicts computed from it.

use super::{Cell, Screen, ADAM_LR, ADJOINT, BASELINES, CMA_SIGMA0, LINE_STEPS};
use crate::lab::optim::report::BACKWARD_COST;
use crate::lab::stats::mean_sd as mean_std;
use crate::lab::stats::median;
use crate::lab::stats::wilcoxon_less;

/// The page.
pub fn report(
    cells: &[Cell],
    command: &str,
    unit: &str,
    budget: usize,
    screen: Option<Screen>,
) -> String {
    use std::fmt::Write;
    let mut s = String::from(
        "# Trajectory refinement: the adjoint against CMA-ES, random search and SAC by dimension\n\n",
    );
    let _ = writeln!(s, "Regenerate: `{command}`  ");
    let _ = writeln!(s, "Machine: {}.\n", crate::lab::study::machine());
    let start = match screen {
        None => "Θ_init(k)".to_string() + ",",
        Some(sc) => format!(
            "the k-th point of the landscape map's Sobol design whose plain skill delivers at least {} {unit} more than the target: a spoon that carries more than the dose, so that the transport and the pour decide how much arrives. A residual on the transport and the pour cannot add to the spoon's load, so a start that delivers less than the target cannot reach it at all; of the {} points screened, {} deliver at least the target and {} at least {} {unit} more (the screening rollouts count against no method)",
            sc.over, sc.screened, sc.reach, cells.first().map_or(0, |c| c.dose.len()), sc.over
        ),
    };
    let mut measured: Vec<String> = Vec::new();
    for c in cells {
        let t = format!("{:.2} ({} knots)", c.backward_cost, c.knots);
        if !measured.contains(&t) {
            measured.push(t);
        }
    }
    let measured = measured.join(", ");
    let _ = writeln!(
        s,
        "Seed k refines the skill of Θ_k with residuals on its transport and pour (6 channels × knots parameters, `optim::refine`), Θ_k being {start}. Every method starts from the plain skill and gets the compute of {budget} forward rollouts (the gradient methods' rollouts planned with a backward pass at {BACKWARD_COST}×; the scores count it at {}×, measured in the study's own rollouts: the mean seconds of its gradient rollouts over its forward ones, minus one). line: the adjoint's direction, then a bracketed root search of the dose along it with forward rollouts (steps {LINE_STEPS:?} each way, then Illinois regula falsi); ray: the same search along random directions, forward rollouts only (the ablation: does the adjoint's direction matter?); adam: Adam (lr {ADAM_LR}) on the adjoint gradient; trust: the adjoint's direction in a trust region that keeps a step only if the loss falls (the hybrid's local phase); cmaes: CMA-ES (σ₀ {CMA_SIGMA0}); random: uniform draws in the box; sac: the optimiser benchmark's SAC over the residuals (its first action the plain skill). Score: dose error ({unit}) of the lowest-loss rollout within each seed's equal-compute budget. p: one-sided exact Wilcoxon signed-rank over the paired seeds that the adjoint method's dose error is smaller than the baseline's (ties dropped).\n",
        measured
    );
    s.push_str("| parameters | method | dose error mean ± std | median | p < cmaes | p < random | p < sac | p < ray | rollouts | G particle-substeps |\n|---|---|---|---|---|---|---|---|---|---|\n");
    for c in cells {
        let (m, sd) = mean_std(&c.dose);
        let p = |base: &str| {
            let b = cells
                .iter()
                .find(|b| b.knots == c.knots && b.method == base);
            match b {
                Some(b) if ADJOINT.contains(&c.method.as_str()) => {
                    wilcoxon_less(&c.dose, &b.dose).map_or("tie".to_string(), |p| format!("{p:.3}"))
                }
                _ => "–".to_string(),
            }
        };
        let _ = writeln!(
            s,
            "| {} | {} | {m:.3} ± {sd:.3} | {:.3} | {} | {} | {} | {} | {:.1} | {:.2} |",
            6 * c.knots,
            c.method,
            median(&c.dose),
            p("cmaes"),
            p("random"),
            p("sac"),
            p("ray"),
            c.rollouts,
            c.cost / 1e9
        );
    }
    s.push_str(&verdicts(cells));
    s
}

/// One line per dimension and adjoint method: does it beat the baselines (CMA-ES, random
/// search and SAC, those of them that ran) at p < 0.05, and does it beat its own forward-only
/// ablation (ray)?
fn verdicts(cells: &[Cell]) -> String {
    use std::fmt::Write;
    let mut s = String::from("\n");
    let find = |k: usize, m: &str| cells.iter().find(|c| c.knots == k && c.method == m);
    let p = |a: &Cell, b: Option<&Cell>| b.and_then(|b| wilcoxon_less(&a.dose, &b.dose));
    for c in cells
        .iter()
        .filter(|c| ADJOINT.contains(&c.method.as_str()))
    {
        let ran: Vec<(&str, Option<f64>)> = BASELINES
            .iter()
            .filter_map(|b| find(c.knots, b).map(|cell| (*b, p(c, Some(cell)))))
            .collect();
        let beats = !ran.is_empty() && ran.iter().all(|(_, q)| q.is_some_and(|q| q < 0.05));
        if !beats {
            continue;
        }
        let _ = write!(
            s,
            "- **{} parameters, {}: beats {} at p < 0.05** ({})",
            6 * c.knots,
            c.method,
            ran.iter()
                .map(|(b, _)| baseline_name(b))
                .collect::<Vec<_>>()
                .join(", "),
            ran.iter()
                .map(|(_, q)| fmt_p(*q))
                .collect::<Vec<_>>()
                .join(", ")
        );
        match p(c, find(c.knots, "ray")) {
            Some(q) if q < 0.05 => {
                let _ = writeln!(s, "; it also beats the same search along random directions (p = {q:.3}), so the adjoint's direction is what wins.");
            }
            q => {
                let _ = writeln!(s, "; **but not the same search along random directions** ({}): the bracketed root search of the dose wins, and the adjoint's direction is not shown to matter.", fmt_p(q));
            }
        }
    }
    if s.len() == 1 {
        s.push_str("- No adjoint method beats the baselines at p < 0.05.\n");
    }
    s
}

/// A baseline's name on the page.
fn baseline_name(b: &str) -> &'static str {
    match b {
        "cmaes" => "CMA-ES",
        "random" => "random search",
        _ => "SAC",
    }
}

fn fmt_p(p: Option<f64>) -> String {
    p.map_or("tie".to_string(), |p| format!("p = {p:.3}"))
}

#[cfg(test)]
mod tests {
    use super::{verdicts, Cell};

    fn cell(method: &str, dose: Vec<f64>) -> Cell {
        Cell {
            knots: 5,
            method: method.into(),
            dose,
            rollouts: 20.0,
            cost: 1.0,
            backward_cost: 3.0,
        }
    }

    #[test]
    fn the_verdict_names_a_win_over_the_baselines_that_its_ablation_matches() {
        let low: Vec<f64> = (0..10).map(|i| 0.01 + 0.001 * i as f64).collect();
        let high: Vec<f64> = (0..10).map(|i| 0.5 + 0.01 * i as f64).collect();
        let cells = [
            cell("line", low.clone()),
            cell("cmaes", high.clone()),
            cell("random", high.clone()),
        ];
        let tie_with_ray = [&cells[..], &[cell("ray", low.clone())]].concat();
        assert!(verdicts(&tie_with_ray).contains("but not the same search along random"));
        let beats_ray = [&cells[..], &[cell("ray", high.clone())]].concat();
        assert!(verdicts(&beats_ray).contains("so the adjoint's direction is what wins"));
        let loses = [
            cell("line", high.clone()),
            cell("cmaes", low.clone()),
            cell("random", low.clone()),
        ];
        assert!(verdicts(&loses).contains("No adjoint method beats"));
        // With SAC run, a win must beat it too.
        let sac_wins = [&cells[..], &[cell("sac", low.clone())]].concat();
        assert!(verdicts(&sac_wins).contains("No adjoint method beats"));
        let sac_loses = [&cells[..], &[cell("sac", high.clone())]].concat();
        assert!(verdicts(&sac_loses).contains("beats CMA-ES, random search, SAC at p < 0.05"));
    }
}
