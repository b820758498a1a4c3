//! Task 2 of seed B's planner for powder: pushing or pulling powder on a plate into a region
//! with a spatula, in seed B's four classes (docs/design.md §12).
//!
//! - **A node** is the powder's state, the share of its mass in the region, and the contact:
//!   the z across the stroke of the powder it aims at.
//! - **A stroke** has five parameters Φ ∈ [−1, 1]⁵, mapped linearly into [`RANGES`]: how far
//!   behind the powder still outside the region the blade lands, its lateral offset from the
//!   contact, its yaw from the class's direction, the height of the blade's edge above the
//!   plate, and the stroke's length. The spatula descends onto the landing point, strokes,
//!   lifts and holds still; the class leans the handle against the stroke (push) or along it
//!   (pull).
//! - **`OptWrench`** ([`wrench`]): CMA-ES on the soft share of mass outside the region, or line
//!   searches along the push loss's gradient, from the scripted stroke, for the plan's
//!   `stroke_budget` rollouts; either keeps the stroke of lowest soft share outside.
//! - **`OptIsSuccess`**: the stroke reached success or moved `min_gain` of the mass in.
//! - **`ContactLoc`** ([`aim`]): the medians of `contacts` bands of the powder still outside, or
//!   bands no wider than the blade weighted by the grains' distance, as the plan's `aim` says.
//! - **Cost**: one per stroke, `move_cost` per relocation; the heuristic is 1 until success, or
//!   a bound on the strokes still needed, as the plan's `heuristic` says.
//! - **Scripted**: a straight stroke through the middle of the powder still outside, the blade
//!   landing 1 cm behind it at 1 mm above the plate and stopping 1 cm inside the region,
//!   repeated until success or `max_strokes`.
//!
//! The rollouts go through a [`Journal`] as the dosing plan's do.

mod aim;
mod wrench;

use super::journal::{key, Entry, Journal, Progress};
use super::search::{search, SearchOptions, Task};
use super::stroke::{motion, Frame};
use crate::components::BodyState;
use crate::math::region::PlateRegion;
use crate::scene::plan::{Aim, Heuristic, PlanSpec, PushClass, PushPlan, StrokeOptimiser};
use crate::scene::{ControlSpec, Scene};
use crate::sim::{Build, SimOptions, Simulation};
use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;
pub use wrench::LINE_RADIUS;

pub use super::stroke::{Stroke, LIFT, RANGES, SETTLE_STEPS};

/// CMA-ES's initial step (Φ units) around the scripted stroke: a quarter of the box's half
/// width. The scripted stroke is a good start (it reaches success alone on a compact patch), and
/// at the default step of 0.5 eight samples around it were all worse on a wide patch.
pub const STROKE_SIGMA: f64 = 0.25;

/// The push loss's ramps, in cells: half a cell, as the soft share's.
pub const PUSH_WIDTH_CELLS: f64 = 0.5;

/// A stroke's backward pass as a multiple of its forward, what a gradient rollout is charged
/// beyond its forward in the plan's budget and compute: what the planning study measured over
/// its own rollouts, 2.93 (504 gradient rollouts, the EPYC) and 3.04 (163, the Intel VM), one
/// thread each. It was 1.7 before, from one printout of `tests/push_gradient.rs` (a single
/// rollout on a noisy VM, whose later runs printed 3.8 and 4.3). At 2.9 a stroke budget of 6
/// buys one gradient rollout and two forward trials, not three.
pub const STROKE_BACKWARD_COST: f64 = 2.9;

/// What [`Push::rollout_grad`] gives.
#[derive(Clone, Debug)]
pub struct GradRollout {
    /// The soft share outside, the optimisers' objective.
    pub loss: f64,
    /// The share in the region.
    pub share: f64,
    /// The push loss (m).
    pub push_loss: f64,
    /// `∂(push loss)/∂Φ`.
    pub grad: [f64; 5],
    pub states: Option<Vec<BodyState>>,
}

/// One stroke of a plan.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Done {
    /// The contact's z (m).
    pub contact: f64,
    pub phi: [f64; 5],
    pub stroke: Stroke,
    /// Where the blade's edge landed (m).
    pub landing: [f64; 3],
    /// The share of the mass in the region after it.
    pub in_region: f64,
    pub rollouts: usize,
}

