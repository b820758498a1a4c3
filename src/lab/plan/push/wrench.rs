//! `OptWrench` for a stroke: the next stroke from a node, optimised for the plan's budget of
//! `stroke_budget` forward rollouts, by one of two optimisers ([`StrokeOptimiser`]):
//!
//! - **CMA-ES** on the soft share of the mass outside the region, from the scripted stroke with
//!   a step of [`STROKE_SIGMA`];
//! - **the gradient**: from the scripted stroke, line searches along the push loss's gradient
//!   by the adjoint ([`Push::rollout_grad`]). A gradient rollout is charged
//!   `1 + STROKE_BACKWARD_COST` forward rollouts. A trial at `Φ − r·g/‖g‖` (clamped to the box,
//!   [`TrustRegion`]) is accepted when its soft share outside is below the incumbent's; the
//!   radius grows on acceptance and halves otherwise. A trial runs with its backward pass while
//!   the budget still holds that and one more forward rollout, so an accepted step goes on from
//!   its own gradient; after that the trials are forward only, along the last gradient.
//!
//! Both keep, of the strokes they tried, the one of lowest soft share outside, so they differ in
//! how they search only. The gradient descends the push loss (every grain outside pulls toward
//! the region) and is judged by the soft share (the measure success counts); the push loss is
//! smooth where a stroke's grain count is not.

use super::{GradRollout, Push, PushNode, PUSH_WIDTH_CELLS, STROKE_BACKWARD_COST, STROKE_SIGMA};
use crate::adjoint::checkpoint::Tape;
use crate::adjoint::loss::Loss;
use crate::adjoint::tape::gradient;
use crate::components::BodyState;
use crate::lab::optim::cma::{reflect, run_sequential};
use crate::lab::optim::hybrid::TrustRegion;
use crate::lab::plan::journal::key;
use crate::lab::plan::journal::node_seed;
use crate::lab::plan::stroke::{phi_gradient, Stroke};
use crate::rollout::DEFAULT_TAPE_BUDGET;
use crate::scene::plan::StrokeOptimiser;
use glam::DVec3;
use std::time::Instant;

/// The gradient's first line-search radius (Φ units, Euclidean): the distance from the scripted
/// stroke of CMA-ES's typical sample (`STROKE_SIGMA·√5 ≈ 0.56`), rounded down.
pub const LINE_RADIUS: f64 = 0.5;

type Tried = (f64, [f64; 5], Option<Vec<BodyState>>);

impl Push {
    /// `OptWrench` from `n`, with the plan's optimiser.
    pub fn optimise(&mut self, n: &PushNode) -> anyhow::Result<Option<PushNode>> {
        if n.strokes >= self.plan.max_strokes {
            return Ok(None);
        }
        let tried = match self.plan.optimiser {
            StrokeOptimiser::Cma => self.cma(n)?,
            StrokeOptimiser::Gradient => self.line_searches(n)?,
        };
        let spent = tried.len();
        let best = tried
            .into_iter()
            .reduce(|a, b| if b.0 < a.0 { b } else { a })
            .expect("one rollout at least");
        Ok(Some(self.after(n, best.1, best.2, spent)?))
    }

    fn cma(&mut self, n: &PushNode) -> anyhow::Result<Vec<Tried>> {
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
        Ok(tried)
    }

    fn line_searches(&mut self, n: &PushNode) -> anyhow::Result<Vec<Tried>> {
        let budget = self.plan.stroke_budget as f64;
        let cost = 1.0 + STROKE_BACKWARD_COST;
        let mut x = self.scripted(n).to_phi();
        let first = self.rollout_grad(n, x)?;
        let mut spent = cost;
        let (mut best, mut grad) = (first.loss, first.grad);
        let mut tried = vec![(first.loss, x, first.states)];
        let mut region = TrustRegion {
            radius: LINE_RADIUS,
        };
        while spent + 1.0 <= budget {
            let Some(trial) = region.propose_in(&x, &grad) else {
                break;
            };
            let phi: [f64; 5] = std::array::from_fn(|k| trial[k]);
            let (loss, states, g) = if spent + cost + 1.0 <= budget {
                spent += cost;
                let r = self.rollout_grad(n, phi)?;
                (r.loss, r.states, Some(r.grad))
            } else {
                spent += 1.0;
                let (l, _, st) = self.rollout(n, phi)?;
                (l, st, None)
            };
            tried.push((loss, phi, states));
            if region.judge(best, loss, LINE_RADIUS) {
                best = loss;
                x = phi;
                if let Some(g) = g {
                    grad = g;
                }
            }
        }
        Ok(tried)
    }

    /// The push loss on a state ([`PlateRegion::distance`], ramps of [`PUSH_WIDTH_CELLS`]).
    pub fn push_loss(&self) -> Loss {
        Loss::Region {
            region: self.region(),
            width: PUSH_WIDTH_CELLS * self.scene.simulation.dx,
        }
    }

    /// One rollout of a stroke with a backward pass: (the soft share outside, the share in the
    /// region, the push loss, `∂(push loss)/∂Φ`, the final state when simulated).
    pub fn rollout_grad(&mut self, n: &PushNode, phi: [f64; 5]) -> anyhow::Result<GradRollout> {
        let full = format!("{}|grad", key(&n.key, &phi));
        if let Some(e) = self.replay(&full) {
            return Ok(GradRollout {
                loss: e.loss,
                share: e.value,
                push_loss: e.push_loss.unwrap_or(f64::NAN),
                grad: e.grad.unwrap_or([f64::NAN; 5]),
                states: None,
            });
        }
        let t0 = Instant::now();
        let st = Stroke::from_phi(&phi);
        let mut sim = self.stroke_simulation(n, &st)?;
        let steps = sim.horizon;
        let g = gradient(
            &mut sim,
            steps,
            &self.push_loss(),
            Tape::Budget(DEFAULT_TAPE_BUDGET),
        )?;
        let name = &self.scene.colliders[self.tool].name;
        let pick = |v: &[(String, DVec3)]| {
            v.iter()
                .find(|(t, _)| t == name)
                .map_or(DVec3::ZERO, |(_, g)| *g)
        };
        let grad = phi_gradient(
            &self.frame(n),
            &st,
            pick(&g.tool_start),
            pick(&g.tool_start_rotation),
            g.tool_controls(name).unwrap_or(&[]),
        );
        let (loss, share, states) = self.record(&mut sim, full, Some((g.loss, grad)), t0)?;
        Ok(GradRollout {
            loss,
            share,
            push_loss: g.loss,
            grad,
            states: Some(states),
        })
    }
}
