//! Where the time of a substep goes at a fixed particle count as the grid grows: the per-stage
//! timers on `study growth`'s grid series at 48 and 160 cells (54,872 particles, 2 threads), in
//! ms per substep of the study's timed steps (the 2nd to the 6th).
//!
//! `cargo run --release --example growth_stages`
use powderlab::lab::study::growth::{plan, simulation, Series};
use powderlab::scene::Scene;

fn main() -> anyhow::Result<()> {
    let base = Scene::load("scenes/sand_box.ron")?;
    for cfg in plan(false, Some(2))
        .into_iter()
        .filter(|c| c.series == Series::Grid && [48, 160].contains(&c.cells))
    {
        let mut sim = simulation(&base, &cfg, true)?;
        sim.step()?;
        let before: Vec<(&str, f64)> = sim.stage_seconds();
        let n0 = sim.clock().total_substeps;
        for _ in 0..cfg.timed_steps {
            sim.step()?;
        }
        let n = (sim.clock().total_substeps - n0) as f64;
        print!("{} cells:", cfg.cells);
        for ((name, t1), (_, t0)) in sim.stage_seconds().iter().zip(&before) {
            print!(" {name} {:.2}", (t1 - t0) / n * 1e3);
        }
        println!(" (ms per substep)");
    }
    Ok(())
}
