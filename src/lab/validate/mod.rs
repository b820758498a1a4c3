//! Validation against exact solutions and published experiments (`shared/validation`).
//!
//! Cases:
//! - `free_fall`: exact, `x = x₀ + v₀t + ½g·t(t + Δt_sub)` and `v = v₀ + g·t` (symplectic Euler);
//! - `column_collapse`: planar granular column collapse, run-out against Lube et al. 2005
//!   (`ΔL/L₀ ≈ 1.2a` for small `a`, `≈ 1.9a^(2/3)` for large `a`), log–log slopes per band,
//!   the arrest time in units of `T_c = √(H₀/g)`, and the scale invariance of the deposit
//!   ([`scale_invariance`]);
//! - `axisymmetric_collapse`: a quarter cylinder's collapse, run-out against Lube et al. 2004
//!   (`(R∞ − R₀)/R₀ ≈ 1.24a` for `a ≲ 1.7`, `≈ 1.6a^½` above), [`axisym`];
//! - `bar`: the fixed–free vibrating elastic bar (period and energy drift), [`bar`];
//! - `self_weight`: the self-weight column (base stress and its convergence order), [`column`];
//! - `incline`: a block on an incline below and above its friction angle, [`incline`];
//! - `pile_angle`: the flank angle of a pile at rest against the plane-strain friction angle,
//!   [`pile`];
//! - `rankine`: the critical height of a cohesive vertical cut against Rankine's, [`rankine`];
//! - `repose`: the angle of repose of a lifted-cylinder heap against cohesion at two friction
//!   angles, [`repose`];
//! - `stability`: stiff and extreme cases, each stable or refused, never NaN, [`stability`].

pub mod axisym;
pub mod bar;
pub mod collapse;
pub mod column;
pub mod incline;
pub mod pile;
pub mod rankine;
pub mod repose;
pub mod rheology;
pub mod silo;
pub mod stability;
pub mod suite;

use crate::scene::Scene;
use crate::sim::{SimOptions, Simulation};
use glam::DVec3;
use serde::Serialize;
use std::path::Path;

/// One checked quantity.
#[derive(Clone, Debug, Serialize)]
pub struct Check {
    pub case: String,
    pub quantity: String,
    pub measured: f64,
    pub published: f64,
    /// Meaning depends on `kind`: relative error bound, absolute band half-width, or factor.
    pub tolerance: f64,
    pub kind: &'static str,
    pub passed: bool,
    pub note: String,
}

impl Check {
    /// A check of `measured` against `published` with a relative tolerance.
    pub fn relative(
        case: &str,
        quantity: String,
        measured: f64,
        published: f64,
        tol: f64,
    ) -> Check {
        let rel = (measured - published).abs() / published.abs();
        Check {
            case: case.into(),
            quantity,
            measured,
            published,
            tolerance: tol,
            kind: "rel<=tol",
            passed: rel <= tol,
            note: format!("relative error {rel:.2e}"),
        }
    }

    /// A check that `measured` is at most `bound`.
    pub fn at_most(
        case: &str,
        quantity: String,
        measured: f64,
        published: f64,
        bound: f64,
    ) -> Check {
        Check {
            case: case.into(),
            quantity,
            measured,
            published,
            tolerance: bound,
            kind: "abs<=tol",
            passed: measured.abs() <= bound,
            note: String::new(),
        }
    }

    pub fn with_note(mut self, note: String) -> Check {
        self.note = if self.note.is_empty() {
            note
        } else {
            format!("{}; {note}", self.note)
        };
        self
    }
}

/// A C¹ ramp from 0 at `t = 0` to 1 at `t = t_ramp`: `½(1 − cos(πt/t_ramp))`. Loading a body this
/// slowly (over several of its elastic periods) brings it to rest with little ringing, where a
/// sudden load would leave it ringing about the rest state with the full static amplitude.
pub fn smooth_ramp(t: f64, t_ramp: f64) -> f64 {
    if t >= t_ramp {
        1.0
    } else {
        0.5 * (1.0 - (std::f64::consts::PI * t / t_ramp).cos())
    }
}

