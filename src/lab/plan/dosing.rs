//! Task 1 of seed B's planner for powder: dosing a mass larger than one spoonful, scoop by scoop
//! (docs/design.md §12).
//!
//! - **A node** is the powder's state after the scoops so far (a snapshot), the mass in the
//!   target cup, and the spoon's entry point into the source cup with the surface height there.
//! - **`OptWrench`** optimises the next scoop's Θ from that state by CMA-ES on the dosing loss
//!   toward `delivered + min(remaining, capacity)`: the rest of the dose when one spoonful can
//!   carry it (a partial pour), as much as possible otherwise. It spends the plan's
//!   `scoop_budget` forward rollouts, the first at the last scoop's Θ (the scene's for the
//!   first), and keeps the rollout of lowest loss.
//! - **Between scoops** the powder outside both cups (still in the spoon after a partial pour,
//!   or spilt) is discarded: a robot empties its spoon into the waste and the bench is wiped.
//!   The next scoop starts from the rest, at rest where it settled.
//! - **`OptIsSuccess`**: the scoop did not pass the target by more than the tolerance, and it
//!   either ended within the tolerance or delivered at least `min_progress_g`.
//! - **`ContactLoc`** proposes the highest admissible points of the source's surface, averaged
//!   over the spoon's bowl (a crater lowers them), clear of the wall.
//! - **Cost**: one per scoop and `move_cost` per relocation; the heuristic is the remaining
//!   mass (less the tolerance) over `spoon_capacity_g`, rounded up: admissible when no scoop
//!   carries more.
//!
//! Every rollout goes through a [`Journal`], so a plan killed and run again replays what it
//! had: the search is deterministic, a recorded rollout is not simulated again, and only each
//! scoop's chosen rollout is re-run for its final state.

use super::contact::{cup_surface, entry_points};
use super::journal::{key, node_seed, Entry, Journal, Progress};
use super::search::{search, SearchOptions, Task};
pub use super::Method;
use crate::components::BodyState;
use crate::lab::optim::cma::{reflect, run_sequential, CmaConfig};
use crate::lab::optim::problem::Problem;
use crate::math::geometry::CupRegion;
use crate::math::heightfield::HeightGrid;
use crate::scene::plan::{DosingPlan, PlanSpec};
use crate::scene::{ControlSpec, LossSpec, Scene, TargetValue};
use crate::sim::Simulation;
use crate::skills::Theta;
use anyhow::Context;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

/// One scoop of a plan.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Scoop {
    /// The spoon's start (x, z) (m).
    pub entry: [f64; 2],
    /// The surface height the skill's descent was measured from (m).
    pub surface: f64,
    pub theta: Theta,
    /// Powder in the target cup after the scoop (g).
    pub delivered_g: f64,
    /// What this scoop added (g).
    pub added_g: f64,
    /// Powder discarded after it (left in the spoon or spilt) (g).
    pub discarded_g: f64,
    /// Rollouts its optimiser spent (1 for a scripted scoop).
    pub rollouts: usize,
}

/// A node of the search.
#[derive(Clone, Debug)]
pub struct DoseNode {
    pub state: Arc<Vec<BodyState>>,
    pub delivered_g: f64,
    pub entry: [f64; 2],
    pub surface: f64,
    /// The scoop that made it (`None` at the start and after a relocation).
    pub scoop: Option<Scoop>,
    /// Scoops so far.
    pub scoops: usize,
    /// The Θ the next scoop's optimiser starts from.
    pub theta_hint: Theta,
    /// The node's path from the start (`s` a scoop, `m<k>` a move to entry `k`): the journal's
    /// key.
    pub key: String,
}

/// What a plan gives.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PlanResult {
    pub method: Method,
    pub target_g: f64,
    pub tolerance_g: f64,
    pub delivered_g: f64,
    /// `|target − delivered|` (g).
    pub dose_error_g: f64,
    pub success: bool,
    pub scoops: Vec<Scoop>,
    /// Forward rollouts spent, including the ones the search threw away.
    pub rollouts: usize,
    /// Simulated particle-substeps of those rollouts.
    pub particle_substeps: f64,
    /// Nodes the search expanded (A*), or scoops tried (greedy, scripted).
    pub expansions: usize,
    /// Rollouts replayed from the journal rather than simulated.
    pub replayed: usize,
    pub wall_s: f64,
}

