//! Load a scene, run it, and read the particles back.
//!
//! ```sh
//! cargo run --release --example run_scene -- scenes/sand_box.ron
//! ```

use powderlab::scene::Scene;
use powderlab::sim::{SimOptions, Simulation};

fn main() -> anyhow::Result<()> {
    let path = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "scenes/free_fall.ron".into());
    // Parsing and every check: a bad field is an error naming the file, line, column and field.
    let scene = Scene::load(&path)?;
    let mut sim = Simulation::new(&scene, &SimOptions::default())?;
    println!(
        "{path}: {} particles, {} steps of {} substeps; systems: {}",
        sim.particle_count(),
        sim.horizon,
        sim.params().substeps,
        sim.system_names().join(" → ")
    );
    for step in 1..=sim.horizon {
        sim.step()?;
        if step % 10 == 0 || step == sim.horizon {
            // One entry per body, in scene order: positions, velocities, C and F.
            let bodies = sim.body_states();
            let n: usize = bodies.iter().map(|b| b.x.len()).sum();
            let mean_y: f64 = bodies.iter().flat_map(|b| &b.x).map(|x| x.y).sum::<f64>();
            let max_v = bodies
                .iter()
                .flat_map(|b| &b.v)
                .map(|v| v.length())
                .fold(0.0, f64::max);
            println!(
                "step {step:4}: mean height {:.4} m, fastest particle {max_v:.3} m/s",
                mean_y / n.max(1) as f64
            );
        }
    }
    Ok(())
}
