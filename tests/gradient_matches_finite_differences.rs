//! End to end: adjoint gradients of `L = Σ_p ‖x_p(T) − t‖` against central differences in f64
//! on a small sand column collapsing on the domain floor (plasticity active), for the initial
//! velocities, E, ν and the friction angle. Also: checkpointed and full-tape runs give
//! bitwise identical gradients, and so do 1 and 2 threads.

use glam::DVec3;
use powderlab::adjoint::tape::{gradient, Gradients, Loss, Tape};
use powderlab::scene::Scene;

mod common;

const STEPS: usize = 8;

const SRC: &str = common::SAND_COLUMN;

fn target() -> DVec3 {
    DVec3::new(0.12, 0.0, 0.05)
}

fn run(scene: &Scene, threads: usize, tape: Tape) -> Gradients {
    let mut sim = common::build(scene, threads);
    gradient(&mut sim, STEPS, &Loss::SumDistance(target()), tape).unwrap()
}

fn loss(scene: &Scene) -> f64 {
    let mut sim = common::build(scene, 2);
    sim.run(STEPS, |_| {}).unwrap();
    let xs: Vec<Vec<DVec3>> = sim.body_states().into_iter().map(|b| b.x).collect();
    Loss::SumDistance(target()).eval(&xs).0
}

fn with_material(
    scene: &Scene,
    f: impl Fn(&mut powderlab::materials::drucker_prager::DruckerPrager),
) -> Scene {
    let mut s = scene.clone();
    if let Some(m) = s
        .materials
        .get_mut("sand")
        .and_then(|m| m.get_mut::<powderlab::materials::drucker_prager::DruckerPrager>())
    {
        f(m);
    }
    s
}

#[test]
fn adjoint_agrees_with_central_differences() {
    let scene = common::parse(SRC).unwrap();
    let g = run(&scene, 2, Tape::Budget(1 << 30));
    // Uniform shift of the initial x-velocity.
    let eps = 1e-6;
    let shift = |d: f64| {
        let mut s = scene.clone();
        s.bodies[0].velocity.0 += d;
        loss(&s)
    };
    let ad: f64 = g.v0[0].iter().map(|v| v.x).sum();
    common::check_fd(shift, eps, ad, "dL/d(shift v0.x)");
    common::check_fd(
        |d| loss(&with_material(&scene, |m| m.youngs_modulus += d)),
        1.0,
        g.material_gradient(0, "youngs_modulus").unwrap(),
        "dL/dE",
    );
    common::check_fd(
        |d| loss(&with_material(&scene, |m| m.poisson_ratio += d)),
        1e-6,
        g.material_gradient(0, "poisson_ratio").unwrap(),
        "dL/dnu",
    );
    common::check_fd(
        |d| loss(&with_material(&scene, |m| m.friction_deg += d)),
        1e-6,
        g.material_gradient(0, "friction_deg").unwrap(),
        "dL/dphi",
    );
}

#[test]
fn checkpointing_and_threads_do_not_change_the_gradient() {
    let scene = common::parse(SRC).unwrap();
    let full = run(&scene, 2, Tape::Every(STEPS));
    let tight = run(&scene, 2, Tape::Every(1));
    let budget = run(&scene, 2, Tape::Budget(1 << 30));
    assert_eq!(full.checkpoint_every, STEPS);
    assert_eq!(tight.checkpoint_every, 1);
    // A 1 GB budget holds the whole horizon: one segment, no recomputation of step states.
    assert_eq!(budget.checkpoint_every, STEPS);
    assert_eq!(full.v0, budget.v0);
    assert_eq!(full.v0, tight.v0);
    assert_eq!(full.x0, tight.x0);
    assert_eq!(full.material, tight.material);
    let one = run(&scene, 1, Tape::Budget(1 << 30));
    assert_eq!(full.v0, one.v0);
    assert_eq!(full.material, one.material);
}

#[test]
fn a_budget_below_the_smallest_tape_is_refused() {
    let scene = common::parse(SRC).unwrap();
    let mut sim = common::build(&scene, 1);
    let err = gradient(
        &mut sim,
        STEPS,
        &Loss::SumDistance(target()),
        Tape::Budget(1000),
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("memory budget of 1000 bytes")
            && err.contains("raise --budget-mb to at least"),
        "{err}"
    );
    assert!(!err.contains("cannot be differentiated"), "{err}");
}

