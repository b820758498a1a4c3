//! The gravimetric pour: a closed loop on the spoon's load during the pour, within the one
//! rollout.
//!
//! An open-loop skill empties whatever the spoon scooped, and what it scoops depends on the
//! grains' packing, which no policy sees (docs/results/policy.md: the optimiser's own Θ on a
//! repacked powder misses by 0.07 g, three grains). A lab robot doses against a balance
//! instead. Here the spoon scoops more than the dose, is carried over the target cup as the
//! skill carries it, and then tilts about the skill's pour axis (at the skill's angular speed
//! up to [`Gravimetric::fast_to_deg`], at [`Gravimetric::speed_deg`] past it) while a load cell
//! at the wrist reads what the spoon still holds. When the mass that has left the spoon, plus
//! [`Gravimetric::lead_steps`] steps of its current outflow (the powder still to leave while
//! the spoon turns back), reaches the dose, the spoon turns back upright at the skill's angular
//! speed (or [`Gravimetric::turn_back_deg`]); what it still holds stays in it. The skill's
//! settle steps follow.
//!
//! **The load cell** reads the grains within `bowl_radius + dx` of the bowl's centre (the
//! spoon's frame origin): the bowl and the heap on it, not a grain that has left the lip by a
//! cell.
//!
//! **It does not meter** (docs/results/pour.md): the powder leaves in bursts and keeps leaving
//! after the spoon turns back, so the loop doses worse than the open-loop policy.
//!
//! The scoop, lift and carry are the skill's own, so a pour differs from the open-loop rollout
//! only after the carry. The loop makes the rollout's controls depend on its state, so it has
//! no adjoint; the policy's rollouts and their search need none.

use crate::components::{Body, Collider, ColliderPose, Position};
use crate::lab::optim::problem::{Outcome, Problem};
use crate::math::sdf::Shape;
use crate::scene::ControlSpec;
use crate::sim::Simulation;
use crate::skills::Theta;
use anyhow::Context;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// The pour's settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Gravimetric {
    /// Tilt speed while pouring (degrees/s).
    pub speed_deg: f64,
    /// The spoon tilts at the skill's angular speed up to this angle (degrees), and at
    /// `speed_deg` past it. The stop rule holds throughout.
    pub fast_to_deg: f64,
    /// The spoon turns back when the mass poured plus this many steps of the current outflow
    /// reaches the dose: the powder that still leaves while it turns back.
    pub lead_steps: f64,
    /// How fast the spoon turns back (degrees/s); `None`, the skill's angular speed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub turn_back_deg: Option<f64>,
    /// Taps past `fast_to_deg`: the spoon drops and rises this far (mm) on alternate steps while
    /// it tilts, and stops tapping when it turns back. `None`, no taps.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tap_mm: Option<f64>,
    /// The most the spoon tilts (degrees).
    pub max_deg: f64,
}

impl Default for Gravimetric {
    /// 10°/s past 60°, where the skill's pour range starts (at dx = 5 mm the randomised powders
    /// start to leave near 63°; at 2.5 mm near 50°, so there the fast tilt pours some); a lead
    /// of 3 steps, the ratio of the powder that still left after the spoon turned back to the
    /// outflow of the step before, on a training draw at dx = 2.5 mm; up to 95°, past the 83° at
    /// which an open-loop pour has emptied the spoon at dx = 5 mm.
    fn default() -> Self {
        Gravimetric {
            speed_deg: 10.0,
            fast_to_deg: 60.0,
            lead_steps: 3.0,
            max_deg: 95.0,
            turn_back_deg: None,
            tap_mm: None,
        }
    }
}

impl Gravimetric {
    /// Refuses settings the loop cannot run: a speed that is not positive (the tilt would never
    /// end), a negative lead or a tilt limit outside (0°, 180°].
    pub fn validate(&self) -> anyhow::Result<()> {
        let ok = self.speed_deg > 0.0
            && self.speed_deg.is_finite()
            && self.lead_steps >= 0.0
            && self.lead_steps.is_finite()
            && self.fast_to_deg >= 0.0
            && self.max_deg > 0.0
            && self.max_deg <= 180.0
            && self.turn_back_deg.is_none_or(|v| v > 0.0 && v.is_finite())
            && self.tap_mm.is_none_or(|v| v > 0.0 && v.is_finite());
        anyhow::ensure!(
            ok,
            "gravimetric pour: speed {}°/s, lead {} steps, fast to {}°, up to {}°, back at {:?}°/s, taps \
             of {:?} mm: the speeds and taps must be positive, the lead at least 0 and the limit \
             in (0°, 180°]",
            self.speed_deg,
            self.lead_steps,
            self.fast_to_deg,
            self.max_deg,
            self.turn_back_deg,
            self.tap_mm
        );
        Ok(())
    }
}

