//! End to end through the spoon: a few hundred particles in a thin-walled cup, a spoon that
//! descends into them and starts its scoop (rotation included), 20 steps. The gradients with
//! respect to the skill parameters and the material agree with central differences in f64.

use glam::DVec3;
use powderlab::adjoint::tape::{gradient, Loss, Tape};
use powderlab::scene::{ControlSpec, Scene};

mod common;

/// Issue acceptance: 1e-3 in f64 away from contact switches.
const E2E_REL_TOL: f64 = 1e-3;
const STEPS: usize = 20;

const SRC: &str = r#"Scene(
    simulation: (cells: (24, 22, 30), dx: 0.005, dt: 0.01, substeps: 10, stability: Auto, seed: 3),
    materials: { "powder": DruckerPrager((youngs_modulus: 4e3, friction_deg: 30.0)) },
    bodies: [(name: "powder", material: "powder", fill: InsideContainer(container: "cup", height: 0.015),
              particles_per_cell: 1, lattice: Jittered(0.3))],
    colliders: [
        (name: "cup", kind: Container,
         shape: Cup(outer_radius: 0.03, height: 0.04, wall_thickness: 0.002, floor_thickness: 0.003),
         position: (0.0601234, 0.0150321, 0.0598765), friction: 0.4),
        (name: "spoon", kind: Tool,
         shape: Spoon(bowl_radius: 0.012, bowl_depth: 0.007, thickness: 0.0015,
                      handle_length: 0.03, handle_radius: 0.002, handle_rise: 0.06),
         position: (0.0603456, 0.0521234, 0.0587654), rotation_deg: (0.0, -90.0, 0.0), friction: 0.3,
         control: Skill((
             theta: (0.31, 0.27, 0.0, 0.0, 0.0),
             ranges: (scoop_depth: (0.004, 0.012), scoop_angle_deg: (10.0, 40.0), lift_height: (0.02, 0.04),
                      transport_distance: (0.05, 0.08), pour_angle_deg: (60.0, 120.0)),
             linear_speed: 0.3, angular_speed_deg: 300.0, scoop_stroke: 0.004, surface_height: 0.0333,
             settle_steps: 5,
         ))),
    ],
)"#;

fn target() -> DVec3 {
    DVec3::new(0.1, 0.0, 0.06)
}

fn loss(scene: &Scene) -> f64 {
    let mut sim = common::build(scene, 2);
    sim.run(STEPS, |_| {}).unwrap();
    let xs: Vec<Vec<DVec3>> = sim.body_states().into_iter().map(|b| b.x).collect();
    Loss::SumDistance(target()).eval(&xs).0
}

fn close(fd: f64, ad: f64, what: &str) {
    let rel = (fd - ad).abs() / fd.abs().max(ad.abs()).max(1e-12);
    println!("{what}: adjoint {ad:.9e}, central difference {fd:.9e}, relative error {rel:.2e}");
    assert!(rel <= E2E_REL_TOL, "{what}: {rel}");
}

#[test]
fn skill_and_material_gradients_through_the_spoon() {
    let scene = common::parse(SRC).unwrap();
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
    let eps = 1e-7;
    for k in 0..2 {
        let edit = |d: f64| {
            let mut s = scene.clone();
            if let Some(ControlSpec::Skill(sk)) = &mut s.colliders[1].control {
                sk.theta[k] += d;
            }
            loss(&s)
        };
        close(
            (edit(eps) - edit(-eps)) / (2.0 * eps),
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
    let h = 4e-3;
    close(
        (mat(&|m| m.youngs_modulus += h) - mat(&|m| m.youngs_modulus -= h)) / (2.0 * h),
        g.material_gradient(0, "youngs_modulus").unwrap(),
        "dL/dE",
    );
    let h = 1e-6;
    close(
        (mat(&|m| m.friction_deg += h) - mat(&|m| m.friction_deg -= h)) / (2.0 * h),
        g.material_gradient(0, "friction_deg").unwrap(),
        "dL/dphi",
    );
}
