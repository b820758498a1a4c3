//! Does the soft height read the pile a camera sees? For a true friction angle of 32°, the
//! noise-free height map of `calibration_collapse` against the soft heights of runs at 28–36°,
//! for three temperatures τ and three edge sharpnesses τ/w: the RMS gap (mm) per angle. The
//! loss's minimum should sit at the truth.
//!
//! `cargo run --release --example soft_height_bias [-- PIXEL_M]` (default one grid cell).

use powderlab::lab::calibrate::{self, params};
use powderlab::math::heightfield::{soft_heights, squared_error, SoftHeight};
use powderlab::scene::Scene;
use powderlab::sim::{SimOptions, Simulation};

fn main() {
    let scene = Scene::load("scenes/calibration_collapse.ron").expect("the shipped scene");
    let pixel: f64 = std::env::args()
        .nth(1)
        .map(|a| a.parse().expect("PIXEL_M: a length in metres"))
        .unwrap_or(scene.simulation.dx);
    let p = params::parse(&scene, &["friction_deg".into()], &[]).expect("friction_deg");
    let steps = scene.simulation.steps.expect("the scene sets its steps");
    let mut truth = scene.clone();
    p[0].apply(&mut truth, 32.0);
    let obs = calibrate::observe(&truth, steps, true, pixel, 0.0, 0, None).expect("observe");
    let calibrate::observation::Observation::Heights { grid, heights } = obs else {
        unreachable!("a height map was asked for")
    };
    let base = scene.floor_height();
    let top = 0.5 * scene.particle_spacing(&scene.bodies[0]);
    let states: Vec<(f64, Vec<glam::DVec3>)> = [28.0, 30.0, 31.0, 32.0, 33.0, 34.0, 36.0]
        .into_iter()
        .map(|phi| {
            let mut s = scene.clone();
            p[0].apply(&mut s, phi);
            let mut sim = Simulation::new(&s, &SimOptions::default()).expect("scene");
            sim.run(steps, |_| {}).expect("run");
            (
                phi,
                sim.body_states().into_iter().flat_map(|b| b.x).collect(),
            )
        })
        .collect();
    println!("RMS gap (mm) between the soft heights at each angle and the camera's at 32°");
    for tau in [0.0625e-3, 0.125e-3, 0.25e-3] {
        for sharp in [1.0, 4.0, 10.0] {
            let mut line = format!("tau {:.4} mm, w = tau/{sharp}:", tau * 1e3);
            for (phi, xs) in &states {
                let edge = tau / sharp;
                let sh = SoftHeight {
                    base,
                    top,
                    tau,
                    edge,
                };
                let soft = soft_heights(&grid, xs, &sh);
                line.push_str(&format!(
                    " {phi}°: {:.3}",
                    squared_error(&soft, &heights).0.sqrt() * 1e3
                ));
            }
            println!("{line}");
        }
    }
}