/// A node of the search.
#[derive(Clone, Debug)]
pub struct PushNode {
    pub state: Arc<Vec<BodyState>>,
    pub in_region: f64,
    pub contact: f64,
    pub stroke: Option<Done>,
    pub strokes: usize,
    pub key: String,
}

/// What a plan gives.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PushResult {
    pub class: PushClass,
    pub method: super::dosing::Method,
    /// The strokes' optimiser (scripted plans optimise nothing).
    #[serde(default)]
    pub optimiser: StrokeOptimiser,
    pub success_fraction: f64,
    /// The share of the mass in the region at the end.
    pub in_region: f64,
    pub success: bool,
    pub strokes: Vec<Done>,
    pub rollouts: usize,
    pub particle_substeps: f64,
    pub expansions: usize,
    pub replayed: usize,
    pub wall_s: f64,
    /// Rollouts with a backward pass, among `rollouts`.
    #[serde(default)]
    pub backward: usize,
    /// Wall seconds and count of the forward-only rollouts simulated (not replayed), and of
    /// those with a backward pass: the backward pass's measured multiple.
    #[serde(default)]
    pub forward_timing: (f64, usize),
    #[serde(default)]
    pub gradient_timing: (f64, usize),
}

/// The push task.
pub struct Push {
    scene: Scene,
    pub plan: PushPlan,
    tool: usize,
    /// The plate's centre and half extents.
    plate: (DVec3, DVec3),
    seed: u64,
    journal: Journal,
    pub rollouts: usize,
    /// Rollouts with a backward pass, among `rollouts`.
    pub backward: usize,
    /// Wall seconds and count of the simulated forward-only and gradient rollouts.
    pub forward_timing: (f64, usize),
    pub gradient_timing: (f64, usize),
    pub particle_substeps: f64,
    pub replayed: usize,
    pub progress: Progress,
}

/// The push plan of a scene, or why it has none.
pub fn push_plan(scene: &Scene) -> anyhow::Result<PushPlan> {
    match &scene.plan {
        Some(PlanSpec::Push(p)) => Ok(p.clone()),
        _ => anyhow::bail!(
            "{}: no push plan; add `plan: Some(Push((plate: \"plate\", class: PushLeft, \
             boundary: 0.06)))` (scenes/plate_push.ron)",
            scene.path.display()
        ),
    }
}

impl Push {
    pub fn new(scene: Scene, seed: u64, journal: Option<&Path>) -> anyhow::Result<Push> {
        let plan = push_plan(&scene)?;
        let plate = plan
            .plate_box(&scene)
            .expect("the scene's check finds the plate");
        let tool = scene
            .colliders
            .iter()
            .position(|c| matches!(c.shape, crate::math::sdf::Shape::Spatula { .. }))
            .expect("the scene's check finds the spatula");
        Ok(Push {
            plan,
            plate,
            tool,
            seed,
            journal: match journal {
                Some(p) => Journal::open(p)?,
                None => Journal::default(),
            },
            rollouts: 0,
            backward: 0,
            forward_timing: (0.0, 0),
            gradient_timing: (0.0, 0),
            particle_substeps: 0.0,
            replayed: 0,
            progress: Box::new(|_, _| {}),
            scene,
        })
    }

    fn plate_top(&self) -> f64 {
        self.plate.0.y + self.plate.1.y
    }

    /// The region the powder goes to.
    pub fn region(&self) -> PlateRegion {
        PlateRegion {
            centre: self.plate.0,
            half: self.plate.1,
            boundary: self.plan.boundary,
            side: self.plan.class.side(),
        }
    }

    /// The hard share of particles in the region (the bodies share one material here, so
    /// particles stand for mass).
    fn share(&self, state: &[BodyState]) -> f64 {
        self.region().share(state.iter().flat_map(|b| b.x.iter()))
    }

    /// The soft share outside the region, with logistic edges half a cell wide.
    fn loss(&self, state: &[BodyState]) -> f64 {
        let w = 0.5 * self.scene.simulation.dx;
        self.region()
            .soft_outside(state.iter().flat_map(|b| b.x.iter()), w)
    }

