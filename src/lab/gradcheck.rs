//! `powderlab gradcheck`: adjoint gradients against central differences in f64, per parameter.
//!
//! The loss is the scene's `loss`, by default `L = Σ_p ‖x_p(T) − t‖` (seed paper eq. 5) with
//! `t` the bottom centre of the task's target cup, or the centre of the domain floor when the
//! scene has no task. Parameters are
//! scalar directions: a uniform shift of all initial velocities or positions along an axis,
//! each material's E, ν and friction angle, each collider's friction, and gravity's y.

use crate::adjoint::loss::scene_loss;
use crate::adjoint::tape::{gradient, Loss, Tape};
use crate::components::{Position, Velocity};
use crate::scene::Scene;
use crate::sim::{SimOptions, Simulation};
use glam::DVec3;
use serde::Serialize;

/// One compared parameter.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub parameter: String,
    pub adjoint: f64,
    pub finite_difference: f64,
    pub rel_error: f64,
    pub eps: f64,
    /// Absolute size below which a central difference is round-off (see [`FD_NOISE_ULPS`]).
    pub noise_floor: f64,
    /// Both values are below `noise_floor`: a zero gradient, matched within round-off.
    pub noise_limited: bool,
    /// The backward and forward differences `(L − L₋)/ε` and `(L₊ − L)/ε`.
    pub one_sided: [f64; 2],
    /// The loss has a kink at the point: the one-sided differences differ by more than
    /// [`KINK_REL`] (and more than round-off). The central difference is then their mean, and
    /// the row is checked against the side the adjoint takes.
    pub kink: bool,
    /// For a kink, the relative error against the nearest of the one-sided differences and
    /// their mean (the central difference): at a kink the adjoint may be any of them.
    pub one_sided_rel_error: Option<f64>,
}

/// The one-sided differences of a loss smooth at the point differ by `O(ε·L″)`, far below 1 %
/// of the gradient at the steps used here (the shipped scenes' smooth rows agree to 1e-4 or
/// better). A loss with a kink exactly at the point has one-sided derivatives that differ by a
/// finite amount at every ε, whatever ε: powder at rest against a wall, shifted uniformly, is
/// pushed into the wall on one side (where particle collision takes its velocity) and away
/// from it on the other. The adjoint takes one side there (`docs/design.md` §6).
pub const KINK_REL: f64 = 1e-2;

/// A central difference `(L₊ − L₋)/2ε` carries a round-off of a few ulps of `L` over `ε`
/// (measured: about 1 ulp for the shipped scenes; 16 leaves room for longer sums). A row whose
/// adjoint and difference are both below this floor is a zero gradient: it passes when they
/// differ by less than the floor (`noise_limited`) and does not count in `max_rel_error`, where
/// a relative error of two round-off values would mean nothing.
pub const FD_NOISE_ULPS: f64 = 16.0;

/// The whole comparison.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    pub loss: f64,
    pub steps: usize,
    pub target_m: [f64; 3],
    pub rows: Vec<Row>,
    pub max_rel_error: f64,
    pub checkpoint_every: usize,
    pub tape_bytes: usize,
    pub forward_s: f64,
    pub forward_backward_s: f64,
}

fn forward_loss(
    scene: &Scene,
    steps: usize,
    threads: Option<usize>,
    dv: DVec3,
    dx: DVec3,
    loss: &Loss,
) -> anyhow::Result<f64> {
    let mut sim = Simulation::new(scene, &SimOptions::threads(threads))?;
    shift_state(&mut sim, dv, dx);
    sim.run(steps, |_| {})?;
    let xs: Vec<Vec<DVec3>> = sim.body_states().into_iter().map(|b| b.x).collect();
    Ok(loss.eval(&xs).0)
}

fn shift_state(sim: &mut Simulation, dv: DVec3, dx: DVec3) {
    if dv != DVec3::ZERO {
        for mut v in sim.world.query::<&mut Velocity>().iter_mut(&mut sim.world) {
            v.0.iter_mut().for_each(|v| *v += dv);
        }
    }
    if dx != DVec3::ZERO {
        for mut x in sim.world.query::<&mut Position>().iter_mut(&mut sim.world) {
            x.0.iter_mut().for_each(|x| *x += dx);
        }
    }
}

