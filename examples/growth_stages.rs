//! Where the time of a substep goes at a fixed particle count as the grid grows: the per-stage
//! timers on `study growth`'s grid series at 48 and 160 cells (54,872 particles, 2 threads), in
//! ms per substep of the study's timed steps (the 2nd to the 6th).
//!
//! `cargo run --release --example growth_stages`
use powderlab::scene::Scene;
use powderlab::sim::{SimOptions, Simulation};
use powderlab::study::growth::{growth_scene, GrowthConfig, Series};
fn main() {
    let base = Scene::load("scenes/sand_box.ron").unwrap();
    for cells in [48usize, 160] {
        let cfg = GrowthConfig {
            series: Series::Grid,
            cells,
            block_cells: 19,
            threads: Some(2),
            timed_steps: powderlab::study::growth::TIMED_STEPS,
        };
        let s = growth_scene(&base, &cfg).unwrap();
        let mut sim = Simulation::new(
            &s,
            &SimOptions {
                threads: Some(2),
                stage_timers: true,
                ..Default::default()
            },
        )
        .unwrap();
        sim.step().unwrap();
        let before: Vec<(&str, f64)> = sim.stage_seconds();
        let n0 = sim.clock().total_substeps;
        for _ in 0..cfg.timed_steps {
            sim.step().unwrap();
        }
        let n = (sim.clock().total_substeps - n0) as f64;
        print!("{cells} cells:");
        for ((name, t1), (_, t0)) in sim.stage_seconds().iter().zip(&before) {
            print!(" {name} {:.2}", (t1 - t0) / n * 1e3);
        }
        println!(" (ms per substep)");
    }
}