/// The dosing task, what A* and the baselines drive.
pub struct Dosing {
    scene: Scene,
    pub plan: DosingPlan,
    pub target_g: f64,
    tool: usize,
    source: CupRegion,
    target: CupRegion,
    bowl_radius: f64,
    /// Each body's particle mass (kg).
    masses: Vec<f64>,
    /// The scene's surface height less the measured one at the start: the measured surface is
    /// the highest grain centre, half a spacing below the powder's top.
    surface_offset: f64,
    seed: u64,
    journal: Journal,
    pub rollouts: usize,
    pub particle_substeps: f64,
    pub replayed: usize,
    /// Called after every rollout with the rollouts so far and a message.
    pub progress: Progress,
}

/// The dosing plan of a scene, or why it has none.
pub fn dosing_plan(scene: &Scene) -> anyhow::Result<DosingPlan> {
    match &scene.plan {
        Some(PlanSpec::Dosing(d)) => Ok(d.clone()),
        Some(PlanSpec::Push(_)) => anyhow::bail!(
            "{}: its plan pushes powder, not doses it",
            scene.path.display()
        ),
        None => anyhow::bail!(
            "{}: no `plan` section; add `plan: Some(Dosing((source: \"source_cup\", \
             spoon_capacity_g: 6.0)))` (scenes/multi_scoop_dosing.ron)",
            scene.path.display()
        ),
    }
}

impl Dosing {
    /// The task of `scene`'s plan; `journal` (a file, created or replayed) keeps the rollouts.
    pub fn new(scene: Scene, seed: u64, journal_path: Option<&Path>) -> anyhow::Result<Dosing> {
        let plan = dosing_plan(&scene)?;
        let Some(TargetValue::Grams(target_g)) = scene.task.as_ref().map(|t| t.target_value) else {
            unreachable!("the scene's check asks a dosing plan for a target in grams")
        };
        let tool = crate::rollout::skill_tool(&scene)?;
        let mut sim = Simulation::new(&scene, &Default::default())?;
        let mut cup = |name: &str| {
            sim.collider_poses()
                .into_iter()
                .find(|c| c.0 == name)
                .and_then(|(_, _, shape, pose)| CupRegion::of(&shape, pose))
                .expect("the scene's check makes both cups")
        };
        let source = cup(&plan.source);
        let target = cup(&scene.task.as_ref().expect("checked").target);
        let bowl_radius = match scene.colliders[tool].shape {
            crate::math::sdf::Shape::Spoon { bowl_radius, .. } => bowl_radius,
            _ => 0.5 * scene.simulation.dx,
        };
        let journal = match journal_path {
            Some(p) => Journal::open(p)?,
            None => Journal::default(),
        };
        let state = sim.body_states();
        let masses = scene
            .prepare()?
            .bodies
            .iter()
            .map(|b| b.particle_mass)
            .collect();
        let mut task = Dosing {
            masses,
            plan,
            target_g,
            tool,
            source,
            target,
            bowl_radius,
            surface_offset: 0.0,
            seed,
            journal,
            rollouts: 0,
            particle_substeps: 0.0,
            replayed: 0,
            progress: Box::new(|_, _| {}),
            scene,
        };
        let start = task.start_entry();
        let (sk_surface, _) = task.skill_settings();
        task.surface_offset = sk_surface - task.surface_at(&state, start);
        Ok(task)
    }

    /// The skill's surface height and Θ in the scene.
    fn skill_settings(&self) -> (f64, Theta) {
        match &self.scene.colliders[self.tool].control {
            Some(ControlSpec::Skill(sk)) => (sk.surface_height, sk.theta),
            _ => unreachable!("skill_tool found it"),
        }
    }

    /// The spoon's start (x, z) in the scene: the first entry.
    fn start_entry(&self) -> [f64; 2] {
        let p = self.scene.colliders[self.tool].position;
        [p.0, p.2]
    }

    /// The start node: the scene's fill at rest, the spoon where the scene puts it.
    pub fn start(&mut self) -> anyhow::Result<DoseNode> {
        let mut sim = Simulation::new(&self.scene, &Default::default())?;
        let state = Arc::new(sim.body_states());
        let delivered_g = self.mass_in(&state, &self.target);
        let entry = self.start_entry();
        Ok(DoseNode {
            surface: self.surface_at(&state, entry) + self.surface_offset,
            state,
            delivered_g,
            entry,
            scoop: None,
            scoops: 0,
            theta_hint: self.skill_settings().1,
            key: String::from("0"),
        })
    }

