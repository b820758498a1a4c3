//! What `powderlab plan` writes into its folder: `plan.json` (the result and every scoop's Θ),
//! `journal.jsonl` (every rollout, for a resumed plan) and `plan.rrd` (the scoops of the plan
//! one after another, on one timeline). The journal's name carries a fingerprint of the scene
//! and the seed, so a changed scene starts afresh instead of replaying stale rollouts. The
//! methods share it: a node's key and Θ fix its rollout whichever method asks, so greedy
//! replays the scoops it has in common with A* (its first ones) instead of simulating them
//! again, and its wall time is that of the rest.

use super::dosing::{DoseNode, Dosing, Method, PlanResult};
use super::journal::Progress;
use super::push::{Push, PushNode, PushResult};
use crate::scene::Scene;
use crate::util::write_atomic;
use std::path::{Path, PathBuf};

/// The journal of the plans of `scene` from `seed`, in `out`.
pub fn journal_path(out: &Path, scene: &Scene, seed: u64) -> PathBuf {
    let fp = crate::util::fnv1a(&format!("{}\n{seed}", scene.fingerprint()));
    out.join(format!("journal-{fp}.jsonl"))
}

/// The file of `method`'s plan in `out` with extension `ext` (`json` or `rrd`).
pub fn plan_file(out: &Path, method: Method, ext: &str) -> PathBuf {
    out.join(format!("plan-{}.{ext}", method.name()))
}

/// Plans `scene` with `method` into `out`: `plan.json`, the journal and, with `record`,
/// `plan.rrd`. `progress` hears of every rollout (rollouts so far, a message).
pub fn plan_into(
    out: &Path,
    scene: Scene,
    method: Method,
    seed: u64,
    record: bool,
    progress: Progress,
) -> anyhow::Result<PlanResult> {
    std::fs::create_dir_all(out)?;
    let journal = journal_path(out, &scene, seed);
    let mut task = Dosing::new(scene, seed, Some(&journal))?;
    task.progress = progress;
    let (result, path) = task.run(method)?;
    write_atomic(
        &plan_file(out, method, "json"),
        serde_json::to_string_pretty(&result)?.as_bytes(),
    )?;
    if record {
        record_path(&task, &path, &plan_file(out, method, "rrd"))?;
    }
    Ok(result)
}

/// [`plan_into`] for a push plan: `plan-METHOD.json` holds a [`PushResult`].
pub fn push_into(
    out: &Path,
    scene: Scene,
    method: Method,
    seed: u64,
    record: bool,
    progress: Progress,
) -> anyhow::Result<PushResult> {
    std::fs::create_dir_all(out)?;
    let journal = journal_path(out, &scene, seed);
    let mut task = Push::new(scene, seed, Some(&journal))?;
    task.progress = progress;
    let (result, path) = task.run(method)?;
    write_atomic(
        &plan_file(out, method, "json"),
        serde_json::to_string_pretty(&result)?.as_bytes(),
    )?;
    if record {
        let sims = path
            .windows(2)
            .filter_map(|pair| pair[1].stroke.as_ref().map(|d| (&pair[0], d.stroke)))
            .map(|(n, st): (&PushNode, _)| task.stroke_simulation(n, &st));
        record_sims(sims, &plan_file(out, method, "rrd"))?;
    }
    Ok(result)
}

/// Records the scoops of `path` one after another (each simulated again from its node).
fn record_path(task: &Dosing, path: &[DoseNode], file: &Path) -> anyhow::Result<()> {
    let sims = path
        .windows(2)
        .filter_map(|pair| pair[1].scoop.as_ref().map(|s| (&pair[0], s.theta)))
        .map(|(n, theta)| task.scoop_simulation(n, theta));
    record_sims(sims, file)
}

/// Records simulations one after another on one timeline, each from its first step to its
/// horizon.
#[cfg(feature = "rerun")]
fn record_sims(
    sims: impl Iterator<Item = anyhow::Result<crate::sim::Simulation>>,
    file: &Path,
) -> anyhow::Result<()> {
    let mut recorder: Option<crate::record::Recorder> = None;
    let mut offset = 0;
    for sim in sims {
        let mut sim = sim?;
        let r = match &mut recorder {
            Some(r) => r,
            None => recorder.insert(crate::record::Recorder::for_scene(
                file,
                &mut sim.world,
                &sim.scene,
            )?),
        };
        r.set_step_offset(offset);
        r.frame(&mut sim.world)?;
        let steps = sim.horizon;
        for _ in 0..steps {
            sim.step()?;
            r.frame(&mut sim.world)?;
        }
        offset += steps + 1;
    }
    if let Some(r) = recorder {
        r.finish()?;
    }
    Ok(())
}

#[cfg(not(feature = "rerun"))]
fn record_sims(
    _: impl Iterator<Item = anyhow::Result<crate::sim::Simulation>>,
    _: &Path,
) -> anyhow::Result<()> {
    anyhow::bail!("a plan's recording needs the `rerun` feature")
}
