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

/// A plan's moves as simulations, built one at a time ([`PlanTask::replay`]).
pub type Replay<'a> = Box<dyn Iterator<Item = anyhow::Result<crate::sim::Simulation>> + 'a>;

/// A plan that [`plan_into`] runs and writes: multi-scoop dosing ([`Dosing`]) or a push plan
/// ([`Push`]).
pub trait PlanTask: Sized {
    /// What `plan-METHOD.json` holds.
    type Result: serde::Serialize;
    /// A node of the plan's path.
    type Node;
    /// The task of `scene` from `seed`, replaying and appending to `journal`.
    fn open(scene: Scene, seed: u64, journal: &Path, progress: Progress) -> anyhow::Result<Self>;
    /// Plans with `method`: the result and the path from the start.
    fn run(&mut self, method: Method) -> anyhow::Result<(Self::Result, Vec<Self::Node>)>;
    /// The path's moves (scoops or strokes), each built from its node as the recording reaches
    /// it, so that one simulation is held at a time.
    fn replay<'a>(&'a self, path: &'a [Self::Node]) -> Replay<'a>;
}

impl PlanTask for Dosing {
    type Result = PlanResult;
    type Node = DoseNode;
    fn open(scene: Scene, seed: u64, journal: &Path, progress: Progress) -> anyhow::Result<Self> {
        let mut task = Dosing::new(scene, seed, Some(journal))?;
        task.progress = progress;
        Ok(task)
    }
    fn run(&mut self, method: Method) -> anyhow::Result<(PlanResult, Vec<DoseNode>)> {
        Dosing::run(self, method)
    }
    fn replay<'a>(&'a self, path: &'a [DoseNode]) -> Replay<'a> {
        Box::new(
            path.windows(2)
                .filter_map(|pair| pair[1].scoop.as_ref().map(|s| (&pair[0], s.theta)))
                .map(|(n, theta)| self.scoop_simulation(n, theta)),
        )
    }
}

impl PlanTask for Push {
    type Result = PushResult;
    type Node = PushNode;
    fn open(scene: Scene, seed: u64, journal: &Path, progress: Progress) -> anyhow::Result<Self> {
        let mut task = Push::new(scene, seed, Some(journal))?;
        task.progress = progress;
        Ok(task)
    }
    fn run(&mut self, method: Method) -> anyhow::Result<(PushResult, Vec<PushNode>)> {
        Push::run(self, method)
    }
    fn replay<'a>(&'a self, path: &'a [PushNode]) -> Replay<'a> {
        Box::new(
            path.windows(2)
                .filter_map(|pair| pair[1].stroke.as_ref().map(|d| (&pair[0], d.stroke)))
                .map(|(n, st)| self.stroke_simulation(n, &st)),
        )
    }
}

/// Plans `scene` with `method` into `out`: `plan-METHOD.json`, the journal and, with `record`,
/// `plan-METHOD.rrd` (the path's moves one after another). `progress` hears of every rollout
/// (rollouts so far, a message).
pub fn plan_into<T: PlanTask>(
    out: &Path,
    scene: Scene,
    method: Method,
    seed: u64,
    record: bool,
    progress: Progress,
) -> anyhow::Result<T::Result> {
    std::fs::create_dir_all(out)?;
    let journal = journal_path(out, &scene, seed);
    let mut task = T::open(scene, seed, &journal, progress)?;
    let (result, path) = task.run(method)?;
    write_atomic(
        &plan_file(out, method, "json"),
        serde_json::to_string_pretty(&result)?.as_bytes(),
    )?;
    if record {
        record_sims(task.replay(&path), &plan_file(out, method, "rrd"))?;
    }
    Ok(result)
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