    /// Grams of the particles inside `cup`.
    fn mass_in(&self, state: &[BodyState], cup: &CupRegion) -> f64 {
        state
            .iter()
            .zip(&self.masses)
            .map(|(b, m)| b.x.iter().filter(|x| cup.inside(**x)).count() as f64 * m * 1e3)
            .sum()
    }

    /// The source's surface ([`cup_surface`]) on a pixel grid of one cell, averaged over the
    /// spoon's bowl.
    fn surface_map(&self, state: &[BodyState]) -> (HeightGrid, Vec<f64>) {
        let xs = state.iter().flat_map(|b| b.x.iter()).copied();
        cup_surface(&self.source, xs, self.scene.simulation.dx, self.bowl_radius)
    }

    /// The averaged surface at the pixel nearest `entry`.
    fn surface_at(&self, state: &[BodyState], entry: [f64; 2]) -> f64 {
        let (grid, h) = self.surface_map(state);
        let i = ((entry[0] - grid.origin[0]) / grid.pixel).round() as usize;
        let j = ((entry[1] - grid.origin[1]) / grid.pixel).round() as usize;
        h[j.min(grid.nz - 1) * grid.nx + i.min(grid.nx - 1)]
    }

    /// `ContactLoc`'s entries for `state`, best first, as (x, z, surface).
    fn entries(&self, state: &[BodyState], k: usize) -> Vec<[f64; 3]> {
        let (grid, h) = self.surface_map(state);
        let c = self.source.pose.translation;
        entry_points(
            &grid,
            &h,
            [c.x, c.z],
            self.source.inner_radius,
            self.plan.clearance,
            k,
            self.plan.spacing,
        )
        .into_iter()
        .map(|p| [p[0], p[1], p[2] + self.surface_offset])
        .collect()
    }

    /// The grams the next scoop from `n` aims to have in the target cup after it.
    pub fn aim(&self, n: &DoseNode) -> f64 {
        let remaining = self.target_g - n.delivered_g;
        n.delivered_g + remaining.min(self.plan.spoon_capacity_g)
    }

    /// The problem of the next scoop from `n`: the spoon at its entry, the skill's descent from
    /// its surface, the dosing loss toward the aim, the powder from its state.
    fn problem(&self, n: &DoseNode) -> anyhow::Result<Problem> {
        let mut scene = self.scene.clone();
        let aim = self.aim(n);
        let spoon = &mut scene.colliders[self.tool];
        spoon.position.0 = n.entry[0];
        spoon.position.2 = n.entry[1];
        if let Some(ControlSpec::Skill(sk)) = &mut spoon.control {
            sk.surface_height = n.surface;
        }
        if let Some(t) = &mut scene.task {
            t.target_value = TargetValue::Grams(aim);
        }
        let width = match scene.loss {
            Some(LossSpec::Dosing { width, .. }) => width,
            _ => None,
        };
        scene.loss = Some(LossSpec::Dosing { grams: aim, width });
        scene.validate()?;
        Problem::new(scene, crate::rollout::DEFAULT_TAPE_BUDGET)?.with_start(&n.state)
    }

    /// One rollout of `p` at Θ from node `key`: (loss, grams in the target cup, the final
    /// state when it was simulated rather than replayed).
    fn rollout(
        &mut self,
        p: &Problem,
        node: &str,
        theta: Theta,
    ) -> anyhow::Result<(f64, f64, Option<Vec<BodyState>>)> {
        let full = key(node, &theta[..]);
        self.rollouts += 1;
        if let Some(e) = self.journal.get(&full) {
            self.particle_substeps += e.particle_substeps;
            self.replayed += 1;
            let (l, d) = (e.loss, e.value);
            (self.progress)(self.rollouts, &format!("replayed: {d:.2} g"));
            return Ok((l, d, None));
        }
        let mut sim = p.simulation(theta, false)?;
        let steps = sim.horizon;
        sim.run(steps, |_| {})
            .with_context(|| format!("scoop from node {node} at Θ = {theta:?}"))?;
        let states = sim.body_states();
        let xs: Vec<_> = states.iter().map(|b| b.x.clone()).collect();
        let loss = p.loss().eval(&xs).0;
        let delivered_g = self.mass_in(&states, &self.target);
        let work = (sim.particle_count() * steps * sim.params().substeps) as f64;
        self.particle_substeps += work;
        self.journal.put(Entry {
            key: full,
            loss,
            value: delivered_g,
            particle_substeps: work,
            push_loss: None,
            grad: None,
        })?;
        (self.progress)(self.rollouts, &format!("{delivered_g:.2} g"));
        Ok((loss, delivered_g, Some(states)))
    }

