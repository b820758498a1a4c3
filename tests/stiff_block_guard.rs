//! Stiff block (E = 1e7 Pa): `stability: Auto` raises the substeps and runs stable; `Strict`
//! refuses with the numbers. Neither ends in a NaN.

use powderlab::scene::Stability;
use powderlab::sim::{SimOptions, Simulation};

mod common;

#[test]
fn auto_raises_substeps_and_stays_finite() {
    let mut scene = common::load("stiff_block.ron");
    scene.simulation.steps = Some(3);
    let mut sim = common::build(&scene, 2);
    let s = sim.stability.clone();
    println!("{s:?}");
    assert!(s.raised());
    assert_eq!(s.substeps_requested, 20);
    assert!(
        s.substeps > 400,
        "E = 1e7 at dx = 5 mm needs > 400 substeps, got {}",
        s.substeps
    );
    assert!(sim.params().dt_sub <= s.dt_max);
    sim.run(3, |_| {}).unwrap();
    common::assert_finite(&mut sim);
    // The block rests on the floor at y = 0.02 and does not fly apart.
    let st = sim.body_states();
    assert!(st[0].x.iter().all(|x| x.y > 0.015 && x.y < 0.08));
}

#[test]
fn strict_refuses_with_the_numbers() {
    let mut scene = common::load("stiff_block.ron");
    scene.simulation.stability = Stability::Strict;
    let err = Simulation::new(&scene, &SimOptions::default())
        .err()
        .expect("strict must refuse");
    let msg = err.to_string();
    println!("{msg}");
    assert!(msg.contains("stiff_block.ron"), "{msg}");
    assert!(msg.contains("unstable time step"), "{msg}");
    assert!(msg.contains("5.000e-4"), "names the substep: {msg}");
    assert!(
        msg.contains("wave speed 110.6"),
        "names the wave speed: {msg}"
    );
    assert!(
        msg.contains("at least 443"),
        "names the substeps needed: {msg}"
    );
}
