//! The gradient of a loss on the final particle positions with respect to a material parameter
//! (the friction angle) and the initial velocity, checked against a central difference.
//!
//! ```sh
//! cargo run --release --example material_gradient
//! ```

use glam::DVec3;
use powderlab::adjoint::loss::Loss;
use powderlab::adjoint::tape::{gradient, Tape};
use powderlab::materials::drucker_prager::DruckerPrager;
use powderlab::scene::Scene;
use powderlab::sim::{SimOptions, Simulation};

/// A block of sand dropped onto a rough floor.
const SCENE: &str = r#"Scene(
    simulation: (cells: (16, 16, 16), dx: 0.01, dt: 0.01, substeps: 10, steps: Some(10),
                 walls: (cells: 3, contact: Separate, friction: 0.5)),
    materials: { "sand": DruckerPrager((youngs_modulus: 2e4, friction_deg: 30.0)) },
    bodies: [(name: "block", material: "sand",
              fill: Box(min: (0.05, 0.04, 0.05), max: (0.10, 0.08, 0.10)), velocity: (0.3, 0.0, 0.0))],
)"#;

fn main() -> anyhow::Result<()> {
    let scene = Scene::parse(SCENE, "material_gradient.ron".as_ref())?;
    // How far the block slides: the sum of the particles' distances from a point behind it.
    let loss = Loss::SumDistance(DVec3::new(0.0, 0.03, 0.075));
    let mut sim = Simulation::new(&scene, &SimOptions::default())?;
    let steps = sim.horizon;
    // Checkpointed: the tape stays within the budget whatever the horizon.
    let g = gradient(&mut sim, steps, &loss, Tape::Budget(256 << 20))?;
    let d_phi = g
        .material_gradient(0, "friction_deg")
        .expect("Drucker–Prager has φ");
    let d_v0: DVec3 = g.v0[0].iter().copied().sum();
    println!("loss {:.6} m", g.loss);
    println!("dL/dφ  = {d_phi:.6e} per degree");
    println!(
        "dL/dv0 = ({:.6e}, {:.6e}, {:.6e}) s (a uniform shift of every particle)",
        d_v0.x, d_v0.y, d_v0.z
    );

    // The same derivative by central differences, from two more runs.
    let at = |phi: f64| -> anyhow::Result<f64> {
        let mut s = scene.clone();
        let sand = s
            .materials
            .get_mut("sand")
            .and_then(|m| m.get_mut::<DruckerPrager>());
        sand.expect("sand is Drucker–Prager").friction_deg = phi;
        let mut sim = Simulation::new(&s, &SimOptions::default())?;
        sim.run(steps, |_| {})?;
        let x: Vec<_> = sim.body_states().into_iter().map(|b| b.x).collect();
        Ok(loss.eval(&x).0)
    };
    let h = 1e-4;
    let fd = (at(30.0 + h)? - at(30.0 - h)?) / (2.0 * h);
    println!(
        "central difference dL/dφ = {fd:.6e} (relative error {:.1e})",
        (fd - d_phi).abs() / fd.abs()
    );
    Ok(())
}
