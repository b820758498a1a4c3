//! The benchmark's page: how it was made, each task's verdict and table.

use super::{StudyOptions, TaskResult, BASELINES};
use crate::lab::optim::Method;
use crate::lab::stats::mean_sd as mean_std;
use crate::lab::stats::median;
use crate::lab::stats::{p_text, ALPHA};
use crate::lab::study::machine;

/// The page: how it was made, the verdict per task, the tables.
pub fn page(o: &StudyOptions, results: &[TaskResult]) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Optimisation benchmark: {} at equal compute\n",
        o.methods
            .iter()
            .map(|m| m.name())
            .collect::<Vec<_>>()
            .join(", ")
    );
    let _ = writeln!(s, "Regenerate: `{}`  ", o.command);
    let _ = writeln!(s, "Machine: {}.\n", machine());
    let stream = crate::lab::streams::Stream {
        noun: "Seeds",
        first: o.first_seed,
        count: o.seeds,
        design: crate::lab::optim::DESIGN_SEEDS,
        chosen: "the optimisers' settings (line's bracket and its 1 % closing width, `line` as `optimize`'s default)",
        flag: "--first-seed",
    };
    let _ = writeln!(
        s,
        "**Stream.** {} The CSV numbers the seeds from 0.\n",
        stream.text()
    );
    let (b, c) = (o.budget, crate::lab::optim::report::BACKWARD_COST);
    let has = |ms: &[Method]| ms.iter().any(|m| o.methods.contains(m));
    // What each method does with its budget, for the methods on the page only.
    let parts: [(&[Method], String); 8] = [
        (&BASELINES, format!("random search, CMA-ES and SAC run {b} forward rollouts")),
        (
            &[Method::Grad, Method::Carry, Method::Smoothed],
            format!("grad, carry and smoothed run {b}/(1 + {c}) gradient rollouts (the budgets are planned with a backward pass at {c} forward passes, `docs/results/performance.md`; the scores count it at the multiple each task's run measured, below), rounded up, and their curriculum frees θ_t and θ_p after half of each method's rollouts"),
        ),
        (
            &[Method::Carry],
            "carry is grad whose first half descends the spoon's soft carried mass against the target (at the end of the lift and of the transport) instead of the scene's loss".into(),
        ),
        (
            &[Method::Hybrid, Method::Line, Method::Ray],
            "the hybrid, line and ray spend half their budget on the same forward rollouts at Θ_init and Sobol points (the hybrid's global phase), then go on from the lowest-loss one".into(),
        ),
        (
            &[Method::Hybrid],
            "the hybrid takes trust-region steps along the adjoint gradient".into(),
        ),
        (
            &[Method::Line, Method::Ray],
            format!("where that phase both over- and under-delivered, line and ray first close the segment from its lowest-loss point to the lowest-loss rollout on the target's other side by Illinois regula falsi (forward rollouts, until the bracket is narrower than {} % of the box's half-width)", crate::lab::optim::line::SKILL_REPEATABILITY * 100.0),
        ),
        (
            &[Method::Line],
            format!("line then takes one gradient rollout for an axis, tries forward rollouts at ±{:?} along it for a sign change of target − delivered, closes on it by Illinois regula falsi, and starts again from its lowest-loss point (a new gradient there) until its budget is spent", crate::lab::optim::line::LINE_STEPS),
        ),
        (
            &[Method::Ray],
            "ray is line with random axes and forward rollouts only: the ablation that says whether the adjoint's axis matters (line's column p < ray)".into(),
        ),
    ];
    let how: Vec<String> = parts
        .into_iter()
        .filter(|(ms, _)| has(ms))
        .map(|(_, t)| t)
        .collect();
    let _ = writeln!(
        s,
        "Each task is one skill scene. Every method starts seed k from the same Θ_init and gets the compute of {b} forward rollouts per seed: {}. \
A method's score after some compute is the dose error |target − delivered| of its rollout of lowest loss so far. **Equal compute** reads every method at each seed's smallest spend of simulated particle-substeps over the methods; **equal rollouts** reads every method after the fewest rollouts any method ran. p is the one-sided exact Wilcoxon signed-rank p-value, over the paired seeds, that the method's dose error at equal compute is smaller than the baseline's (ties dropped); a verdict needs p < {ALPHA}. Run time per seed is one core's share (two rollouts run side by side).\n",
        how.join("; "),
    );
    let _ = writeln!(
        s,
        "![median best dose error against compute and rollouts]({}.svg)\n",
        o.page
    );
    for t in results {
        let best_base = t
            .ranked()
            .into_iter()
            .find(|r| BASELINES.contains(&r.method))
            .map(|r| r.method.name())
            .unwrap_or("none");
        let best = t
            .ranked()
            .first()
            .map(|r| r.method.name())
            .unwrap_or("none");
        let _ = writeln!(
            s,
            "## {} (target {} {}, {} paired seeds)\n",
            t.scene, t.target, t.unit, t.seeds
        );
        let winners = t.winners();
        let _ = writeln!(
            s,
            "Budget: {:.2} G particle-substeps per seed on average, a backward pass counted at {}. Lowest mean dose error at equal compute: **{best}**; best baseline: {best_base}. {}\n",
            t.budget_particle_substeps / 1e9,
            t.backward_cost_measured.map_or_else(
                || format!("the planned {c}× a forward pass (no run of both kinds to measure it)"),
                |m| format!("**{m:.2}× a forward pass, as measured in this task's rollouts** (the mean rollout seconds of its gradient rollouts over its forward ones, minus one)")
            ),
            if winners.is_empty() {
                format!("**No gradient-informed method beats all three baselines at p < {ALPHA}.**")
            } else {
                format!(
                    "Beats all three baselines at p < {ALPHA}: **{}**.",
                    winners.iter().map(|m| m.name()).collect::<Vec<_>>().join(", ")
                )
            }
        );
        if let Some(p) = t
            .rows
            .iter()
            .find(|r| r.method == Method::Line)
            .and_then(|r| r.p_vs.get(Method::Ray.name()))
        {
            let _ = writeln!(
                s,
                "line against its ablation ray (random axes): p = {}: {}\n",
                p_text(*p),
                if p.is_some_and(|p| p < ALPHA) {
                    "the adjoint's axis matters."
                } else {
                    "the adjoint's axis is not shown to matter."
                }
            );
        }
        if let Some((base, ps)) = t.worse_than_best_baseline() {
            if !ps.is_empty() {
                let _ = writeln!(
                    s,
                    "No worse than the best baseline? The one-sided p that {} does better than each gradient-informed method (p < {ALPHA}: shown worse): {}.\n",
                    base.name(),
                    ps.iter()
                        .map(|(m, p)| format!(
                            "{} {}{}",
                            m.name(),
                            p_text(*p),
                            if p.is_some_and(|p| p < ALPHA) {
                                " (worse)"
                            } else {
                                ""
                            }
                        ))
                        .collect::<Vec<_>>()
                        .join(", ")
                );
            }
        }
        s.push_str(&table(t));
        s.push('\n');
    }
    s
}

