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
//! - **`OptWrench`** runs CMA-ES on the soft share of mass outside the region (logistic edges
//!   half a cell wide), from the scripted stroke with a step of [`STROKE_SIGMA`], for the plan's
//!   `stroke_budget` rollouts, and keeps the one of lowest loss.
//! - **`OptIsSuccess`**: the stroke reached success or moved `min_gain` of the mass in.
//! - **`ContactLoc`** splits the powder still outside into `contacts` bands across the stroke
//!   and aims at each band's median z.
//! - **Cost**: one per stroke, `move_cost` per relocation; the heuristic is 1 until success.
//! - **Scripted**: a straight stroke through the middle of the powder still outside, the blade
//!   landing 1 cm behind it at 1 mm above the plate and stopping 1 cm inside the region,
//!   repeated until success or `max_strokes`.
//!
//! The rollouts go through a [`Journal`] as the dosing plan's do.

use super::journal::{key, node_seed, Entry, Journal, Progress};
use super::search::{search, SearchOptions, Task};
use crate::components::BodyState;
use crate::lab::optim::cma::{reflect, run_sequential};
use crate::scene::plan::{PlanSpec, PushClass, PushPlan};
use crate::scene::{ControlSpec, Scene};
use crate::sim::{Build, SimOptions, Simulation};
use glam::{DQuat, DVec3};
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

/// The physical range of each stroke parameter: landing distance behind the powder (m),
/// lateral offset (m), yaw (degrees), edge height above the plate (m), length (m).
pub const RANGES: [(f64, f64); 5] = [
    (0.003, 0.02),
    (-0.015, 0.015),
    (-30.0, 30.0),
    (0.0005, 0.005),
    (0.02, 0.12),
];

/// The height the blade descends from onto its landing point, and lifts by after the stroke
/// (m).
pub const LIFT: f64 = 0.02;
/// Steps the spatula holds still after lifting, for the powder to settle.
pub const SETTLE_STEPS: usize = 10;

/// CMA-ES's initial step (Φ units) around the scripted stroke: a quarter of the box's half
/// width. The scripted stroke is a good start (it reaches success alone on a compact patch), and
/// at the default step of 0.5 eight samples around it were all worse on a wide patch.
pub const STROKE_SIGMA: f64 = 0.25;

/// A stroke in physical units.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
pub struct Stroke {
    pub behind: f64,
    pub lateral: f64,
    pub yaw_deg: f64,
    pub height: f64,
    pub length: f64,
}

