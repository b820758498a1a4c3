//! How still the weighing vial's powder rests once the spatula has left it: the largest and
//! mean speed of the grains in the vial, and the largest displacement since step 150, every
//! 10 steps of the scene's own skill (scoop, carry over the boat, tip) and after it. The creep
//! this shows is what `sim::rest` leaves out when it sets resting powder aside.
//!
//! ```sh
//! cargo run --release --example rest_creep
//! ```

use powderlab::scene::Scene;
use powderlab::sim::{SimOptions, Simulation};

fn main() -> anyhow::Result<()> {
    let scene = Scene::load("scenes/vial_weighing.ron")?;
    let mut sim = Simulation::new(&scene, &SimOptions::threads(Some(2)))?;
    // The vial's cavity: within its inner radius of its axis.
    let vial = scene
        .colliders
        .iter()
        .find(|c| c.name == "vial")
        .expect("a vial");
    let (cx, cz) = (vial.position.0, vial.position.2);
    let mut start: Option<Vec<glam::DVec3>> = None;
    for k in 1..=260 {
        sim.step()?;
        if k % 10 != 0 {
            continue;
        }
        let b = &sim.body_states()[0];
        let inside: Vec<usize> = (0..b.x.len())
            .filter(|&i| (b.x[i].x - cx).hypot(b.x[i].z - cz) < 0.0115)
            .collect();
        let speed = |i: &usize| b.v[*i].length();
        let vmax = inside.iter().map(speed).fold(0.0, f64::max);
        let vmean = inside.iter().map(speed).sum::<f64>() / inside.len() as f64;
        if k == 150 {
            start = Some(b.x.clone());
        }
        let moved = start.as_ref().map_or(0.0, |s| {
            inside
                .iter()
                .map(|&i| (b.x[i] - s[i]).length())
                .fold(0.0, f64::max)
        });
        println!(
            "step {k:3}: {} grains in the vial, speed max {vmax:.2e} mean {vmean:.2e} m/s, \
             moved since step 150 at most {moved:.2e} m",
            inside.len()
        );
    }
    Ok(())
}
