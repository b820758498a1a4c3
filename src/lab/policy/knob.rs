//! The dataset's labeller: one family of skills per scene, "scoop the dose, then empty the spoon
//! over the cup", and a root search of the dose along it.
//!
//! **Why a family.** Many Θ deliver the same mass (a shallow scoop emptied, a deep one tipped
//! part way), so a per-scene optimiser over all five parameters lands in a different mode on
//! similar scenes, and a network fitted to such labels learns their mean. On the family, Θ is
//! a function of the scene and one number, the scoop depth `s`; the mass scooped, and so
//! delivered, rises with it (a sweep over the randomised powders: 0 g at the shallowest, 2.9–3.8
//! g at the deepest, monotone), so the label of a (scene, target) pair is unique.
//!
//! **The family** ([`family`]): scoop depth `s`; scoop angle, lift height and pour angle at
//! [`CANONICAL`] (a pour angle of 127.5°, past the 60–83° band in which a spoon empties, so the
//! whole scoop falls); transport distance equal to the scene's cup distance.
//!
//! **The search** ([`search`]): rollouts at `s = −1` and `s = +1`; where the target lies
//! between what they deliver, the Illinois root search of [`crate::lab::optim::line`] closes the
//! bracket, forward only, to [`SKILL_REPEATABILITY`] or the budget. A target above the deepest
//! scoop's mass is answered with `s = +1`.
//!
//! **Hindsight.** Every rollout of the search is itself an exact answer: Θ delivers its own mass
//! M, so it is the label of the same scene with target M (the target does not change the
//! physics). [`crate::lab::policy::dataset`] keeps these as extra samples at no extra rollout.

use crate::lab::optim::line::{self, Budget, Probe, SKILL_REPEATABILITY};
use crate::lab::optim::problem::{Outcome, Problem};
use crate::lab::optim::report::BACKWARD_COST;
use crate::scene::randomize::Draw;
use crate::scene::ControlSpec;
use crate::skills::Theta;
use crate::util::SplitMix64;

/// Θ's component that is the knob: the scoop depth.
pub const KNOB: usize = 0;
/// The family's other components (normalised): scoop angle 34°, lift height 60 mm, pour angle
/// 127.5° (in the randomised scene's ranges). The transport distance (component 3) is the scene's.
pub const CANONICAL: Theta = Theta([0.0, 0.2, 0.0, 0.0, 0.5]);

/// The normalised transport distance that carries the spoon over the target cup: the cup
/// distance mapped into the skill's range, clamped into the box.
pub fn transport(problem: &Problem, d: &Draw) -> f64 {
    match &problem.scene().colliders[problem.tool].control {
        Some(ControlSpec::Skill(sk)) => {
            let (lo, hi) = sk.ranges.transport_distance;
            (2.0 * (d.cup_distance - lo) / (hi - lo) - 1.0).clamp(-1.0, 1.0)
        }
        _ => unreachable!("Problem::new checks for a skill tool"),
    }
}

/// The family's Θ at scoop depth `s` on scene `d`.
pub fn family(problem: &Problem, d: &Draw, s: f64) -> Theta {
    let mut t = CANONICAL;
    t[KNOB] = s.clamp(-1.0, 1.0);
    t[3] = transport(problem, d);
    t
}

/// The search's rollouts, in order: each knob value and its outcome.
pub type Trace = Vec<(f64, Outcome)>;

/// The root search of the dose along the family, at most `budget` forward rollouts (at least 2).
pub fn search(problem: &Problem, d: &Draw, budget: usize) -> anyhow::Result<Trace> {
    let mut trace: Trace = Vec::new();
    let run = |s: f64, trace: &mut Trace| -> anyhow::Result<Probe> {
        let o = problem.evaluate(family(problem, d, s), false, true)?;
        let p = Probe {
            indicator: o.indicator,
            loss: o.loss,
            grad: None,
        };
        trace.push((s, o));
        Ok(p)
    };
    let lo = run(-1.0, &mut trace)?;
    let hi = run(1.0, &mut trace)?;
    if lo.indicator * hi.indicator >= 0.0 || budget <= 2 {
        return Ok(trace);
    }
    let mut rng = SplitMix64(0);
    line::search(
        &[-1.0],
        Some((lo.indicator, lo.loss)),
        Some((&[1.0], hi.indicator)),
        Budget {
            forward_rollouts: (budget - 2) as f64,
            gradient_cost: 1.0 + BACKWARD_COST,
            restart: false,
            closed: SKILL_REPEATABILITY,
        },
        false,
        &mut rng,
        &mut |w, _| run(w[0], &mut trace),
    )?;
    Ok(trace)
}

/// The trace's rollout of lowest loss (its knob value and outcome).
pub fn best(trace: &Trace) -> Option<&(f64, Outcome)> {
    trace.iter().min_by(|a, b| a.1.loss.total_cmp(&b.1.loss))
}
