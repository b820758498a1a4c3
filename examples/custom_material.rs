//! A material of your own: a compressible Neo-Hookean solid, registered at run time and named by
//! a scene. It needs its parameters, its update in principal space and that update's adjoint.
//!
//! ```sh
//! cargo run --release --example custom_material
//! ```

use bevy_ecs::prelude::*;
use glam::DVec3;
use powderlab::error::FieldError;
use powderlab::materials::{material_adj, POISSON_RATIO, YOUNGS_MODULUS};
use powderlab::materials::{register, Material, Param, UpdateAdj};
use powderlab::math::return_map::{lame, lame_adj};
use powderlab::{scene::Scene, sim::Simulation};

/// `τ_i = μ(σ_i² − 1) + λ·ln J`, the principal Kirchhoff stresses, `J = σ₁σ₂σ₃`.
#[derive(Component, Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct NeoHookean {
    density: f64,
    youngs_modulus: f64,
    poisson_ratio: f64,
}

impl Material for NeoHookean {
    const NAME: &'static str = "neo_hookean";
    const TAG: &'static str = "NeoHookean";
    const PARAMS: &'static [Param] = &[YOUNGS_MODULUS, POISSON_RATIO];
    fn param(&self, i: usize) -> f64 {
        [self.youngs_modulus, self.poisson_ratio][i]
    }
    fn set_param(&mut self, i: usize, v: f64) {
        *[&mut self.youngs_modulus, &mut self.poisson_ratio][i] = v;
    }
    fn density(&self) -> f64 {
        self.density
    }
    fn lame(&self) -> (f64, f64) {
        lame(self.youngs_modulus, self.poisson_ratio)
    }
    fn validate(&self) -> Result<(), FieldError> {
        let ok = self.density > 0.0 && self.youngs_modulus > 0.0 && self.poisson_ratio < 0.5;
        ok.then_some(()).ok_or_else(|| {
            FieldError::new("youngs_modulus", "", "a positive density and E, ν < 0.5")
        })
    }
    fn update(&self, s: DVec3, _q: &mut f64) -> (Option<DVec3>, DVec3) {
        let (mu, lambda) = self.lame();
        (
            None,
            mu * (s * s - DVec3::ONE) + DVec3::splat(lambda * s.element_product().ln()),
        )
    }
    fn update_adj(&self, s: DVec3, _q: f64, _g_sigma_new: DVec3, g_tau: DVec3) -> UpdateAdj {
        let (mu, lambda) = self.lame();
        let sum = g_tau.element_sum();
        let (g_mu, g_lambda) = (
            g_tau.dot(s * s - DVec3::ONE),
            sum * s.element_product().ln(),
        );
        let (g_e, g_nu) = lame_adj(self.youngs_modulus, self.poisson_ratio, g_mu, g_lambda);
        UpdateAdj {
            sigma_new: None,
            tau: self.update(s, &mut 0.0).1,
            // ∂τ_i/∂σ_j = 2μσ_i·δ_ij + λ/σ_j.
            g_sigma: 2.0 * mu * s * g_tau + lambda * sum / s,
            g_material: material_adj(&[g_e, g_nu]),
        }
    }
}

fn main() -> anyhow::Result<()> {
    register::<NeoHookean>();
    let scene = Scene::parse(
        r#"Scene(
    simulation: (cells: (16, 24, 16), dx: 0.01, dt: 0.01, substeps: 20, steps: Some(30)),
    materials: { "jelly": NeoHookean((density: 1000.0, youngs_modulus: 2e4, poisson_ratio: 0.3)) },
    bodies: [(name: "cube", material: "jelly", fill: Box(min: (0.05, 0.08, 0.05), max: (0.10, 0.13, 0.10)))],
)"#,
        "custom_material.ron".as_ref(),
    )?;
    let mut sim = Simulation::new(&scene, &Default::default())?;
    println!("systems: {}", sim.system_names().join(" → "));
    sim.run(sim.horizon, |_| {})?;
    let b = &sim.body_states()[0];
    let lowest = b.x.iter().map(|x| x.y).fold(f64::INFINITY, f64::min);
    let floor = scene.simulation.walls.cells as f64 * scene.simulation.dx;
    println!(
        "after the drop the cube's lowest particle is at {lowest:.4} m (the floor at {floor:.3} m)"
    );
    Ok(())
}
