//! Labels in one basin: each training scene searched again from the distilled policy's own Θ.
//!
//! CMA-ES from the scene file's Θ finds good skills in different modes of a rugged landscape:
//! two similar scenes can get Θ\* far apart, and a network fitted to such labels learns little
//! more than their mean. Searching each scene again from what that network proposes, with a
//! small first step ([`AnchorConfig::sigma`]) and a few rollouts, finds the good Θ nearest to
//! the network's answer, so the new labels vary with the scene as smoothly as the landscape
//! allows. This is seed B's warm-started re-optimisation used for consistency (as DAgger
//! relabels a learner's own states). A scene whose search misses keeps its first label.
//!
//! Each scene's result is kept in `dir/scene-K.json`, so a killed run resumes.

use super::dataset::{optimise, problem_of, Sample};
use super::net::Policy;
use crate::scene::Scene;
use anyhow::Context;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The re-search's settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AnchorConfig {
    /// Forward rollouts per scene.
    pub budget: usize,
    /// CMA-ES's first step from the policy's Θ.
    pub sigma: f64,
    /// A re-searched label is used when it doses within this many grams; otherwise the
    /// scene keeps its first label.
    pub max_error_g: f64,
}

impl Default for AnchorConfig {
    fn default() -> Self {
        Self {
            budget: 6,
            sigma: 0.2,
            max_error_g: 0.5,
        }
    }
}

/// The anchored dataset: each optimised scene (copy 0) of `samples` with its label searched
/// again from `policy`'s Θ (kept when it doses within `max_error_g`, else the first label),
/// its compute added to the sample's. `progress(done)` hears of each scene.
pub fn anchor(
    base: &Scene,
    policy: &Policy,
    samples: &[Sample],
    cfg: &AnchorConfig,
    dir: &Path,
    progress: &(dyn Fn(usize) + Sync),
) -> anyhow::Result<Vec<Sample>> {
    crate::util::create_output_dir(dir, "--dir")?;
    let done = std::sync::atomic::AtomicUsize::new(0);
    samples
        .par_iter()
        .filter(|s| s.copy == 0)
        .map(|s| {
            let path = dir.join(format!("scene-{}.json", s.scene));
            let out = super::file::kept(
                &path,
                |_: &Sample| true,
                || {
                    let (problem, _) = problem_of(base, &s.draw)?;
                    let x0 = policy.act(&s.features)?;
                    let r = optimise(
                        &problem,
                        x0,
                        cfg.sigma,
                        cfg.budget,
                        3_000_000 + s.scene as u64,
                    )
                    .with_context(|| format!("anchoring scene {}", s.scene))?;
                    let mut a = s.clone();
                    a.rollouts += r.rollouts;
                    a.particle_substeps += r.particle_substeps;
                    if r.best.indicator.abs() <= cfg.max_error_g {
                        a.theta = r.theta;
                        a.loss = r.best.loss;
                        a.indicator = r.best.indicator;
                    }
                    Ok(a)
                },
            )?;
            progress(done.fetch_add(1, std::sync::atomic::Ordering::SeqCst) + 1);
            Ok(out)
        })
        .collect()
}