#[test]
fn hardening_is_refused_not_silently_wrong() {
    let src = SRC.replace(
        "friction_deg: 30.0))",
        "friction_deg: 30.0, hardening: Some((35.0, 9.0, 0.2, 10.0))))",
    );
    let mut sim = common::build(&common::parse(&src).unwrap(), 1);
    let err = gradient(&mut sim, 1, &Loss::MeanL1(target()), Tape::Budget(1 << 30))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("cannot be differentiated yet") && err.contains("hardening"),
        "{err}"
    );
}

/// A box tool sweeping through the sand (the sand_box motion in miniature): the gradient with
/// respect to the tool's velocity and start position. Central differences through contact
/// need a small step in f64 (shared/reference/RESULTS.md): with ε = 1e-7 no grid node crosses
/// the contact band within the horizon. The start digits matter: from (0.0312345, 0.0612345,
/// 0.0551234) a node sits within 1e-8 of the band edge, and there the forward difference equals
/// the adjoint to 7 digits while the backward one jumps (the one-sided kink the docs describe).
#[test]
fn gradient_through_a_moving_tool() {
    let src = SRC.replace(
        "velocity: (0.2, 0.0, 0.0))],",
        "velocity: (0.0, 0.0, 0.0))],\n    colliders: [(name: \"paddle\", kind: Tool, shape: Box(half_extents: (0.01, 0.015, 0.02)),\n                 position: (0.0313579, 0.0617531, 0.0552468), friction: 0.0, particle_contact: false,\n                 control: Constant(linear: (0.8, 0.05, 0.1), steps: 8))],",
    );
    let scene = common::parse(&src).unwrap();
    let g = run(&scene, 2, Tape::Budget(1 << 30));
    let dt = scene.simulation.dt;
    let eps = 1e-7;
    let with_v = |k: usize, d: f64| {
        let mut s = scene.clone();
        if let Some(powderlab::scene::ControlSpec::Constant { linear, .. }) =
            &mut s.colliders[0].control
        {
            match k {
                0 => linear.0 += d,
                1 => linear.1 += d,
                _ => linear.2 += d,
            }
        }
        loss(&s)
    };
    let with_x = |k: usize, d: f64| {
        let mut s = scene.clone();
        let p = &mut s.colliders[0].position;
        match k {
            0 => p.0 += d,
            1 => p.1 += d,
            _ => p.2 += d,
        }
        loss(&s)
    };
    for k in 0..3 {
        let ad: f64 = g.controls[0].1.iter().map(|u| u[k] * dt).sum();
        common::check_fd(
            |d| with_v(k, d),
            eps,
            ad,
            &format!("dL/d(tool velocity)[{k}]"),
        );
        common::check_fd(
            |d| with_x(k, d),
            eps,
            g.tool_start[0].1[k],
            &format!("dL/d(tool start)[{k}]"),
        );
    }
}

/// The same sand on a rough floor (a static Plane container, friction 0.4): the friction
/// gradient and the initial-velocity gradient through frictional contact.
#[test]
fn gradient_through_a_frictional_floor() {
    let src = SRC
        .replace("Box(min: (0.05, 0.03, 0.04), max: (0.08, 0.09, 0.07))", "Box(min: (0.05, 0.05, 0.04), max: (0.08, 0.09, 0.07))")
        .replace(
            "velocity: (0.2, 0.0, 0.0))],",
            "velocity: (0.2, 0.0, 0.0))],\n    colliders: [(name: \"floor\", kind: Container, shape: Plane(normal: (0.0, 1.0, 0.0)),\n                 position: (0.0, 0.045, 0.0), friction: 0.4, particle_contact: false)],",
        );
    let scene = common::parse(&src).unwrap();
    assert_eq!(scene.colliders.len(), 1);
    let g = run(&scene, 2, Tape::Budget(1 << 30));
    // The loss's round-off is about 4e-14, so a step of 1e-6 leaves the difference 4e-8 of
    // noise, above the check's floor: dL/dmu's central differences at 1e-4 … 1e-7 were
    // 2.524467, 2.5244403538, 2.5244403524, 2.5244403468, 2.5244403137, 2.5244404434 against
    // the adjoint's 2.5244403535, so the step is 1e-5, where truncation and round-off are both
    // below 1e-9.
    let eps = 1e-5;
    let with_mu = |d: f64| {
        let mut s = scene.clone();
        s.colliders[0].friction += d;
        loss(&s)
    };
    common::check_fd(with_mu, eps, g.friction[0].1, "dL/dmu(floor)");
    let shift = |d: f64| {
        let mut s = scene.clone();
        s.bodies[0].velocity.0 += d;
        loss(&s)
    };
    let ad: f64 = g.v0[0].iter().map(|v| v.x).sum();
    common::check_fd(shift, eps, ad, "dL/d(shift v0.x) with floor friction");
}