/// What a gravimetric rollout gives besides its outcome.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PourTrace {
    /// The load cell's reading when the pour began (g).
    pub held_g: f64,
    /// The tilt (degrees) and the mass that had left the spoon (g), per pour step.
    pub steps: Vec<(f64, f64)>,
    /// The pour step at which the spoon turned back, if it did before `max_deg`.
    pub stopped_at: Option<usize>,
}

/// The mass (g) the load cell of the tool `tool` reads in `sim`'s current state.
pub fn held_g(sim: &mut Simulation, tool: usize, reach: f64) -> f64 {
    let world = &mut sim.world;
    let mut q = world.query::<(&Collider, &ColliderPose)>();
    let pose = q
        .iter(world)
        .find(|(c, _)| c.index == tool)
        .map(|(_, p)| p.pose)
        .expect("the problem's tool is in its world");
    let mut q = world.query::<(&Body, &Position)>();
    let mut kg = 0.0;
    for (b, x) in q.iter(world) {
        let n =
            x.0.iter()
                .filter(|p| pose.to_local(**p).length() < reach)
                .count();
        kg += n as f64 * b.particle_mass;
    }
    kg * 1e3
}

/// One rollout of Θ whose pour is the gravimetric loop toward `target_g`.
pub fn rollout(
    problem: &Problem,
    theta: Theta,
    target_g: f64,
    g: &Gravimetric,
) -> anyhow::Result<(Outcome, PourTrace)> {
    let t0 = Instant::now();
    g.validate()?;
    let tool = &problem.scene().colliders[problem.tool];
    let Some(ControlSpec::Skill(sk)) = &tool.control else {
        unreachable!("Problem::new checks for a skill tool")
    };
    let reach = match tool.shape {
        Shape::Spoon { bowl_radius, .. } => bowl_radius + problem.scene().simulation.dx,
        _ => anyhow::bail!("the gravimetric pour needs a spoon; the tool is not one"),
    };
    let (dt, settle) = (problem.scene().simulation.dt, sk.settle_steps);
    let axis = glam::DVec3::from(sk.pour_axis).normalize();
    let w_fast = sk.angular_speed_deg.to_radians() * dt;
    let w_back = g.turn_back_deg.map_or(w_fast, |v| v.to_radians() * dt);
    let w = g.speed_deg.to_radians() * dt;
    let carry = std::cell::Cell::new(0);
    let mut sim = problem.simulation_with(theta, true, |c, phases| {
        carry.set(phases[..4].iter().sum());
        c.truncate(carry.get());
    })?;
    let carry = carry.get();
    let context = || format!("gravimetric rollout at Θ = {theta:?}");
    sim.run(carry, |_| {}).with_context(context)?;
    let ti = problem.tool;
    let mut trace = PourTrace {
        held_g: held_g(&mut sim, ti, reach),
        ..Default::default()
    };
    let max = g.max_deg.to_radians();
    let (mut angle, mut turning, mut tapped) = (0.0_f64, false, 0usize);
    let mut steps = carry;
    // Bounded: the tilt rises to `max` and the return takes as long at the faster speed.
    let bound = carry + 2 * (max / w).ceil() as usize + 2;
    loop {
        let poured = trace.held_g - held_g(&mut sim, ti, reach);
        let rate = trace.steps.last().map_or(0.0, |l| (poured - l.1).max(0.0));
        trace.steps.push((angle.to_degrees(), poured));
        let w = if angle < g.fast_to_deg.to_radians() {
            w_fast
        } else {
            w
        };
        if !turning && (poured + g.lead_steps * rate >= target_g || angle + w > max) {
            turning = true;
            trace.stopped_at = (angle + w <= max).then_some(trace.steps.len() - 1);
        }
        let d = if turning { -w_back.min(angle) } else { w };
        if turning && d == 0.0 || steps >= bound {
            break;
        }
        // Past `fast_to_deg` a tap drops the spoon one step and lifts it back the next; a tap in
        // progress when the spoon turns back still lifts it back.
        let y = match g.tap_mm {
            Some(t) if !turning && angle >= g.fast_to_deg.to_radians() && tapped % 2 == 0 => {
                -t * 1e-3
            }
            Some(t) if tapped % 2 == 1 => t * 1e-3,
            _ => 0.0,
        };
        if y != 0.0 {
            tapped += 1;
        }
        angle += d;
        let r = axis * d;
        sim.drive_tool(ti, [0.0, y, 0.0, r.x, r.y, r.z]);
        sim.step().with_context(context)?;
        steps += 1;
    }
    sim.run(settle, |_| {}).with_context(context)?;
    sim.horizon = steps + settle;
    let xs: Vec<_> = sim.body_states().into_iter().map(|b| b.x).collect();
    let loss = problem.loss().eval(&xs).0;
    let (transported, indicator) = problem.indicator(&mut sim);
    Ok((
        Outcome {
            loss,
            indicator,
            transported,
            grad: None,
            steps: sim.horizon,
            substeps: sim.params().substeps,
            particles: sim.particle_count(),
            wall_s: t0.elapsed().as_secs_f64(),
        },
        trace,
    ))
}