/// Reads the positions and velocities of the scene's first body in place: the per-step
/// measurements of the validation cases, which [`Simulation::body_states`] would copy whole
/// (with `C` and `F`) at every step.
pub fn read_body<R>(sim: &mut Simulation, f: impl FnOnce(&[DVec3], &[DVec3]) -> R) -> R {
    let mut q = sim.world.query::<(
        &crate::components::Body,
        &crate::components::Position,
        &crate::components::Velocity,
    )>();
    let (_, x, v) = q
        .iter(&sim.world)
        .min_by_key(|b| b.0.index)
        .expect("the scene has a body");
    f(&x.0, &v.0)
}

/// Mean x of the first body's particles (m).
pub fn mean_x(sim: &mut Simulation) -> f64 {
    read_body(sim, |x, _| {
        x.iter().map(|p| p.x).sum::<f64>() / x.len() as f64
    })
}

/// Sets every particle's velocity from its position.
pub fn set_velocity(sim: &mut Simulation, f: impl Fn(DVec3) -> DVec3) {
    let mut q = sim.world.query::<(
        &crate::components::Position,
        &mut crate::components::Velocity,
    )>();
    for (x, mut v) in q.iter_mut(&mut sim.world) {
        for (x, v) in x.0.iter().zip(v.0.iter_mut()) {
            *v = f(*x);
        }
    }
}

/// Parses a validation scene (named `<validate:name>` in errors) and builds its simulation.
pub(crate) fn build(
    src: &str,
    name: &str,
    threads: Option<usize>,
) -> anyhow::Result<(Scene, Simulation)> {
    let scene = Scene::parse(src, Path::new(&format!("<validate:{name}>")))?;
    let sim = Simulation::new(&scene, &SimOptions::threads(threads))?;
    Ok((scene, sim))
}

/// Relative tolerance of the free-fall check in f64: the grid transfer sums 27 weights per
/// node and per particle, so round-off is a few hundred ulps of the displacement at most.
pub const FREE_FALL_REL_TOL: f64 = 1e-12;

/// Free fall of an elastic block: the largest relative position and velocity errors.
pub fn free_fall(threads: Option<usize>) -> anyhow::Result<Vec<Check>> {
    // The shipped scene, so that `validate free_fall` and `simulate scenes/free_fall.ron` run
    // the same block. It leaves empty_node_ratio at its default, 0: every node touched by a
    // particle is used, so the partition of unity is exact. A threshold of 1e-6 drops the nodes
    // of tiny weight and gives a position error of 2.2e-8 relative here, so this check also
    // guards the default.
    let src = crate::scene::shipped::text("free_fall").expect("free_fall is a shipped scene");
    let (scene, mut sim) = build(src, "free_fall", threads)?;
    let x0 = sim.body_states()[0].x.clone();
    let v0 = DVec3::from(scene.bodies[0].velocity);
    let g = DVec3::from(scene.simulation.gravity);
    sim.run(sim.horizon, |_| {})?;
    let p = sim.params().clone();
    let t = sim.horizon as f64 * p.dt;
    let st = &sim.body_states()[0];
    let disp = v0 * t + 0.5 * g * t * (t + p.dt_sub);
    let v_exact = v0 + g * t;
    let mut ex: f64 = 0.0;
    let mut ev: f64 = 0.0;
    for (k, x) in st.x.iter().enumerate() {
        ex = ex.max((*x - (x0[k] + disp)).length() / disp.length());
        ev = ev.max((st.v[k] - v_exact).length() / v_exact.length());
    }
    Ok(vec![
        Check::at_most(
            "free_fall",
            "max relative position error".into(),
            ex,
            0.0,
            FREE_FALL_REL_TOL,
        )
        .with_note(format!(
            "{} particles, {} substeps, exact law x0 + v0 t + g t (t + dt)/2",
            st.x.len(),
            sim.clock().total_substeps
        )),
        Check::at_most(
            "free_fall",
            "max relative velocity error".into(),
            ev,
            0.0,
            FREE_FALL_REL_TOL,
        )
        .with_note("v = v0 + g t".into()),
    ])
}

pub use collapse::*;
pub use rheology::Rheology;

#[cfg(test)]
mod tests;
