//! No particle is ever inside a wall: in every frame of `powder_transport` (1.5 mm spoon bowl,
//! 2 mm cup walls), at the default resolution (dx = 5 mm), a coarser one (dx = 6.25 mm) and the
//! fine scene's (dx = 2.5 mm), every particle has φ ≥ 0 against every collider.

use powderlab::components::{Collider, ColliderPose, Position};

mod common;

fn min_clearance(sim: &mut powderlab::sim::Simulation) -> (f64, String) {
    let cs: Vec<(Collider, ColliderPose)> = sim
        .world
        .query::<(&Collider, &ColliderPose)>()
        .iter(&sim.world)
        .map(|(c, p)| (c.clone(), *p))
        .collect();
    let mut worst = (f64::INFINITY, String::new());
    for x in sim.world.query::<&Position>().iter(&sim.world) {
        for p in &x.0 {
            for (c, pose) in &cs {
                let phi = pose.sdf(&c.shape, *p).0;
                if phi < worst.0 {
                    worst = (phi, c.name.clone());
                }
            }
        }
    }
    worst
}

/// `scene` rescaled to cell size `dx` (the same domain and geometry; contact bands stay in
/// cells).
fn check(file: &str, dx: f64) {
    let mut scene = common::load(file);
    let scale = scene.simulation.dx / dx;
    let c = scene.simulation.cells;
    scene.simulation.dx = dx;
    scene.simulation.cells = (
        (c.0 as f64 * scale).ceil() as usize,
        (c.1 as f64 * scale).ceil() as usize,
        (c.2 as f64 * scale).ceil() as usize,
    );
    let mut sim = common::build(&scene, 2);
    let mut transported_any = false;
    for step in 0..sim.horizon {
        sim.step().unwrap();
        let (phi, name) = min_clearance(&mut sim);
        assert!(
            phi >= 0.0,
            "dx {dx}: step {step}: a particle is {:.3e} m inside '{name}'",
            -phi
        );
        if step == sim.horizon - 1 {
            let m = powderlab::metrics::frame_metrics(&mut sim.world, Some("target_cup"));
            transported_any = m.transported > 0;
            println!(
                "dx {dx}: {} particles, {} transported, min clearance {phi:.2e} m",
                m.particles, m.transported
            );
        }
    }
    assert!(
        transported_any,
        "the spoon must carry powder through the test, or it proves nothing"
    );
}

#[test]
fn no_leaks_at_default_resolution() {
    check("powder_transport.ron", 0.005);
}

#[test]
fn no_leaks_at_a_coarser_resolution() {
    check("powder_transport.ron", 0.00625);
}

#[test]
fn no_leaks_at_the_fine_resolution() {
    check("powder_transport_fine.ron", 0.0025);
}
