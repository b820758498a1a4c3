//! The layered bed: one friction angle per layer of `scenes/calibration_layers.ron`, fitted from
//! a side camera that tells the coloured layers apart: each layer's particles as a point cloud
//! (`BODY=FILE` observations, 0.5 dx noise) at frames through the collapse. A calibration with
//! several parameters, where one backward pass prices all of them together while a search's
//! samples must grow with their count: the case the single-parameter cases cannot show.
//!
//! Each pair draws every layer's true angle and start from its seed; the methods share them and
//! the observation, get [`BUDGET_FACTOR`] times the study's budget, and are scored by the RMS
//! error over the layers of their rollout of lowest loss, and by that loss against the loss at
//! the truth (below it, the method has done what the observation allows).

use super::Shared;
use crate::lab::calibrate::observation::Observed;
use crate::lab::calibrate::{
    self, params, AdamConfig, Calibration, Eval, Identifiability, TrustConfig, CURVATURE_STEP,
};
use crate::scene::Scene;
use crate::util::SplitMix64;
use rayon::prelude::*;
use serde::Serialize;
use std::path::PathBuf;

/// The layered column.
pub const SCENE: &str = "scenes/calibration_layers.ron";

/// Its layers, bottom first: material `layerK` is layer K.
pub const LAYERS: usize = 4;

/// Each layer's true friction angle is uniform in this range (°).
pub const TRUTHS: (f64, f64) = (20.0, 42.0);

/// Each layer's start is uniform in this range (°), as the single-parameter cases' starts.
pub const STARTS: (f64, f64) = (15.0, 50.0);

/// The camera sees the layers every this many global steps, to the end (8 frames over the
/// 0.4 s collapse: a camera at 20 Hz).
pub const FRAME_EVERY: usize = 10;

/// Noise on every observed coordinate (m): the 0.5 dx on points (dx = 2.5 mm).
pub const POINT_NOISE: f64 = 1.25e-3;

/// Pairs per `--seeds`.
pub const PAIRS_PER_SEED: usize = 3;

/// The compute per pair and method, as a multiple of the single-parameter cases' budget: four
/// parameters, three times the compute.
pub const BUDGET_FACTOR: f64 = 3.0;

/// The methods, as the journal keys them; CMA-ES last (the paired tests' reference). Adam is
/// left out here: it costs as much again, and the single-parameter cases already place it
/// behind BFGS.
pub const METHODS: [&str; 2] = ["bfgs", "cmaes"];

/// One pair's result for one method.
#[derive(Clone, Debug, Serialize)]
pub struct LayerRun {
    pub pair: usize,
    pub method: String,
    pub truth: Vec<f64>,
    pub start: Vec<f64>,
    pub fitted: Vec<f64>,
    /// RMS over the layers of the fitted angle's error (°).
    pub error: f64,
    /// (compute so far, RMS error of the best rollout so far).
    pub curve: Vec<(f64, f64)>,
    /// The loss of the best rollout, and at the truth.
    pub loss: f64,
    pub truth_loss: f64,
}

/// Pair `k`'s true angles and start, bottom layer first.
pub fn pair(k: usize) -> (Vec<f64>, Vec<f64>) {
    let mut rng = SplitMix64(0x1A7E_0000 + 7919 * k as u64);
    let truth = (0..LAYERS)
        .map(|_| rng.uniform_in(TRUTHS.0, TRUTHS.1))
        .collect();
    let start = (0..LAYERS)
        .map(|_| rng.uniform_in(STARTS.0, STARTS.1))
        .collect();
    (truth, start)
}

/// RMS of `a − b`.
pub fn rms(a: &[f64], b: &[f64]) -> f64 {
    (a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / a.len().max(1) as f64).sqrt()
}

