//! The carry loss (a tool's soft carried mass at a step of the rollout, `adjoint::loss::Carry`)
//! end to end through the spoon: its gradient with respect to the skill parameters agrees with
//! central differences in f64, for a term in mid-rollout and one on the final state, with no
//! final-state loss beside them.

use glam::DVec3;
use powderlab::adjoint::tape::{gradient_with, Carry, Loss, Tape, Term};
use powderlab::scene::{ControlSpec, Scene};

mod common;

const STEPS: usize = 20;
/// Central-difference step on Θ (that of `gradient_spoon_scoop.rs`: small enough to stay
/// between contact switches, large enough above f64 round-off).
const EPS: f64 = 1e-7;

fn terms(scene: &Scene) -> Vec<Carry> {
    let masses = scene.particle_masses();
    // The bowl's sphere (radius 12 mm), a ramp 4 mm wide (about a particle spacing), and a
    // target the spoon does not meet, so that the terms' gradients are not zero.
    [(12, 0.35, 1.0), (STEPS, 0.2, 0.6)]
        .iter()
        .map(|&(step, target_g, weight)| Carry {
            tool: "spoon".into(),
            step,
            // 3 mm off the sphere's centre, so that the spoon's turn moves the ball too and
            // the rotation's share of the pose gradient is checked.
            centre: DVec3::new(0.0, 0.003, 0.0),
            radius: 0.012,
            width: 0.004,
            particle_mass: masses.clone(),
            target_mass: target_g * 1e-3,
            weight,
        })
        .collect()
}

fn as_terms(carry: &[Carry]) -> Vec<Term> {
    carry.iter().cloned().map(Term::Carry).collect()
}

/// Nothing on the final positions: the carry terms alone.
fn no_final_loss(scene: &Scene) -> Loss {
    let mut sim = common::build(scene, 1);
    Loss::Linear(
        sim.body_states()
            .iter()
            .map(|b| vec![DVec3::ZERO; b.x.len()])
            .collect(),
    )
}

/// The forward value of the terms (the tape's forward, with its gradient unused).
fn value(scene: &Scene) -> f64 {
    let mut sim = common::build(scene, 2);
    let loss = no_final_loss(scene);
    gradient_with(
        &mut sim,
        STEPS,
        &loss,
        &as_terms(&terms(scene)),
        Tape::Every(STEPS),
    )
    .unwrap()
    .loss
}

#[test]
fn carry_loss_gradient_through_the_spoon_matches_central_differences() {
    let scene = common::load_test_scene("spoon_scoop.ron");
    let mut sim = common::build(&scene, 2);
    let loss = no_final_loss(&scene);
    let ts = terms(&scene);
    let g = gradient_with(
        &mut sim,
        STEPS,
        &loss,
        &as_terms(&ts),
        Tape::Budget(1 << 30),
    )
    .unwrap();
    assert!(g.loss > 0.0, "the terms must be away from their targets");
    // The same value from a plain forward evaluation of the terms (the spoon's pose and the
    // positions at the term's step, not a step off).
    let mut fwd = common::build(&scene, 2);
    let mut by_hand = 0.0;
    for s in 0..=STEPS {
        for t in ts.iter().filter(|t| t.step == s) {
            let xs: Vec<Vec<DVec3>> = fwd.body_states().into_iter().map(|b| b.x).collect();
            let pose = fwd
                .collider_poses()
                .into_iter()
                .find(|c| c.0 == "spoon")
                .expect("the spoon")
                .3;
            by_hand += t.eval(&xs, &pose).value;
        }
        if s < STEPS {
            fwd.step().unwrap();
        }
    }
    assert!(
        (by_hand - g.loss).abs() <= 1e-12 * by_hand.abs(),
        "{by_hand} against {}",
        g.loss
    );
    let theta_g = scene.skill_gradients(&g.controls)[0].1;
    assert!(
        theta_g.iter().any(|x| x.abs() > 0.0),
        "no gradient reaches Θ"
    );
    for (k, &ad) in theta_g.iter().enumerate().take(3) {
        let edit = |d: f64| {
            let mut s = scene.clone();
            if let Some(ControlSpec::Skill(sk)) = &mut s.colliders[1].control {
                sk.theta[k] += d;
            }
            value(&s)
        };
        common::check_fd(edit, EPS, ad, &format!("dL/dtheta[{k}]"));
    }
}
