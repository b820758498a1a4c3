//! Time per particle-substep of each timed step of `study growth`'s particles series, step by
//! step, on 2 threads: shows why the study times several steps rather than one.
//!
//! `cargo run --release --example growth_probe -- [CELLS,CELLS,...] [STEPS]` (default: the 27,
//! 86 and 126-cell configurations, 5 steps after the untimed first). CELLS are those of the
//! study's particles series (27, 34, 43, 54, 68, 86, 108, 126).
use powderlab::scene::Scene;
use powderlab::study::growth::{plan, simulation, Series, TIMED_STEPS};
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let cells: Vec<usize> = args
        .get(1)
        .map_or("27,86,126", |s| s.as_str())
        .split(',')
        .map(|c| c.parse())
        .collect::<Result<_, _>>()?;
    let steps: usize = args.get(2).map_or(Ok(TIMED_STEPS), |s| s.parse())?;
    let base = Scene::load("scenes/sand_box.ron")?;
    let series: Vec<_> = plan(false, Some(2))
        .into_iter()
        .filter(|c| c.series == Series::Particles)
        .collect();
    for n in cells {
        let Some(cfg) = series.iter().find(|c| c.cells == n) else {
            anyhow::bail!("{n} cells is not in the study's particles series");
        };
        let mut sim = simulation(&base, cfg, false)?;
        let particles = sim.particle_count() as f64;
        sim.step()?;
        let mut per_step = Vec::new();
        for _ in 0..steps {
            let before = sim.clock().total_substeps;
            let t = Instant::now();
            sim.step()?;
            let substeps = (sim.clock().total_substeps - before) as f64;
            per_step.push(format!(
                "{:.0}",
                t.elapsed().as_secs_f64() / substeps / particles * 1e9
            ));
        }
        println!(
            "{n} cells, {particles} particles: ns per particle-substep in steps 2..={}: {}",
            steps + 1,
            per_step.join(", ")
        );
    }
    Ok(())
}