/// The markdown table of one task.
pub fn table(t: &TaskResult) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "| method | dose error at equal compute ({u}), mean ± std | median | p < random | p < cmaes | p < sac | p < ray | rollouts in budget | G particle-substeps | rollout s per seed | dose error at {k} rollouts, mean ± std | method wall s |",
        u = t.unit,
        k = t.equal_rollouts
    );
    s.push_str("|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for r in t.ranked() {
        let (m, sd) = mean_std(&r.dose_equal_compute);
        let (mr, sr) = mean_std(&r.dose_equal_rollouts);
        let p = |b: &str| match r.p_vs.get(b) {
            Some(Some(p)) => format!("{p:.3}"),
            Some(None) => "tie".into(),
            None => "–".into(),
        };
        let _ = writeln!(
            s,
            "| {} | {m:.3} ± {sd:.3} | {:.3} | {} | {} | {} | {} | {:.1} | {:.2} | {:.0} | {mr:.3} ± {sr:.3} | {:.0} |",
            r.method.name(),
            median(&r.dose_equal_compute),
            p("random"),
            p("cmaes"),
            p("sac"),
            p("ray"),
            r.rollouts_in_budget,
            r.particle_substeps / 1e9,
            r.rollout_s,
            t.wall_s.get(r.method.name()).copied().unwrap_or(f64::NAN),
        );
    }
    s
}
