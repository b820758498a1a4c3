//! How sensitive is where a spilled grain ends on the floor to how it landed? A lone particle
//! (or a small clump) of the default transport scene's powder, on its grid and floor, thrown at
//! `(V, 0, 0)` m/s from height `H` m: prints its final x and the central difference of that
//! x in V at several ε. A Coulomb slide on a floor of friction μ gives `∂x/∂V ≈ V/(μg)` plus the
//! flight time, a few tenths of a second; a much larger value means the grid floor amplifies
//! a landing's small differences.
//!
//! ```sh
//! cargo run --release --example floor_slide -- [V=0.3] [H=0.03] [PPC=1] [STEPS=150]
//! ```
//!
//! `PPC` is the particles per cell of the one-cell box the clump fills (1 gives one particle).

use glam::DVec3;
use powderlab::scene::Scene;
use powderlab::sim::{SimOptions, Simulation};
use std::path::Path;

/// The scene whose grid, walls, substeps and powder the clump uses.
const SCENE: &str = "scenes/powder_transport.ron";

/// That scene without its cups, spoon and task, and with its powder body replaced by a clump
/// filling one cell at x = 0.1 m, z = 0.05 m, its bottom `h` above the floor's wall layers.
fn scene(v: f64, h: f64, ppc: usize) -> anyhow::Result<Scene> {
    let base = Scene::load(SCENE)?;
    let sim = &base.simulation;
    let dx = sim.dx;
    let y0 = sim.domain_min.1 + sim.walls.cells as f64 * dx + h;
    let material = &base.bodies[0].material;
    let body = format!(
        "(name: \"clump\", material: \"{material}\", \
         fill: Box(min: (0.1, {y0}, 0.05), max: ({x1}, {y1}, {z1})), \
         particles_per_cell: {ppc}, velocity: ({v}, 0.0, 0.0))",
        x1 = 0.1 + dx,
        y1 = y0 + dx,
        z1 = 0.05 + dx,
    );
    let clump = Scene {
        bodies: vec![ron::from_str(&body)?],
        colliders: Vec::new(),
        task: None,
        record: None,
        loss: None,
        ..base
    };
    // Through the scene parser, so that the clump scene is validated like a file.
    Ok(Scene::parse(
        &ron::to_string(&clump)?,
        Path::new("<floor_slide>"),
    )?)
}

fn final_x(v: f64, h: f64, ppc: usize, steps: usize) -> anyhow::Result<(Vec<DVec3>, usize)> {
    let mut sim = Simulation::new(&scene(v, h, ppc)?, &SimOptions::default())?;
    let subs = sim.params().substeps;
    sim.run(steps, |_| {})?;
    Ok((sim.body_states()[0].x.clone(), subs))
}

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().collect();
    let arg = |k: usize, d: f64| a.get(k).map_or(Ok(d), |s| s.parse::<f64>());
    // PPC and STEPS are counts: "2.5" is refused, not truncated to 2.
    let count = |k: usize, name: &str, d: usize| {
        a.get(k).map_or(Ok(d), |s| {
            s.parse::<usize>()
                .map_err(|e| anyhow::anyhow!("{name} = {s:?}: {e}; give a whole number"))
        })
    };
    let (v, h) = (arg(1, 0.3)?, arg(2, 0.03)?);
    let (ppc, steps) = (count(3, "PPC", 1)?, count(4, "STEPS", 150)?);
    let (x, subs) = final_x(v, h, ppc, steps)?;
    let mean = |x: &[DVec3]| x.iter().sum::<DVec3>() / x.len() as f64;
    let m = mean(&x);
    println!(
        "{} particles, V = {v} m/s, H = {h} m, {steps} steps x {subs} substeps: final mean \
         position {m:.6?}",
        x.len()
    );
    for eps in [1e-9, 1e-8, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3] {
        let (xp, _) = final_x(v + eps, h, ppc, steps)?;
        let (xm, _) = final_x(v - eps, h, ppc, steps)?;
        let d = (mean(&xp).x - mean(&xm).x) / (2.0 * eps);
        let worst = xp
            .iter()
            .zip(&xm)
            .map(|(p, m)| (*p - *m).length() / (2.0 * eps))
            .fold(0.0f64, f64::max);
        println!("eps {eps:.0e}: d(mean x)/dV = {d:+.6e} s, largest |dx_j/dV| = {worst:.6e} s");
    }
    Ok(())
}
