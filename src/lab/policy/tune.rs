//! The fine-tune on simulated scenes: REINFORCE ([`super::reinforce`]) whose episodes are
//! rollouts of freshly drawn scenes ([`fresh_contexts`]), rewarded with −L (the scene's dosing
//! loss). The Gaussian lives on the policy's knob; an episode runs the family's Θ at the drawn
//! knob ([`super::knob::family`]). Not the dataset's scenes: the distilled network already fits
//! their labels, so there the rewards could only teach it what it knows; new scenes are where it
//! makes its errors.
//!
//! Each episode's reward is kept in `dir/episode-I-S.json` with its scene and Θ, so a killed
//! fine-tune replays what it ran (the draws follow the seed) and continues.

use super::dataset::{draw_scene, problem_of, spec_of};
use super::knob::KNOB;
use super::net::Policy;
use super::reinforce::{finetune, Iteration, ReinforceConfig};
use crate::scene::randomize::Draw;
use crate::scene::Scene;
use crate::skills::Theta;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Added to the dataset's seed to draw the fine-tune's scenes: a stream that neither the dataset
/// nor the held-out scenes ([`super::eval::HELD_OUT_STREAM`]) use.
pub const FINETUNE_STREAM: u64 = 0xF1AE_7E57;

/// `n` scenes of the fine-tune's stream for the dataset seed `seed`, each with its features.
pub fn fresh_contexts(base: &Scene, seed: u64, n: usize) -> anyhow::Result<Vec<(Draw, Vec<f64>)>> {
    let spec = spec_of(base)?;
    (0..n)
        .into_par_iter()
        .map(|k| {
            let d = draw_scene(spec, base, seed.wrapping_add(FINETUNE_STREAM), k);
            let (_, f) = problem_of(base, &d)?;
            Ok((d, f))
        })
        .collect()
}

#[derive(Serialize, Deserialize, PartialEq)]
struct Episode {
    draw: Draw,
    context: usize,
    theta: Theta,
    reward: f64,
    particle_substeps: f64,
}

/// Fine-tunes `policy` in place on the scenes of `contexts` (a draw and its features); returns
/// each iteration's batch and the particle-substeps the episodes simulated.
pub fn finetune_scenes(
    base: &Scene,
    policy: &Policy,
    contexts: &[(Draw, Vec<f64>)],
    cfg: &ReinforceConfig,
    dir: &Path,
    on_iteration: &mut dyn FnMut(&Iteration),
) -> anyhow::Result<(Vec<Iteration>, f64)> {
    crate::util::create_output_dir(dir, "--dir")?;
    let rows: Vec<Vec<f64>> = contexts.iter().map(|(_, f)| f.clone()).collect();
    let spent = std::sync::Mutex::new(0.0);
    let reward = |it: usize, slot: usize, ctx: usize, a: &[f64]| -> anyhow::Result<f64> {
        let path = dir.join(format!("episode-{it}-{slot}.json"));
        let draw = &contexts[ctx].0;
        // The draw and the knob fix Θ, so a kept episode is checked without building its scene.
        let e = super::file::kept(
            &path,
            |e: &Episode| e.context == ctx && e.theta[KNOB] == a[0] && e.draw == *draw,
            || {
                let (problem, _) = problem_of(base, draw)?;
                let theta = super::knob::family(&problem, draw, a[0]);
                let o = problem.evaluate(theta, false, true)?;
                let e = Episode {
                    draw: contexts[ctx].0.clone(),
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
    let its = finetune(policy, &rows, cfg, &reward, on_iteration)?;
    let total = *spent.lock().expect("lock");
    Ok((its, total))
}