    /// The node a scoop at Θ from `n` leads to, from the scoop's final state (simulated again
    /// when the journal had it), with the powder outside both cups discarded.
    fn after(
        &mut self,
        p: &Problem,
        n: &DoseNode,
        theta: Theta,
        states: Option<Vec<BodyState>>,
        rollouts: usize,
    ) -> anyhow::Result<DoseNode> {
        let states = match states {
            Some(s) => s,
            None => {
                let mut sim = p.simulation(theta, false)?;
                let steps = sim.horizon;
                sim.run(steps, |_| {})?;
                sim.body_states()
            }
        };
        let before = self.mass_in(&states, &self.target) + self.mass_in(&states, &self.source);
        let total: f64 = {
            states
                .iter()
                .zip(&self.masses)
                .map(|(b, m)| b.x.len() as f64 * m * 1e3)
                .sum()
        };
        let kept: Vec<BodyState> = states
            .into_iter()
            .map(|b| {
                let keep: Vec<usize> = (0..b.x.len())
                    .filter(|&i| self.source.inside(b.x[i]) || self.target.inside(b.x[i]))
                    .collect();
                BodyState {
                    name: b.name,
                    x: keep.iter().map(|&i| b.x[i]).collect(),
                    v: keep.iter().map(|&i| b.v[i]).collect(),
                    c: keep.iter().map(|&i| b.c[i]).collect(),
                    f: keep.iter().map(|&i| b.f[i]).collect(),
                }
            })
            .collect();
        anyhow::ensure!(
            kept.iter().all(|b| !b.x.is_empty()),
            "node {}: the scoop left no powder in either cup",
            n.key
        );
        let delivered_g = self.mass_in(&kept, &self.target);
        let best = self.entries(&kept, 1);
        let [x, z, surface] = best.first().copied().context("no admissible entry point")?;
        let scoop = Scoop {
            entry: n.entry,
            surface: n.surface,
            theta,
            delivered_g,
            added_g: delivered_g - n.delivered_g,
            discarded_g: total - before,
            rollouts,
        };
        Ok(DoseNode {
            state: Arc::new(kept),
            delivered_g,
            entry: [x, z],
            surface,
            scoop: Some(scoop),
            scoops: n.scoops + 1,
            theta_hint: theta,
            key: format!("{}/s", n.key),
        })
    }

    /// The simulation of the scoop at Θ from `n`, at its first step (for a recording).
    pub fn scoop_simulation(&self, n: &DoseNode, theta: Theta) -> anyhow::Result<Simulation> {
        self.problem(n)?.simulation(theta, false)
    }

    /// One scoop at a given Θ from `n` (the scripted policy).
    pub fn scoop_at(&mut self, n: &DoseNode, theta: Theta) -> anyhow::Result<DoseNode> {
        let p = self.problem(n)?;
        let (_, _, states) = self.rollout(&p, &n.key, theta)?;
        self.after(&p, n, theta, states, 1)
    }

    /// `OptWrench` from `n`: `None` when the plan allows no more scoops or the dose is passed.
    pub fn optimise(&mut self, n: &DoseNode) -> anyhow::Result<Option<DoseNode>> {
        if n.scoops >= self.plan.max_scoops || n.delivered_g > self.target_g + self.plan.tolerance_g
        {
            return Ok(None);
        }
        let p = self.problem(n)?;
        let budget = self.plan.scoop_budget;
        let mut best: Option<(f64, Theta, Option<Vec<BodyState>>)> = None;
        let mut consider = |l: f64, th: Theta, st: Option<Vec<BodyState>>| {
            if best.as_ref().is_none_or(|b| l < b.0) {
                best = Some((l, th, st));
            }
        };
        let (l, _, st) = self.rollout(&p, &n.key, n.theta_hint)?;
        consider(l, n.theta_hint, st);
        if budget > 1 {
            // The node's key seeds its optimiser, so a resumed plan draws the same samples.
            let seed = node_seed(self.seed, &n.key);
            let x0 = n.theta_hint.to_vec();
            let sigma = CmaConfig::default().sigma0;
            let mut evals = Vec::new();
            run_sequential(x0, sigma, seed, budget - 1, |x| {
                let th = Theta(std::array::from_fn(|k| reflect(x[k])));
                let (l, _, st) = self.rollout(&p, &n.key, th)?;
                evals.push((l, th, st));
                Ok(l)
            })?;
            for (l, th, st) in evals {
                consider(l, th, st);
            }
        }
        let (_, theta, states) = best.expect("one rollout at least");
        Ok(Some(self.after(&p, n, theta, states, budget)?))
    }

