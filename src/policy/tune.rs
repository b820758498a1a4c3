//! The fine-tune on simulated scenes: REINFORCE ([`super::reinforce`]) whose episodes are
//! rollouts of the dataset's scenes, rewarded with −L (the scene's dosing loss).
//!
//! Each episode's reward is kept in `dir/episode-I-S.json` with its scene and Θ, so a killed
//! fine-tune replays what it ran (the draws follow the seed) and continues.

use super::dataset::{problem_of, Sample};
use super::net::Policy;
use super::reinforce::{finetune, Iteration, ReinforceConfig};
use crate::scene::Scene;
use serde::{Deserialize, Serialize};
use std::path::Path;

#[derive(Serialize, Deserialize, PartialEq)]
struct Episode {
    context: usize,
    theta: [f64; 5],
    reward: f64,
    particle_substeps: f64,
}

/// Fine-tunes `policy` in place on the scenes of `samples`; returns each iteration's batch and
/// the particle-substeps the episodes simulated.
pub fn finetune_scenes(
    base: &Scene,
    policy: &Policy,
    samples: &[Sample],
    cfg: &ReinforceConfig,
    dir: &Path,
    on_iteration: &mut dyn FnMut(&Iteration),
) -> anyhow::Result<(Vec<Iteration>, f64)> {
    crate::util::create_output_dir(dir, "--dir")?;
    let contexts: Vec<Vec<f64>> = samples.iter().map(|s| s.features.clone()).collect();
    let spent = std::sync::Mutex::new(0.0);
    let reward = |it: usize, slot: usize, ctx: usize, theta: [f64; 5]| -> anyhow::Result<f64> {
        let path = dir.join(format!("episode-{it}-{slot}.json"));
        let e = super::file::kept(
            &path,
            |e: &Episode| e.context == ctx && e.theta == theta,
            || {
                let (problem, _) = problem_of(base, &samples[ctx].draw)?;
                let o = problem.evaluate(theta, false, true)?;
                let e = Episode {
                    context: ctx,
                    theta,
                    reward: -o.loss,
                    particle_substeps: super::dataset::cost(&o),
                };
                Ok(e)
            },
        )?;
        *spent.lock().expect("lock") += e.particle_substeps;
        Ok(e.reward)
    };
    let its = finetune(policy, &contexts, cfg, &reward, on_iteration)?;
    let total = *spent.lock().expect("lock");
    Ok((its, total))
}