/// The problem of pair `k`: its observation (every [`FRAME_EVERY`] steps, seeded noise) and
/// the scene at its start.
pub fn problem(
    k: usize,
    threads: Option<usize>,
    backward_cost: f64,
) -> anyhow::Result<(Calibration, Vec<f64>, Vec<f64>)> {
    let (truth, start) = pair(k);
    let mut scene = Scene::load(SCENE)?;
    let names: Vec<String> = (0..LAYERS)
        .map(|l| format!("layer{l}.friction_deg"))
        .collect();
    let fit = params::parse(&scene, &names, &[]).map_err(anyhow::Error::msg)?;
    for (p, &v) in fit.iter().zip(&truth) {
        p.apply(&mut scene, v);
    }
    let steps = scene.simulation.steps.unwrap_or(0);
    let mut observed = Vec::new();
    for step in (FRAME_EVERY..=steps).step_by(FRAME_EVERY) {
        let seed = 0x1A7E ^ ((k as u64) << 16) ^ step as u64;
        let clouds = calibrate::observe_bodies(&scene, step, POINT_NOISE, seed, threads)?;
        for (b, obs) in clouds.into_iter().enumerate() {
            let body = scene.bodies[b].name.clone();
            observed.push(Observed {
                path: PathBuf::from(format!("synthetic layers pair {k}: {body}@{step}")),
                step: Some(step),
                body: Some(body),
                what: obs,
            });
        }
    }
    for (p, &v) in fit.iter().zip(&start) {
        p.apply(&mut scene, v);
    }
    let mut cal = Calibration::new(&scene, fit, &observed, None).map_err(anyhow::Error::msg)?;
    cal.threads = threads;
    cal.backward_cost = backward_cost;
    Ok((cal, truth, start))
}

/// What the layered case found: the runs, and the curvature at pair 0's truth (which layers the
/// sequence pins down).
pub struct LayerOutcome {
    pub runs: Vec<LayerRun>,
    pub backward_cost: f64,
    pub identifiability: Option<(Vec<String>, Vec<f64>, Identifiability, usize)>,
}

/// Every pair and method (resuming from the shared journal), then the curvature.
pub(super) fn run(
    shared: &Shared,
    pairs: usize,
    budget: f64,
    threads: Option<usize>,
    backward_cost: f64,
) -> anyhow::Result<LayerOutcome> {
    let jobs: Vec<(usize, &str)> = (0..pairs)
        .flat_map(|k| METHODS.iter().map(move |m| (k, *m)))
        .collect();
    let budget = BUDGET_FACTOR * budget;
    let runs = jobs
        .par_iter()
        .map(|&(k, method)| -> anyhow::Result<LayerRun> {
            let (cal, truth, start) = problem(k, threads, backward_cost)?;
            let u0 = cal.start();
            let key = format!("layers/{k}/{method}");
            let eval = |i: usize, u: &[f64], g: bool| shared.eval(&cal, &key, i, u, g);
            let seed = 0x1A7E + k as u64;
            let trace = match method {
                "adam" => calibrate::adam(&u0, budget, AdamConfig::default(), eval)?,
                "bfgs" => {
                    calibrate::trust_region(&u0, budget, TrustConfig::for_dims(LAYERS), seed, eval)?
                }
                _ => calibrate::cmaes(&u0, budget.floor() as usize, seed, eval)?,
            };
            let (fitted, curve) = score(&trace, &truth);
            let at_truth = cal.to_unit(&truth);
            let truth_loss = shared
                .eval(&cal, &format!("layers/{k}/truth"), 0, &at_truth, false)?
                .loss;
            Ok(LayerRun {
                loss: calibrate::lowest(&trace).map_or(f64::NAN, |e| e.loss),
                truth_loss,
                pair: k,
                method: method.into(),
                error: rms(&fitted, &truth),
                truth,
                start,
                fitted,
                curve,
            })
        })
        .collect::<anyhow::Result<Vec<LayerRun>>>()?;
    // The curvature at pair 0's truth, on every worker.
    let (cal, truth, _) = problem(0, None, backward_cost)?;
    let u = cal.to_unit(&truth);
    let mut i = 0;
    let id = calibrate::identifiability(&cal, &u, CURVATURE_STEP, |u| {
        let e = shared.eval(&cal, "layers/curvature", i, u, false);
        i += 1;
        e
    })?;
    let labels = cal.params.iter().map(|p| p.label.clone()).collect();
    Ok(LayerOutcome {
        runs,
        backward_cost,
        identifiability: Some((labels, truth, id, cal.residuals)),
    })
}

/// The fitted angles of the rollout of lowest loss, and the curve of its RMS error against
/// compute.
fn score(trace: &[Eval], truth: &[f64]) -> (Vec<f64>, Vec<(f64, f64)>) {
    let (mut c, mut best) = (0.0, f64::INFINITY);
    let mut values = vec![f64::NAN; truth.len()];
    let mut curve = Vec::new();
    for e in trace {
        c += e.cost;
        if e.loss < best {
            best = e.loss;
            values = e.values.clone();
        }
        curve.push((c, rms(&values, truth)));
    }
    (values, curve)
}

