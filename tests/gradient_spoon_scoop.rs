//! End to end through the spoon: a few hundred particles in a thin-walled cup, a spoon that
//! descends into them and starts its scoop (rotation included), 20 steps. The gradients with
//! respect to the skill parameters and the material agree with central differences in f64.

use glam::DVec3;
use powderlab::adjoint::tape::{gradient, Loss, Tape};
use powderlab::scene::{ControlSpec, Scene};

mod common;

const STEPS: usize = 20;

fn target() -> DVec3 {
    DVec3::new(0.1, 0.0, 0.06)
}

fn loss(scene: &Scene) -> f64 {
    let mut sim = common::build(scene, 2);
    sim.run(STEPS, |_| {}).unwrap();
    let xs: Vec<Vec<DVec3>> = sim.body_states().into_iter().map(|b| b.x).collect();
    Loss::SumDistance(target()).eval(&xs).0
}

#[test]
fn skill_and_material_gradients_through_the_spoon() {
    let scene = common::load_test_scene("spoon_scoop.ron");
    let mut sim = common::build(&scene, 2);
    let n = sim.particle_count();
    assert!((100..1000).contains(&n), "a few hundred particles: {n}");
    let g = gradient(
        &mut sim,
        STEPS,
        &Loss::SumDistance(target()),
        Tape::Budget(1 << 30),
    )
    .unwrap();
    // The spoon must be in contact with the powder, or the check proves nothing.
    let spoon_g = &g.controls[0].1;
    assert!(
        spoon_g
            .iter()
            .take(STEPS)
            .any(|u| u.iter().any(|x| x.abs() > 0.0)),
        "no gradient reaches the spoon"
    );
    // The loss (a sum over a few hundred particles) carries about 2.5e-14 of round-off, which
    // a step of 1e-7 turns into 2.5e-7 of the difference, 3e-4 of dL/dtheta[1]: its central
    // differences at 1e-5, 3e-6, 1e-6, 3e-7, 1e-7, 1e-8 were −9.10788, −9.10785, −9.10743,
    // −9.10756, −9.11031, −9.08518 (·1e-4) against the adjoint's −9.10780. 3e-6 keeps both
    // truncation and round-off near 1e-5 of it.
    let eps = 3e-6;
    for k in 0..2 {
        let edit = |d: f64| {
            let mut s = scene.clone();
            if let Some(ControlSpec::Skill(sk)) = &mut s.colliders[1].control {
                sk.theta[k] += d;
            }
            loss(&s)
        };
        common::check_fd(
            edit,
            eps,
            scene.skill_gradients(&g.controls)[0].1[k],
            &format!("dL/dtheta[{k}]"),
        );
    }
    let mat = |f: &dyn Fn(&mut powderlab::materials::drucker_prager::DruckerPrager)| {
        let mut s = scene.clone();
        if let Some(m) = s
            .materials
            .get_mut("powder")
            .and_then(|m| m.get_mut::<powderlab::materials::drucker_prager::DruckerPrager>())
        {
            f(m);
        }
        loss(&s)
    };
    common::check_fd(
        |d| mat(&|m| m.youngs_modulus += d),
        4e-3,
        g.material_gradient(0, "youngs_modulus").unwrap(),
        "dL/dE",
    );
    common::check_fd(
        |d| mat(&|m| m.friction_deg += d),
        1e-6,
        g.material_gradient(0, "friction_deg").unwrap(),
        "dL/dphi",
    );
}