    /// The particles still outside the region.
    fn outside<'a>(&self, state: &'a [BodyState]) -> impl Iterator<Item = DVec3> + 'a {
        let region = self.region();
        state
            .iter()
            .flat_map(|b| b.x.iter())
            .filter(move |x| !region.inside(**x))
            .copied()
    }

    /// The contacts from a state, the node's own first: the plan's [`Aim`].
    fn contacts(&self, state: &[BodyState], k: usize) -> Vec<f64> {
        if self.plan.aim == Aim::Bands {
            let w = PUSH_WIDTH_CELLS * self.scene.simulation.dx;
            let region = self.region();
            let grains: Vec<(f64, f64)> = self
                .outside(state)
                .map(|x| (x.z, region.distance(x, w).0))
                .collect();
            let b = aim::bands(&grains, self.blade_width(), k);
            return if b.is_empty() {
                vec![self.plate.0.z]
            } else {
                b
            };
        }
        let mut z: Vec<f64> = self.outside(state).map(|x| x.z).collect();
        if z.is_empty() {
            return vec![self.plate.0.z];
        }
        z.sort_by(f64::total_cmp);
        (0..k)
            .map(|i| z[((2 * i + 1) * z.len() / (2 * k)).min(z.len() - 1)])
            .collect()
    }

    /// The spatula's blade width (m).
    fn blade_width(&self) -> f64 {
        match self.scene.colliders[self.tool].shape {
            crate::math::sdf::Shape::Spatula { blade_width, .. } => blade_width,
            _ => unreachable!("Push::new finds the spatula"),
        }
    }

    /// The plan's heuristic at `n` (see [`Heuristic`]).
    fn estimate(&self, n: &PushNode) -> f64 {
        if self.done(n) {
            return 0.0;
        }
        match self.plan.heuristic {
            Heuristic::Unit => 1.0,
            Heuristic::Strokes => {
                let total: usize = n.state.iter().map(|b| b.x.len()).sum();
                let zs: Vec<f64> = self.outside(&n.state).map(|x| x.z).collect();
                let sweep = self.blade_width() + RANGES[4].1 * RANGES[2].1.to_radians().sin();
                aim::strokes_bound(&zs, total, sweep, self.plan.success_fraction - n.in_region)
            }
        }
    }

    pub fn start(&mut self) -> anyhow::Result<PushNode> {
        let mut sim = Simulation::new(&self.scene, &SimOptions::default())?;
        let state = Arc::new(sim.body_states());
        let contact = self.contacts(&state, 1)[0];
        Ok(PushNode {
            in_region: self.share(&state),
            state,
            contact,
            stroke: None,
            strokes: 0,
            key: String::from("0"),
        })
    }

    /// The x of the far side, from the region, of the powder still outside it (the boundary
    /// when none is).
    fn trailing_edge(&self, state: &[BodyState]) -> f64 {
        let s = self.plan.class.side();
        let far = self
            .outside(state)
            .map(|x| -s * x.x)
            .fold(f64::NEG_INFINITY, f64::max);
        if far.is_finite() {
            -s * far
        } else {
            self.plan.boundary
        }
    }

    /// The frame a stroke from `n` is measured in.
    pub fn frame(&self, n: &PushNode) -> Frame {
        let lean =
            self.plan.lean_deg.to_radians() * if self.plan.class.pulls() { 1.0 } else { -1.0 };
        Frame {
            side: self.plan.class.side(),
            trailing: self.trailing_edge(&n.state),
            contact: n.contact,
            plate_top: self.plate_top(),
            lean,
            speed: self.plan.speed,
            dt: self.scene.simulation.dt,
        }
    }

    /// The simulation of a stroke from `n`, at its first step.
    pub fn stroke_simulation(&self, n: &PushNode, st: &Stroke) -> anyhow::Result<Simulation> {
        let m = motion(&self.frame(n), st);
        let mut scene = self.scene.clone();
        let tool = &mut scene.colliders[self.tool];
        tool.position = m.start.into();
        let (a, b, c) = m.rotation.to_euler(glam::EulerRot::XYZ);
        tool.rotation_deg = (a.to_degrees(), b.to_degrees(), c.to_degrees());
        tool.control = Some(ControlSpec::Actions(m.controls));
        scene.validate()?;
        let build = Build::new(&scene)?.with_start(&scene, &n.state)?;
        Ok(build.simulation(scene, &SimOptions::default())?)
    }

    /// One rollout of a stroke: (loss, share in the region, the final state when simulated).
    pub fn rollout(
        &mut self,
        n: &PushNode,
        phi: [f64; 5],
    ) -> anyhow::Result<(f64, f64, Option<Vec<BodyState>>)> {
        let full = key(&n.key, &phi);
        if let Some(e) = self.replay(&full) {
            return Ok((e.loss, e.value, None));
        }
        let t0 = Instant::now();
        let st = Stroke::from_phi(&phi);
        let mut sim = self.stroke_simulation(n, &st)?;
        let steps = sim.horizon;
        sim.run(steps, |_| {})?;
        let (loss, share, states) = self.record(&mut sim, full, None, t0)?;
        Ok((loss, share, Some(states)))
    }

    /// A rollout counted, and its journal entry if it has one (then also counted as replayed,
    /// with its compute).
    fn replay(&mut self, full: &str) -> Option<Entry> {
        self.rollouts += 1;
        let e = self.journal.get(full)?.clone();
        self.particle_substeps += e.particle_substeps;
        self.replayed += 1;
        self.backward += usize::from(e.grad.is_some());
        (self.progress)(
            self.rollouts,
            &format!("replayed: {:.0} % in", 100.0 * e.value),
        );
        Some(e)
    }

    /// A simulated rollout, `sim` after its horizon, with its push loss and gradient if a
    /// backward pass ran: its loss, share and final state, and its time (a gradient rollout's
    /// where it has a gradient), its compute (the backward pass at the multiple of a forward the
    /// plan budgets with), its journal line and the progress message.
    fn record(
        &mut self,
        sim: &mut Simulation,
        key: String,
        backward: Option<(f64, [f64; 5])>,
        t0: Instant,
    ) -> anyhow::Result<(f64, f64, Vec<BodyState>)> {
        let states = sim.body_states();
        let (loss, share) = (self.loss(&states), self.share(&states));
        let gradient = backward.is_some();
        let charge = if gradient {
            1.0 + STROKE_BACKWARD_COST
        } else {
            1.0
        };
        let e = Entry {
            key,
            loss,
            value: share,
            particle_substeps: (sim.particle_count() * sim.horizon * sim.params().substeps) as f64
                * charge,
            push_loss: backward.map(|b| b.0),
            grad: backward.map(|b| b.1),
        };
        let timing = if gradient {
            self.backward += 1;
            &mut self.gradient_timing
        } else {
            &mut self.forward_timing
        };
        timing.0 += t0.elapsed().as_secs_f64();
        timing.1 += 1;
        self.particle_substeps += e.particle_substeps;
        let message = format!(
            "{:.0} % in{}",
            100.0 * e.value,
            if gradient { " (gradient)" } else { "" }
        );
        self.journal.put(e)?;
        (self.progress)(self.rollouts, &message);
        Ok((loss, share, states))
    }

    /// The node a stroke leads to.
    fn after(
        &mut self,
        n: &PushNode,
        phi: [f64; 5],
        states: Option<Vec<BodyState>>,
        rollouts: usize,
    ) -> anyhow::Result<PushNode> {
        let st = Stroke::from_phi(&phi);
        let states = match states {
            Some(s) => s,
            None => {
                let mut sim = self.stroke_simulation(n, &st)?;
                let steps = sim.horizon;
                sim.run(steps, |_| {})?;
                sim.body_states()
            }
        };
        let landing = motion(&self.frame(n), &st).landing().to_array();
        let in_region = self.share(&states);
        let contact = self.contacts(&states, 1)[0];
        Ok(PushNode {
            stroke: Some(Done {
                contact: n.contact,
                phi,
                stroke: st,
                landing,
                in_region,
                rollouts,
            }),
            state: Arc::new(states),
            in_region,
            contact,
            strokes: n.strokes + 1,
            key: format!("{}/s", n.key),
        })
    }

    /// The scripted stroke from `n`: straight through the middle of the powder still
    /// outside, landing 1 cm behind it, 1 mm above the plate, ending 1 cm inside the region.
    pub fn scripted(&self, n: &PushNode) -> Stroke {
        let s = self.plan.class.side();
        let trailing = self.trailing_edge(&n.state);
        let behind = 0.01;
        let landing = trailing - s * behind;
        Stroke {
            behind,
            lateral: 0.0,
            yaw_deg: 0.0,
            height: 0.001,
            length: ((self.plan.boundary + s * 0.01 - landing) * s).clamp(RANGES[4].0, RANGES[4].1),
        }
    }

    pub fn done(&self, n: &PushNode) -> bool {
        n.in_region >= self.plan.success_fraction
    }

    fn result(
        &self,
        method: super::dosing::Method,
        path: &[PushNode],
        expansions: usize,
        t0: Instant,
    ) -> PushResult {
        let last = path.last().expect("the start");
        PushResult {
            class: self.plan.class,
            method,
            optimiser: self.plan.optimiser,
            success_fraction: self.plan.success_fraction,
            in_region: last.in_region,
            success: self.done(last),
            strokes: path.iter().filter_map(|n| n.stroke.clone()).collect(),
            rollouts: self.rollouts,
            particle_substeps: self.particle_substeps,
            expansions,
            replayed: self.replayed,
            wall_s: t0.elapsed().as_secs_f64(),
            backward: self.backward,
            forward_timing: self.forward_timing,
            gradient_timing: self.gradient_timing,
        }
    }

    /// Plans with `method`: the result and the path from the start.
    pub fn run(
        &mut self,
        method: super::dosing::Method,
    ) -> anyhow::Result<(PushResult, Vec<PushNode>)> {
        use super::dosing::Method;
        let t0 = Instant::now();
        let start = self.start()?;
        if method == Method::Astar {
            let opts = SearchOptions {
                explore: self.plan.explore,
                seed: self.seed,
                max_expansions: self.plan.max_expansions,
            };
            let r = search(self, start, &opts)?;
            return Ok((self.result(method, &r.path, r.expansions, t0), r.path));
        }
        let mut path = vec![start];
        while path.len() <= self.plan.max_strokes {
            let n = path.last().expect("the start").clone();
            if self.done(&n) {
                break;
            }
            let next = if method == Method::Greedy {
                match self.optimise(&n)? {
                    Some(m) => m,
                    None => break,
                }
            } else {
                let phi = self.scripted(&n).to_phi();
                let (_, _, st) = self.rollout(&n, phi)?;
                self.after(&n, phi, st, 1)?
            };
            path.push(next);
        }
        let tried = path.len() - 1;
        Ok((self.result(method, &path, tried, t0), path))
    }
}

impl Task for Push {
    type Node = PushNode;
    fn is_success(&self, n: &PushNode) -> bool {
        self.done(n)
    }
    fn opt_wrench(&mut self, n: &PushNode) -> anyhow::Result<Option<(PushNode, f64)>> {
        Ok(self.optimise(n)?.map(|m| (m, 1.0)))
    }
    fn opt_is_success(&self, from: &PushNode, to: &PushNode) -> bool {
        self.done(to) || to.in_region - from.in_region >= self.plan.min_gain
    }
    fn contact_loc(&mut self, n: &PushNode) -> Vec<(PushNode, f64)> {
        let k = self.plan.contacts;
        self.contacts(&n.state, k)
            .into_iter()
            .enumerate()
            .filter(|(_, z)| (z - n.contact).abs() > 1e-9)
            .map(|(i, z)| {
                let mut m = n.clone();
                m.contact = z;
                m.stroke = None;
                m.key = format!("{}/m{i}", n.key);
                (m, self.plan.move_cost)
            })
            .collect()
    }
    fn heuristic(&self, n: &PushNode) -> f64 {
        self.estimate(n)
    }
    fn distance(&self, n: &PushNode) -> f64 {
        (self.plan.success_fraction - n.in_region).max(0.0)
    }
}