impl Stroke {
    pub fn from_phi(phi: &[f64; 5]) -> Stroke {
        let m = |k: usize| RANGES[k].0 + 0.5 * (phi[k] + 1.0) * (RANGES[k].1 - RANGES[k].0);
        Stroke {
            behind: m(0),
            lateral: m(1),
            yaw_deg: m(2),
            height: m(3),
            length: m(4),
        }
    }
    /// Φ of a stroke, clamped into the box.
    pub fn to_phi(&self) -> [f64; 5] {
        let v = [
            self.behind,
            self.lateral,
            self.yaw_deg,
            self.height,
            self.length,
        ];
        std::array::from_fn(|k| {
            (2.0 * (v[k] - RANGES[k].0) / (RANGES[k].1 - RANGES[k].0) - 1.0).clamp(-1.0, 1.0)
        })
    }
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
            particle_substeps: 0.0,
            replayed: 0,
            progress: Box::new(|_, _| {}),
            scene,
        })
    }

    fn plate_top(&self) -> f64 {
        self.plate.0.y + self.plate.1.y
    }

    /// Whether a position lies in the region: on the plate (above its bottom, within its
    /// extent) beyond the boundary on the class's side.
    fn in_region(&self, x: DVec3) -> bool {
        let (c, h) = self.plate;
        let s = self.plan.class.side();
        s * (x.x - self.plan.boundary) > 0.0
            && (x.x - c.x).abs() < h.x
            && (x.z - c.z).abs() < h.z
            && x.y > c.y - h.y
    }

    /// The hard share of particles in the region (the bodies share one material here, so
    /// particles stand for mass).
    fn share(&self, state: &[BodyState]) -> f64 {
        let n: usize = state.iter().map(|b| b.x.len()).sum();
        let k = state
            .iter()
            .flat_map(|b| b.x.iter())
            .filter(|x| self.in_region(**x))
            .count();
        k as f64 / n.max(1) as f64
    }

    /// The soft share outside the region: `1 − mean σ(s·(x − boundary)/w)·σ(edge terms)`.
    fn loss(&self, state: &[BodyState]) -> f64 {
        use crate::math::geometry::logistic;
        let (c, h) = self.plate;
        let w = 0.5 * self.scene.simulation.dx;
        let s = self.plan.class.side();
        let (mut sum, mut n) = (0.0, 0.0);
        for x in state.iter().flat_map(|b| b.x.iter()) {
            sum += logistic(s * (x.x - self.plan.boundary) / w)
                * logistic((h.x - (x.x - c.x).abs()) / w)
                * logistic((h.z - (x.z - c.z).abs()) / w)
                * logistic((x.y - (c.y - h.y)) / w);
            n += 1.0;
        }
        1.0 - sum / n
    }

    /// The particles still outside the region.
    fn outside<'a>(&'a self, state: &'a [BodyState]) -> impl Iterator<Item = DVec3> + 'a {
        state
            .iter()
            .flat_map(|b| b.x.iter())
            .filter(|x| !self.in_region(**x))
            .copied()
    }

    /// The median of the z of the particles outside, within `[lo, hi]` quantiles of z.
    fn contacts(&self, state: &[BodyState], k: usize) -> Vec<f64> {
        let mut z: Vec<f64> = self.outside(state).map(|x| x.z).collect();
        if z.is_empty() {
            return vec![self.plate.0.z];
        }
        z.sort_by(f64::total_cmp);
        (0..k)
            .map(|i| z[((2 * i + 1) * z.len() / (2 * k)).min(z.len() - 1)])
            .collect()
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

    /// The landing point, the pose and the per-step controls of a stroke from `n`.
    fn motion(&self, n: &PushNode, st: &Stroke) -> ([f64; 3], DQuat, Vec<[f64; 6]>) {
        let s = self.plan.class.side();
        let trailing = self.trailing_edge(&n.state);
        let yaw = st.yaw_deg.to_radians();
        let d = DVec3::new(s * yaw.cos(), 0.0, yaw.sin());
        let landing = DVec3::new(
            trailing - s * st.behind,
            self.plate_top() + st.height,
            n.contact + st.lateral,
        );
        // Local z (the blade's face normal) along the stroke, then the handle leaned about the
        // blade's width: toward the stroke for a pull, against it for a push.
        let face = DQuat::from_rotation_y(d.x.atan2(d.z));
        let width = face * DVec3::X;
        let lean =
            self.plan.lean_deg.to_radians() * if self.plan.class.pulls() { 1.0 } else { -1.0 };
        let rotation = DQuat::from_axis_angle(width, lean) * face;
        let dt = self.scene.simulation.dt;
        let steps = |dist: f64| ((dist / (self.plan.speed * dt)).round() as usize).max(1);
        let mut controls = Vec::new();
        let n1 = steps(LIFT);
        controls.extend(std::iter::repeat_n(
            [0.0, -LIFT / n1 as f64, 0.0, 0.0, 0.0, 0.0],
            n1,
        ));
        let n2 = steps(st.length);
        let step = d * st.length / n2 as f64;
        controls.extend(std::iter::repeat_n(
            [step.x, 0.0, step.z, 0.0, 0.0, 0.0],
            n2,
        ));
        controls.extend(std::iter::repeat_n(
            [0.0, LIFT / n1 as f64, 0.0, 0.0, 0.0, 0.0],
            n1,
        ));
        controls.extend(std::iter::repeat_n([0.0; 6], SETTLE_STEPS));
        let start = landing + DVec3::new(0.0, LIFT, 0.0);
        (start.to_array(), rotation, controls)
    }

    /// The simulation of a stroke from `n`, at its first step.
    pub fn stroke_simulation(&self, n: &PushNode, st: &Stroke) -> anyhow::Result<Simulation> {
        let (start, rotation, controls) = self.motion(n, st);
        let mut scene = self.scene.clone();
        let tool = &mut scene.colliders[self.tool];
        tool.position = (start[0], start[1], start[2]);
        let (a, b, c) = rotation.to_euler(glam::EulerRot::XYZ);
        tool.rotation_deg = (a.to_degrees(), b.to_degrees(), c.to_degrees());
        tool.control = Some(ControlSpec::Actions(controls.clone()));
        scene.validate()?;
        let build = Build::new(&scene)?.with_start(&scene, &n.state)?;
        Ok(build.simulation(scene, &SimOptions::default())?)
    }

    /// One rollout of a stroke: (loss, share in the region, the final state when simulated).
    fn rollout(
        &mut self,
        n: &PushNode,
        phi: [f64; 5],
    ) -> anyhow::Result<(f64, f64, Option<Vec<BodyState>>)> {
        let full = key(&n.key, &phi);
        self.rollouts += 1;
        if let Some(e) = self.journal.get(&full) {
            self.particle_substeps += e.particle_substeps;
            self.replayed += 1;
            let (l, v) = (e.loss, e.value);
            (self.progress)(self.rollouts, &format!("replayed: {:.0} % in", 100.0 * v));
            return Ok((l, v, None));
        }
        let st = Stroke::from_phi(&phi);
        let mut sim = self.stroke_simulation(n, &st)?;
        let steps = sim.horizon;
        sim.run(steps, |_| {})?;
        let states = sim.body_states();
        let (loss, share) = (self.loss(&states), self.share(&states));
        let work = (sim.particle_count() * steps * sim.params().substeps) as f64;
        self.particle_substeps += work;
        self.journal.put(Entry {
            key: full,
            loss,
            value: share,
            particle_substeps: work,
        })?;
        (self.progress)(self.rollouts, &format!("{:.0} % in", 100.0 * share));
        Ok((loss, share, Some(states)))
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
        let landing = {
            let (start, _, _) = self.motion(n, &st);
            [start[0], start[1] - LIFT, start[2]]
        };
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

    /// `OptWrench` from `n`.
    pub fn optimise(&mut self, n: &PushNode) -> anyhow::Result<Option<PushNode>> {
        if n.strokes >= self.plan.max_strokes {
            return Ok(None);
        }
        let budget = self.plan.stroke_budget;
        let x0 = self.scripted(n).to_phi();
        let mut tried = Vec::new();
        let first = self.rollout(n, x0)?;
        tried.push((first.0, x0, first.2));
        if budget > 1 {
            let seed = node_seed(self.seed, &n.key);
            run_sequential(x0.to_vec(), STROKE_SIGMA, seed, budget - 1, |x| {
                let phi: [f64; 5] = std::array::from_fn(|k| reflect(x[k]));
                let (l, _, st) = self.rollout(n, phi)?;
                tried.push((l, phi, st));
                Ok(l)
            })?;
        }
        let best = tried
            .into_iter()
            .reduce(|a, b| if b.0 < a.0 { b } else { a })
            .expect("one rollout at least");
        Ok(Some(self.after(n, best.1, best.2, budget)?))
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
            success_fraction: self.plan.success_fraction,
            in_region: last.in_region,
            success: self.done(last),
            strokes: path.iter().filter_map(|n| n.stroke.clone()).collect(),
            rollouts: self.rollouts,
            particle_substeps: self.particle_substeps,
            expansions,
            replayed: self.replayed,
            wall_s: t0.elapsed().as_secs_f64(),
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
        if self.done(n) {
            0.0
        } else {
            1.0
        }
    }
    fn distance(&self, n: &PushNode) -> f64 {
        (self.plan.success_fraction - n.in_region).max(0.0)
    }
}