/// Parameter groups `gradcheck` knows.
pub const GROUPS: [&str; 7] = [
    "v0", "x0", "material", "friction", "gravity", "tool", "skill",
];

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / a.abs().max(b.abs()).max(1e-300)
}

/// Compares an adjoint value with the differences of the losses `plus`, `minus` at ±`eps` about
/// `base`: the central difference, the round-off floor, and whether the loss has a kink there.
pub fn compare(parameter: String, adjoint: f64, base: f64, plus: f64, minus: f64, eps: f64) -> Row {
    let fd = (plus - minus) / (2.0 * eps);
    let noise_floor = FD_NOISE_ULPS * f64::EPSILON * base.abs() / eps;
    let diff = (fd - adjoint).abs();
    let noise_limited = fd.abs().max(adjoint.abs()) <= noise_floor && diff <= noise_floor;
    let one_sided = [(base - minus) / eps, (plus - base) / eps];
    let kink = !noise_limited
        && (one_sided[0] - one_sided[1]).abs() > 2.0 * noise_floor
        && rel(one_sided[0], one_sided[1]) > KINK_REL;
    let mut row = Row {
        parameter,
        adjoint,
        finite_difference: fd,
        rel_error: rel(fd, adjoint),
        noise_limited,
        eps,
        noise_floor,
        one_sided,
        kink,
        one_sided_rel_error: None,
    };
    row.one_sided_rel_error = row.nearest_side().map(|(_, e)| e);
    row
}

impl Row {
    /// At a kink, which of the one-sided differences and their mean (the central difference)
    /// the adjoint is nearest, and its relative error against it; `None` off a kink.
    pub fn nearest_side(&self) -> Option<(&'static str, f64)> {
        let [minus, plus] = self.one_sided;
        self.kink.then(|| {
            [
                ("the − side", rel(self.adjoint, minus)),
                ("the + side", rel(self.adjoint, plus)),
                (
                    "the mean of the two sides",
                    rel(self.finite_difference, self.adjoint),
                ),
            ]
            .into_iter()
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .expect("three candidates")
        })
    }
}

/// Runs the comparison for the chosen parameter groups, each at its own central-difference
/// step.
pub fn run(
    scene: &Scene,
    steps: usize,
    groups: &[String],
    threads: Option<usize>,
    budget_bytes: usize,
) -> anyhow::Result<Report> {
    run_scaled(scene, steps, groups, threads, budget_bytes, 1.0)
}