/// Sand poured into a thin-walled cup (2 mm wall on a 1 cm grid: particle collision keeps it
/// in): gradients through the particle-collision adjoint, for the initial velocity and the
/// cup's friction.
#[test]
fn gradient_through_thin_wall_particle_collision() {
    let src = SRC.replace(
        "velocity: (0.2, 0.0, 0.0))],",
        "velocity: (0.3, -0.2, 0.1))],\n    colliders: [(name: \"cup\", kind: Container,\n                 shape: Cup(outer_radius: 0.045, height: 0.06, wall_thickness: 0.002, floor_thickness: 0.002),\n                 position: (0.0812345, 0.0101234, 0.0601234), friction: 0.3, particle_contact: true)],",
    );
    let src = src.replace(
        "Box(min: (0.05, 0.03, 0.04), max: (0.08, 0.09, 0.07))",
        "Box(min: (0.06, 0.04, 0.05), max: (0.09, 0.1, 0.08))",
    );
    let scene = common::parse(&src).unwrap();
    let g = run(&scene, 2, Tape::Budget(1 << 30));
    let eps = 1e-7;
    let shift = |k: usize, d: f64| {
        let mut s = scene.clone();
        match k {
            0 => s.bodies[0].velocity.0 += d,
            1 => s.bodies[0].velocity.1 += d,
            _ => s.bodies[0].velocity.2 += d,
        }
        loss(&s)
    };
    for k in 0..3 {
        let ad: f64 = g.v0[0].iter().map(|v| v[k]).sum();
        common::check_fd(
            |d| shift(k, d),
            eps,
            ad,
            &format!("dL/d(shift v0)[{k}] with a thin-walled cup"),
        );
    }
    let with_mu = |d: f64| {
        let mut s = scene.clone();
        s.colliders[0].friction += d;
        loss(&s)
    };
    // At 1e-7 the differences at h and h/2 are both round-off and happened to agree to ten
    // digits, which hid their error; ε^(1/3) ≈ 6e-6 balances truncation and round-off.
    common::check_fd(with_mu, 1e-6, g.friction[0].1, "dL/dmu(cup)");
}

/// A box paddle translating and spinning through the sand: gradients with respect to its
/// linear and angular velocity (the rotation-vector exponential and its left Jacobian).
#[test]
fn gradient_through_a_rotating_tool() {
    let src = SRC.replace(
        "velocity: (0.2, 0.0, 0.0))],",
        "velocity: (0.0, 0.0, 0.0))],\n    colliders: [(name: \"paddle\", kind: Tool, shape: Box(half_extents: (0.01, 0.015, 0.02)),\n                 position: (0.0313579, 0.0617531, 0.0552468), friction: 0.2, particle_contact: false,\n                 control: Constant(linear: (0.6, 0.05, 0.1), angular: (0.3, 1.2, -0.8), steps: 8))],",
    );
    let scene = common::parse(&src).unwrap();
    let g = run(&scene, 2, Tape::Budget(1 << 30));
    let dt = scene.simulation.dt;
    let eps = 1e-7;
    let edit = |k: usize, d: f64| {
        let mut s = scene.clone();
        if let Some(powderlab::scene::ControlSpec::Constant {
            linear, angular, ..
        }) = &mut s.colliders[0].control
        {
            let v = if k < 3 { linear } else { angular };
            match k % 3 {
                0 => v.0 += d,
                1 => v.1 += d,
                _ => v.2 += d,
            }
        }
        loss(&s)
    };
    for k in 0..6 {
        let ad: f64 = g.controls[0].1.iter().map(|u| u[k] * dt).sum();
        let what = if k < 3 {
            format!("dL/d(linear)[{k}]")
        } else {
            format!("dL/d(angular)[{}]", k - 3)
        };
        common::check_fd(|d| edit(k, d), eps, ad, &what);
    }
}
