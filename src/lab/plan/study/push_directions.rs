//! The push task's direction test (on the planning page): at the scripted stroke from the
//! start of each layout, the cosine between the adjoint gradient of the push loss in Φ and the
//! secant gradients of the measures the plan is judged by: the hard share of the mass outside
//! the region (`1 −` what success counts) and the soft share outside (what both optimisers
//! keep the best stroke by). `ĝ_k = (m(Φ + h·e_k) − m(Φ − h·e_k))/(Φ⁺_k − Φ⁻_k)`, the steps
//! clamped to the box; 1 means descending the push loss descends the measure at the scale `h`.
//!
//! The rollouts go through each layout's plan journal, so a killed run resumes.

use super::push::{push_scene_of, PushInstance};
use crate::lab::plan::output::journal_path;
use crate::lab::plan::push::Push;
use crate::lab::stats::{cosine, mean, median};
use std::fmt::Write;
use std::path::Path;

/// The secants' steps (Φ units).
pub const STEPS: [f64; 2] = [0.1, 0.05];

/// One point: its label and, per step, the cosines against the hard and the soft share.
#[derive(Clone, Debug)]
pub struct Point {
    pub label: String,
    pub share: f64,
    pub cosines: Vec<(f64, f64)>,
}

/// The test at the scripted stroke from the start of each instance.
pub fn run(
    base: &crate::scene::Scene,
    dir: &Path,
    instances: &[PushInstance],
    progress: &dyn Fn(usize),
) -> anyhow::Result<Vec<Point>> {
    let mut out = Vec::new();
    for (i, inst) in instances.iter().enumerate() {
        progress(i);
        let scene = push_scene_of(base, inst)?;
        let class = inst.class.name().replace(' ', "-");
        let folder = dir.join(format!("{class}-{}", inst.index));
        std::fs::create_dir_all(&folder)?;
        let journal = journal_path(&folder, &scene, inst.index as u64);
        let mut push = Push::new(scene, inst.index as u64, Some(&journal))?;
        let n = push.start()?;
        let phi = push.scripted(&n).to_phi();
        let g = push.rollout_grad(&n, phi)?;
        let mut cosines = Vec::new();
        for h in STEPS {
            let (mut hard, mut soft) = ([0.0; 5], [0.0; 5]);
            for k in 0..5 {
                let (mut lo, mut hi) = (phi, phi);
                lo[k] = (phi[k] - h).max(-1.0);
                hi[k] = (phi[k] + h).min(1.0);
                let (l_lo, s_lo, _) = push.rollout(&n, lo)?;
                let (l_hi, s_hi, _) = push.rollout(&n, hi)?;
                let span = hi[k] - lo[k];
                hard[k] = ((1.0 - s_hi) - (1.0 - s_lo)) / span;
                soft[k] = (l_hi - l_lo) / span;
            }
            cosines.push((cosine(&g.grad, &hard), cosine(&g.grad, &soft)));
        }
        out.push(Point {
            label: format!("{} {}", inst.class.name(), inst.index),
            share: g.share,
            cosines,
        });
    }
    Ok(out)
}

/// The section of the page.
pub fn report(points: &[Point]) -> String {
    let mut md = String::new();
    if points.is_empty() {
        return md;
    }
    let _ = writeln!(
        md,
        "\n### Direction test: does the push loss's gradient point where the share outside \
         falls?\n\nAt the scripted stroke from the start of {} kept layouts, the cosine between \
         the push loss's adjoint gradient in Φ and the central secant gradient, at step h, of \
         the hard share outside the region (what success counts) and of the soft share outside \
         (what the optimisers keep the best stroke by). 1: descending the push loss descends the \
         measure; 0: unrelated; NaN: a flat secant (no grain changed sides).\n",
        points.len()
    );
    let _ = writeln!(
        md,
        "| measure | h | mean cosine | median | positive | points |\n|---|---|---|---|---|---|"
    );
    for (m, name) in [(0usize, "hard share outside"), (1, "soft share outside")] {
        for (j, h) in STEPS.iter().enumerate() {
            let c: Vec<f64> = points
                .iter()
                .map(|p| {
                    if m == 0 {
                        p.cosines[j].0
                    } else {
                        p.cosines[j].1
                    }
                })
                .filter(|c| c.is_finite())
                .collect();
            let pos = c.iter().filter(|c| **c > 0.0).count();
            let _ = writeln!(
                md,
                "| {name} | {h} | {:+.3} | {:+.3} | {pos}/{} | {} |",
                mean(&c),
                median(&c),
                c.len(),
                points.len()
            );
        }
    }
    let _ = writeln!(
        md,
        "\n| point | share in the region after the scripted stroke | hard, h = 0.1 | hard, h = \
         0.05 | soft, h = 0.1 | soft, h = 0.05 |\n|---|---|---|---|---|---|"
    );
    for p in points {
        let _ = writeln!(
            md,
            "| {} | {:.1} % | {:+.2} | {:+.2} | {:+.2} | {:+.2} |",
            p.label,
            100.0 * p.share,
            p.cosines[0].0,
            p.cosines[1].0,
            p.cosines[0].1,
            p.cosines[1].1
        );
    }
    md
}