/// [`run`] with every central-difference step multiplied by `eps_scale`: a sweep over it tells
/// a wrong adjoint (no step agrees) from a contact switch inside ±ε (large steps agree, small
/// ones do not, or the reverse).
pub fn run_scaled(
    scene: &Scene,
    steps: usize,
    groups: &[String],
    threads: Option<usize>,
    budget_bytes: usize,
    eps_scale: f64,
) -> anyhow::Result<Report> {
    anyhow::ensure!(
        eps_scale.is_finite() && eps_scale > 0.0,
        "--eps-scale {eps_scale}: expected a positive factor, such as 0.01 or 100"
    );
    for g in groups {
        anyhow::ensure!(
            GROUPS.contains(&g.as_str()),
            "unknown parameter group '{g}': expected some of {GROUPS:?}"
        );
    }
    let loss = scene_loss(scene);
    let target = match &loss {
        Loss::MeanL1(t) | Loss::SumDistance(t) => *t,
        Loss::Dosing(d) => d.cup.pose.translation,
        Loss::Linear(_)
        | Loss::HeightField(_)
        | Loss::Chamfer(_)
        | Loss::Region { .. }
        | Loss::Only { .. } => DVec3::ZERO,
    };
    let t0 = std::time::Instant::now();
    let base = forward_loss(scene, steps, threads, DVec3::ZERO, DVec3::ZERO, &loss)?;
    let forward_s = t0.elapsed().as_secs_f64();
    let mut sim = Simulation::new(scene, &SimOptions::threads(threads))?;
    let t1 = std::time::Instant::now();
    let g = gradient(&mut sim, steps, &loss, Tape::Budget(budget_bytes))?;
    let forward_backward_s = t1.elapsed().as_secs_f64();
    let mut rows = Vec::new();
    let mut push = |parameter: String, adjoint: f64, plus: f64, minus: f64, eps: f64| {
        rows.push(compare(parameter, adjoint, base, plus, minus, eps));
    };
    let has = |name: &str| groups.iter().any(|g| g == name);
    let axes = [("x", DVec3::X), ("y", DVec3::Y), ("z", DVec3::Z)];
    if has("v0") {
        let eps = 1e-6 * eps_scale;
        for (k, (name, e)) in axes.iter().enumerate() {
            let ad: f64 = g.v0.iter().flatten().map(|v| v[k]).sum();
            let p = forward_loss(scene, steps, threads, *e * eps, DVec3::ZERO, &loss)?;
            let m = forward_loss(scene, steps, threads, *e * -eps, DVec3::ZERO, &loss)?;
            push(format!("v0.{name} (uniform shift)"), ad, p, m, eps);
        }
    }
    if has("x0") {
        let eps = 1e-7 * eps_scale;
        for (k, (name, e)) in axes.iter().enumerate() {
            let ad: f64 = g.x0.iter().flatten().map(|v| v[k]).sum();
            let p = forward_loss(scene, steps, threads, DVec3::ZERO, *e * eps, &loss)?;
            let m = forward_loss(scene, steps, threads, DVec3::ZERO, *e * -eps, &loss)?;
            push(format!("x0.{name} (uniform shift)"), ad, p, m, eps);
        }
    }
    if has("material") {
        for (mname, spec) in &scene.materials {
            let users: Vec<usize> = scene
                .bodies
                .iter()
                .enumerate()
                .filter(|(_, b)| &b.material == mname)
                .map(|(i, _)| i)
                .collect();
            if users.is_empty() {
                continue;
            }
            for (k, param) in spec.params().iter().enumerate() {
                let ad: f64 = users.iter().map(|&i| g.material[i].0[k]).sum();
                let value = spec.param(k);
                let eps = param.fd_step.at(value) * eps_scale;
                let mut sp = scene.clone();
                sp.materials
                    .insert(mname.clone(), spec.with_param(k, value + eps));
                let mut sm = scene.clone();
                sm.materials
                    .insert(mname.clone(), spec.with_param(k, value - eps));
                let p = forward_loss(&sp, steps, threads, DVec3::ZERO, DVec3::ZERO, &loss)?;
                let m = forward_loss(&sm, steps, threads, DVec3::ZERO, DVec3::ZERO, &loss)?;
                push(format!("materials.{mname}.{}", param.name), ad, p, m, eps);
            }
        }
    }
    if has("friction") {
        let eps = 1e-6 * eps_scale;
        for (i, (name, ad)) in g.friction.iter().enumerate() {
            let mut sp = scene.clone();
            sp.colliders[i].friction += eps;
            let mut sm = scene.clone();
            sm.colliders[i].friction = (sm.colliders[i].friction - eps).max(0.0);
            let e_minus = scene.colliders[i].friction - sm.colliders[i].friction;
            let p = forward_loss(&sp, steps, threads, DVec3::ZERO, DVec3::ZERO, &loss)?;
            let m = forward_loss(&sm, steps, threads, DVec3::ZERO, DVec3::ZERO, &loss)?;
            // One-sided at μ = 0 (friction cannot be negative).
            let fd_eps = 0.5 * (eps + e_minus);
            push(format!("colliders.{name}.friction"), *ad, p, m, fd_eps);
        }
    }
    if has("tool") {
        // Tools with a constant velocity: the gradient w.r.t. that velocity is Σ_steps ∂L/∂u·Δt.
        let dt = scene.simulation.dt;
        let eps = 1e-7 * eps_scale;
        for (i, c) in scene.colliders.iter().enumerate() {
            let Some((_, gu)) = g.controls.iter().find(|(n, _)| n == &c.name) else {
                continue;
            };
            if let Some(crate::scene::ControlSpec::Constant { .. }) = &c.control {
                for (k, name) in ["x", "y", "z"].iter().enumerate() {
                    let ad: f64 = gu.iter().map(|u| u[k] * dt).sum();
                    let edit = |d: f64| {
                        let mut s = scene.clone();
                        if let Some(crate::scene::ControlSpec::Constant { linear, .. }) =
                            &mut s.colliders[i].control
                        {
                            match k {
                                0 => linear.0 += d,
                                1 => linear.1 += d,
                                _ => linear.2 += d,
                            }
                        }
                        s
                    };
                    let p =
                        forward_loss(&edit(eps), steps, threads, DVec3::ZERO, DVec3::ZERO, &loss)?;
                    let m =
                        forward_loss(&edit(-eps), steps, threads, DVec3::ZERO, DVec3::ZERO, &loss)?;
                    push(
                        format!("colliders.{}.velocity.{name}", c.name),
                        ad,
                        p,
                        m,
                        eps,
                    );
                }
            }
        }
    }
    if has("skill") {
        // Θ of skill-driven tools; ε is small enough that no phase's step count changes (a
        // change would be a jump the straight-through gradient does not see).
        let eps = 1e-7 * eps_scale;
        for (name, gt) in &scene.skill_gradients(&g.controls) {
            let i = scene
                .colliders
                .iter()
                .position(|c| &c.name == name)
                .expect("a tool of the scene");
            for (k, label) in ["depth", "scoop_angle", "lift", "transport", "pour"]
                .iter()
                .enumerate()
            {
                let edit = |d: f64| {
                    let mut s = scene.clone();
                    if let Some(crate::scene::ControlSpec::Skill(sk)) = &mut s.colliders[i].control
                    {
                        sk.theta[k] += d;
                    }
                    s
                };
                let p = forward_loss(&edit(eps), steps, threads, DVec3::ZERO, DVec3::ZERO, &loss)?;
                let m = forward_loss(&edit(-eps), steps, threads, DVec3::ZERO, DVec3::ZERO, &loss)?;
                push(
                    format!("colliders.{name}.theta[{k}] ({label})"),
                    gt[k],
                    p,
                    m,
                    eps,
                );
            }
        }
    }
    if has("gravity") {
        let eps = 1e-6 * eps_scale;
        let mut sp = scene.clone();
        sp.simulation.gravity.1 += eps;
        let mut sm = scene.clone();
        sm.simulation.gravity.1 -= eps;
        let p = forward_loss(&sp, steps, threads, DVec3::ZERO, DVec3::ZERO, &loss)?;
        let m = forward_loss(&sm, steps, threads, DVec3::ZERO, DVec3::ZERO, &loss)?;
        push("gravity.y".into(), g.gravity.y, p, m, eps);
    }
    // A row at a kink is checked against the nearest of its sides and their mean (and says so).
    let max_rel_error = rows
        .iter()
        .filter(|r| !r.noise_limited)
        .map(|r| r.one_sided_rel_error.unwrap_or(r.rel_error))
        .fold(0.0, f64::max);
    debug_assert!((g.loss - base).abs() <= 1e-12 * base.abs().max(1.0));
    Ok(Report {
        loss: g.loss,
        steps,
        target_m: target.to_array(),
        rows,
        max_rel_error,
        checkpoint_every: g.checkpoint_every,
        tape_bytes: g.tape_bytes,
        forward_s,
        forward_backward_s,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_smooth_loss_has_no_kink_and_a_kink_is_checked_against_its_sides() {
        let eps = 1e-6;
        // L = 3x + x² at x = 0.5: smooth, slope 4.
        let l = |x: f64| 3.0 * x + x * x;
        let r = compare("x".into(), 4.0, l(0.5), l(0.5 + eps), l(0.5 - eps), eps);
        assert!(!r.kink && r.rel_error < 1e-8, "{r:?}");
        // L = 10 + 2|x| − x at x = 0: slopes −3 and +1, central difference −1.
        let l = |x: f64| 10.0 + 2.0 * x.abs() - x;
        let r = compare("x".into(), 1.0, l(0.0), l(eps), l(-eps), eps);
        assert!(r.kink && (r.finite_difference + 1.0).abs() < 1e-6, "{r:?}");
        assert!(r.one_sided_rel_error.unwrap() < 1e-8 && r.rel_error > 1.0);
        // An adjoint that matches neither side still fails.
        let r = compare("x".into(), -7.0, l(0.0), l(eps), l(-eps), eps);
        assert!(r.one_sided_rel_error.unwrap() > 0.5);
    }
}
