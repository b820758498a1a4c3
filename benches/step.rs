//! Criterion benchmarks: every stage alone and a full substep, on the `sand_box` scene (the
//! Taichi reference's scene) at two grid sizes, plus the `powder_transport` substep.
//!
//! `cargo bench --bench step`

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use powderlab::scene::Scene;
use powderlab::sim::{SimOptions, Simulation};
use std::time::Duration;

fn sim_for(name: &str, n_grid: Option<usize>, stage_timers: bool) -> Simulation {
    let mut scene = Scene::load(format!("{}/scenes/{name}", env!("CARGO_MANIFEST_DIR"))).unwrap();
    if let Some(n) = n_grid {
        scene.simulation.cells = (n, n, n);
        scene.simulation.dx = 1.0 / n as f64;
    }
    let mut sim = Simulation::new(
        &scene,
        &SimOptions {
            threads: Some(2),
            stage_timers,
            ..Default::default()
        },
    )
    .unwrap();
    // One step so that the state (C, F, grid) is a moving one, not the initial rest state.
    sim.step().unwrap();
    sim
}

fn substep(c: &mut Criterion) {
    let mut g = c.benchmark_group("substep");
    g.sample_size(10).measurement_time(Duration::from_secs(10));
    for n in [32usize, 48] {
        let mut sim = sim_for("sand_box.ron", Some(n), false);
        let particles = sim.particle_count();
        g.bench_with_input(BenchmarkId::new("sand_box", particles), &n, |b, _| {
            b.iter(|| sim.substep().unwrap())
        });
    }
    let mut sim = sim_for("powder_transport.ron", None, false);
    let particles = sim.particle_count();
    g.bench_with_input(
        BenchmarkId::new("powder_transport", particles),
        &0,
        |b, _| b.iter(|| sim.substep().unwrap()),
    );
    g.finish();
}

fn stages(c: &mut Criterion) {
    let mut g = c.benchmark_group("stage");
    g.sample_size(10).measurement_time(Duration::from_secs(4));
    let mut sim = sim_for("sand_box.ron", Some(48), true);
    let particles = sim.particle_count();
    for name in sim.stage_names() {
        g.bench_with_input(BenchmarkId::new(name, particles), &name, |b, name| {
            b.iter(|| assert!(sim.run_stage(name)))
        });
    }
    g.finish();
}

criterion_group!(benches, substep, stages);
criterion_main!(benches);
