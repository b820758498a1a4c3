//! Closed form: in free fall, momentum conservation of the P2G/G2P transfers makes the mean
//! position exactly `x̄(t) = x̄₀ + v̄₀·t + ½g·t(t + Δt)`, so for `L = Σ_p w·x_p(T)` every particle
//! has `∂L/∂v_p(0) = t·w` and `∂L/∂x_p(0) = w`, i.e. `∂x̄_T/∂v̄₀ = T·Δt·I`.

use glam::DVec3;
use powderlab::adjoint::tape::{gradient, Loss, Tape};

mod common;

/// Round-off of ~10³ substeps of 27-node transfers in f64.
const REL_TOL: f64 = 1e-10;

#[test]
fn free_fall_gradient_is_t_times_identity() {
    let scene = common::load("free_fall.ron");
    let mut sim = common::build(&scene, 2);
    let n = sim.particle_count();
    let w = DVec3::new(0.3, -1.1, 0.7);
    let steps = 5;
    let g = gradient(
        &mut sim,
        steps,
        &Loss::Linear(vec![vec![w; n]]),
        Tape::Budget(1 << 30),
    )
    .unwrap();
    let t = steps as f64 * sim.params().dt;
    let mut worst_v: f64 = 0.0;
    let mut worst_x: f64 = 0.0;
    for (gv, gx) in g.v0[0].iter().zip(&g.x0[0]) {
        worst_v = worst_v.max((*gv - w * t).length() / (w * t).length());
        worst_x = worst_x.max((*gx - w).length() / w.length());
    }
    println!(
        "max relative error: dL/dv0 {worst_v:.2e}, dL/dx0 {worst_x:.2e}; dL/dg {:?}",
        g.gravity
    );
    assert!(worst_v <= REL_TOL, "dL/dv0: {worst_v}");
    assert!(worst_x <= REL_TOL, "dL/dx0: {worst_x}");
    // x̄ depends on g through ½·t(t + Δt_sub) per particle.
    let dt_sub = sim.params().dt_sub;
    let expect = w * (n as f64 * 0.5 * t * (t + dt_sub));
    assert!(
        (g.gravity - expect).length() <= REL_TOL * expect.length(),
        "{:?} vs {expect:?}",
        g.gravity
    );
}

/// A non-finite adjoint stops the backward pass naming the step, substep, stage and field.
#[test]
fn a_non_finite_adjoint_is_an_error_not_a_gradient() {
    let mut sim = common::build(&common::load("free_fall.ron"), 1);
    let n = sim.particle_count();
    let mut w = vec![DVec3::ZERO; n];
    w[17] = DVec3::new(f64::NAN, 0.0, 0.0);
    let err = gradient(&mut sim, 2, &Loss::Linear(vec![w]), Tape::Budget(1 << 30))
        .unwrap_err()
        .to_string();
    println!("{err}");
    assert!(err.contains("step 1, substep 9"), "{err}");
    assert!(err.contains("stage 'advect'"), "{err}");
    assert!(
        err.contains("'x adjoint'") && err.contains("index 17"),
        "{err}"
    );
}