/// The layered bed's section of the page, and its figure `calibration_layers.svg` in `results`.
pub fn report(o: &LayerOutcome, budget: f64, results: &std::path::Path) -> anyhow::Result<String> {
    use super::report::{method_columns, title};
    use crate::lab::calibrate::plot::{colour, curves_svg, Curve};
    use crate::lab::stats::{mean_sd as mean_std, p_text, wilcoxon_less};
    let total = BUDGET_FACTOR * budget;
    let of = |m: &str| -> Vec<&LayerRun> {
        let mut v: Vec<&LayerRun> = o.runs.iter().filter(|r| r.method == m).collect();
        v.sort_by_key(|r| r.pair);
        v
    };
    let by: Vec<Vec<&LayerRun>> = METHODS.iter().map(|m| of(m)).collect();
    if by.iter().any(|v| v.is_empty()) {
        return Ok(String::new());
    }
    let deg = |v: &[f64]| {
        v.iter()
            .map(|x| format!("{x:.1}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let (head, rule) = method_columns(&["fitted", "RMS error", "loss ÷ truth's"]);
    let mut md = format!(
        "\n## Friction angle per layer of a layered bed (`{SCENE}`, `--fit layer0.friction_deg,…,layer{}.friction_deg`)\n\n\
The column of the first case as {LAYERS} layers of 7.5 mm, each its own material: every layer's true friction angle is drawn \
uniformly from {}° to {}° and its start from {}° to {}°, per pair. A side camera tells the coloured layers apart: each \
layer's particles are observed as a point cloud (`layerK`'s body `bedK=FILE`, a Chamfer loss each) every {FRAME_EVERY} steps \
through the collapse ({} frames, {:.2} mm of noise on every coordinate, the issue's 0.5 dx). Each method gets {total} forward rollouts of compute per pair \
({BUDGET_FACTOR} times the single-parameter cases'; a gradient rollout counts 1 + {:.2}, the backward pass's cost measured \
on this scene) and is scored by the RMS error over the layers of its rollout of lowest loss; \"loss ÷ truth's\" is that \
rollout's loss over the loss at the true angles (under 1: the method found angles the observation prefers to the truth, \
and what error is left is the observation's). Angles are listed bottom layer first.\n\n\
| pair | true | start |{}\n|---|---|---|{}\n",
        LAYERS - 1,
        TRUTHS.0,
        TRUTHS.1,
        STARTS.0,
        STARTS.1,
        80 / FRAME_EVERY,
        POINT_NOISE * 1e3,
        o.backward_cost,
        head,
        rule,
    );
    for (k, a) in by[0].iter().enumerate() {
        md.push_str(&format!(
            "| {} | {} | {} |",
            a.pair,
            deg(&a.truth),
            deg(&a.start)
        ));
        for runs in &by {
            let r = runs[k];
            md.push_str(&format!(
                " {} | {:.2} | {:.4} |",
                deg(&r.fitted),
                r.error,
                r.loss / r.truth_loss
            ));
        }
        md.push('\n');
    }
    let cma = by.last().expect("CMA-ES is the last method");
    md.push('\n');
    for (m, runs) in METHODS.iter().zip(&by) {
        let e: Vec<f64> = runs.iter().map(|r| r.error).collect();
        let (mean, sd) = mean_std(&e);
        let per_layer: Vec<f64> = (0..LAYERS)
            .map(|l| {
                runs.iter()
                    .map(|r| (r.fitted[l] - r.truth[l]).abs())
                    .sum::<f64>()
                    / runs.len() as f64
            })
            .collect();
        md.push_str(&format!(
            "- {}: RMS error {mean:.2} ± {sd:.2}°; mean error per layer, bottom first: {}°",
            title(m),
            deg(&per_layer)
        ));
        if *m != "cmaes" {
            let ec: Vec<f64> = cma.iter().map(|r| r.error).collect();
            md.push_str(&format!(
                "; lower than CMA-ES's: p = {}",
                p_text(wilcoxon_less(&e, &ec))
            ));
        }
        md.push_str(".\n");
    }
    md.push_str(&format!(
        "\nAt smaller budgets (the RMS error of the best rollout so far; p: lower than CMA-ES's, one-sided Wilcoxon over the {} pairs):\n\n",
        cma.len()
    ));
    let curves: Vec<Vec<&[(f64, f64)]>> = by
        .iter()
        .map(|runs| runs.iter().map(|r| r.curve.as_slice()).collect())
        .collect();
    md.push_str(&super::report::budgets_table(
        &METHODS,
        &curves,
        &[total / 4.0, total / 2.0, total],
        "RMS error",
        2,
    ));
    if let Some((labels, truth, id, n)) = &o.identifiability {
        md.push_str(&format!(
            "\nWhich layers the frames pin down, at pair 0's truth: the curvature by central second differences at {} % of each range, standard errors from `Cov(u) ≈ (2L*/n) H⁻¹` with n = {n} observed points over the frames (the Chamfer loss read as least squares); pinned down when under {} % of the range.\n\n| parameter | true | std. error (°) | share | pinned down |\n|---|---|---|---|---|\n",
            id.step * 100.0,
            calibrate::PINNED_SHARE * 100.0
        ));
        for (i, l) in labels.iter().enumerate() {
            md.push_str(&format!(
                "| {l} | {:.2} | {:.3} | {:.2} % | {} |\n",
                truth[i],
                id.std_error[i],
                id.relative[i] * 100.0,
                id.pinned_text(i)
            ));
        }
        let smallest = id.eigenvalues.last().copied().unwrap_or(f64::NAN);
        md.push_str(&format!(
            "\nEigenvalues of the curvature in unit coordinates: {}; the eigenvector of the smallest is ({}), bottom layer first.{}\n",
            id.eigenvalues
                .iter()
                .map(|l| format!("{l:.3e}"))
                .collect::<Vec<_>>()
                .join(", "),
            id.eigenvectors
                .last()
                .map(|v| v.iter().map(|x| format!("{x:.2}")).collect::<Vec<_>>().join(", "))
                .unwrap_or_default(),
            if smallest > 0.0 {
                String::new()
            } else {
                " The curvature is not positive definite: along that direction the loss, at this step, does not rise away from the truth, so no standard error is finite and no layer counts as pinned down by this reading; the pairs' errors above say what the fits recover.".to_string()
            }
        ));
    }
    let figure: Vec<Curve> = by
        .iter()
        .flatten()
        .map(|r| Curve {
            label: r.method.clone(),
            colour: colour(&r.method),
            points: r.curve.clone(),
            faint: false,
        })
        .collect();
    curves_svg(
        &results.join("calibration_layers.svg"),
        "RMS error over the layers of the best rollout so far",
        "compute (forward rollouts)",
        "RMS error (°)",
        &figure,
    )?;
    md.push_str("\n![RMS error over the layers against compute](calibration_layers.svg)\n\nOne line per pair and method.\n");
    Ok(md)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pairs_are_seeded_and_inside_their_ranges() {
        let (t0, s0) = pair(0);
        assert_eq!(pair(0), (t0.clone(), s0.clone()));
        assert_ne!(pair(1).0, t0);
        assert_eq!((t0.len(), s0.len()), (LAYERS, LAYERS));
        assert!(t0.iter().all(|v| (TRUTHS.0..TRUTHS.1).contains(v)));
        assert!(s0.iter().all(|v| (STARTS.0..STARTS.1).contains(v)));
    }

    #[test]
    fn the_score_follows_the_lowest_loss_and_its_rms_error() {
        let e = |values: Vec<f64>, loss: f64| Eval {
            u: values.clone(),
            values,
            loss,
            cost: 1.0,
            grad: None,
            wall_s: 0.0,
        };
        let trace = [
            e(vec![30.0, 30.0], 2.0),
            e(vec![21.0, 40.0], 3.0),
            e(vec![24.0, 28.0], 1.0),
        ];
        let (fitted, curve) = score(&trace, &[20.0, 30.0]);
        assert_eq!(fitted, vec![24.0, 28.0]);
        // RMS of (10, 0), then unchanged (a higher loss), then of (4, −2).
        let r1 = (50.0f64).sqrt();
        assert_eq!(curve, vec![(1.0, r1), (2.0, r1), (3.0, (10.0f64).sqrt())]);
    }
}