    /// Whether a scoop from `from` to `to` did what it aimed for.
    pub fn scoop_succeeded(&self, from: &DoseNode, to: &DoseNode) -> bool {
        let tol = self.plan.tolerance_g;
        to.delivered_g <= self.target_g + tol
            && ((self.target_g - to.delivered_g).abs() <= tol
                || to.delivered_g - from.delivered_g >= self.plan.min_progress_g)
    }

    pub fn done(&self, n: &DoseNode) -> bool {
        (self.target_g - n.delivered_g).abs() <= self.plan.tolerance_g
    }

    /// The result of a path of nodes.
    fn result(
        &self,
        method: Method,
        path: &[DoseNode],
        expansions: usize,
        t0: Instant,
    ) -> PlanResult {
        let last = path.last().expect("a path holds the start");
        PlanResult {
            method,
            target_g: self.target_g,
            tolerance_g: self.plan.tolerance_g,
            delivered_g: last.delivered_g,
            dose_error_g: (self.target_g - last.delivered_g).abs(),
            success: self.done(last),
            scoops: path.iter().filter_map(|n| n.scoop.clone()).collect(),
            rollouts: self.rollouts,
            particle_substeps: self.particle_substeps,
            expansions,
            replayed: self.replayed,
            wall_s: t0.elapsed().as_secs_f64(),
        }
    }

    /// Plans with `method`: the result, and the path of nodes from the start.
    pub fn run(&mut self, method: Method) -> anyhow::Result<(PlanResult, Vec<DoseNode>)> {
        let t0 = Instant::now();
        let start = self.start()?;
        match method {
            Method::Astar => {
                let opts = SearchOptions {
                    explore: self.plan.explore,
                    seed: self.seed,
                    max_expansions: self.plan.max_expansions,
                };
                let r = search(self, start, &opts)?;
                Ok((self.result(method, &r.path, r.expansions, t0), r.path))
            }
            Method::Greedy | Method::Scripted => {
                let mut path = vec![start];
                let theta = self.skill_settings().1;
                while path.len() <= self.plan.max_scoops {
                    let n = path.last().expect("the start");
                    let stop = match method {
                        Method::Greedy => self.done(n),
                        _ => n.delivered_g >= self.target_g - self.plan.tolerance_g,
                    };
                    if stop || n.delivered_g > self.target_g + self.plan.tolerance_g {
                        break;
                    }
                    let next = match method {
                        Method::Greedy => match self.optimise(n)? {
                            Some(m) => m,
                            None => break,
                        },
                        _ => {
                            let n = n.clone();
                            self.scoop_at(&n, theta)?
                        }
                    };
                    path.push(next);
                }
                let tried = path.len() - 1;
                Ok((self.result(method, &path, tried, t0), path))
            }
        }
    }
}

impl Task for Dosing {
    type Node = DoseNode;
    fn is_success(&self, n: &DoseNode) -> bool {
        self.done(n)
    }
    fn opt_wrench(&mut self, n: &DoseNode) -> anyhow::Result<Option<(DoseNode, f64)>> {
        Ok(self.optimise(n)?.map(|m| (m, 1.0)))
    }
    fn opt_is_success(&self, from: &DoseNode, to: &DoseNode) -> bool {
        self.scoop_succeeded(from, to)
    }
    fn contact_loc(&mut self, n: &DoseNode) -> Vec<(DoseNode, f64)> {
        let k = self.plan.entries;
        self.entries(&n.state, k + 1)
            .into_iter()
            .filter(|e| (e[0] - n.entry[0]).hypot(e[1] - n.entry[1]) > 1e-9)
            .take(k)
            .enumerate()
            .map(|(i, [x, z, surface])| {
                let mut m = n.clone();
                m.entry = [x, z];
                m.surface = surface;
                m.scoop = None;
                m.key = format!("{}/m{i}", n.key);
                (m, self.plan.move_cost)
            })
            .collect()
    }
    fn heuristic(&self, n: &DoseNode) -> f64 {
        let tol = self.plan.tolerance_g;
        let remaining = self.target_g - n.delivered_g;
        if remaining < -tol {
            f64::INFINITY
        } else {
            ((remaining - tol).max(0.0) / self.plan.spoon_capacity_g).ceil()
        }
    }
    fn distance(&self, n: &DoseNode) -> f64 {
        (self.target_g - n.delivered_g).abs()
    }
}
