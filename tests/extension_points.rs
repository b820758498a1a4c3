//! A material and a shape can be added without touching `src/`: this file defines a toy
//! material (St. Venant–Kirchhoff in principal stretches) and a toy shape (a torus), registers
//! both, runs a scene that names them, and checks the adjoint through both against central
//! differences (`docs/design.md` §6, "One place per extension").

#![cfg(feature = "lab")]

use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3};
use powderlab::error::FieldError;
use powderlab::materials::{
    material_adj, register, Material, Param, UpdateAdj, POISSON_RATIO, YOUNGS_MODULUS,
};
use powderlab::math::return_map::{lame, lame_adj};
use powderlab::math::sdf::{circle_distance_hessian, register_shape, ShapePlugin};
use powderlab::scene::Scene;
use powderlab::sim::{SimOptions, Simulation};

/// Largest relative error of the gradient check. The rows agree to 2e-8 or better (run with
/// `--nocapture` to see them), as the built-in materials' do in
/// `tests/gradient_matches_finite_differences.rs`; an error in either adjoint is of order 1.
const GRAD_REL_TOL: f64 = 1e-6;

/// `τ_i = σ_i²·(λ·Σ_j e_j + 2μ·e_i)` with the Green strains `e_j = (σ_j² − 1)/2`.
#[derive(Component, Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct StVenantKirchhoff {
    density: f64,
    youngs_modulus: f64,
    poisson_ratio: f64,
}

impl Material for StVenantKirchhoff {
    const NAME: &'static str = "st_venant_kirchhoff";
    const TAG: &'static str = "StVenantKirchhoff";
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
        if self.youngs_modulus > 0.0 && self.density > 0.0 {
            return Ok(());
        }
        Err(FieldError::new("youngs_modulus", "", "> 0 Pa"))
    }
    fn update(&self, s: DVec3, _q: &mut f64) -> (Option<DVec3>, DVec3) {
        let (mu, lambda) = self.lame();
        let e = (s * s - DVec3::ONE) * 0.5;
        (
            None,
            s * s * (DVec3::splat(lambda * e.element_sum()) + 2.0 * mu * e),
        )
    }
    fn update_adj(&self, s: DVec3, _q: f64, _g_sigma_new: DVec3, g: DVec3) -> UpdateAdj {
        let (mu, lambda) = self.lame();
        let e = (s * s - DVec3::ONE) * 0.5;
        let stress = DVec3::splat(lambda * e.element_sum()) + 2.0 * mu * e;
        // ∂τ_i/∂σ_k = 2σ_i·S_i·δ_ik + σ_i²·(λ + 2μ·δ_ik)·σ_k.
        let g_sigma = 2.0 * s * g * stress
            + s * lambda * (g * s * s).element_sum()
            + 2.0 * mu * s * s * s * g;
        let (g_mu, g_lambda) = (
            (g * s * s * 2.0 * e).element_sum(),
            (g * s * s).element_sum() * e.element_sum(),
        );
        let (g_e, g_nu) = lame_adj(self.youngs_modulus, self.poisson_ratio, g_mu, g_lambda);
        UpdateAdj {
            sigma_new: None,
            tau: s * s * stress,
            g_sigma,
            g_material: material_adj(&[g_e, g_nu]),
        }
    }
}

/// A torus about the local y axis: `φ = √((ρ − R)² + y²) − r`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Torus {
    major_radius: f64,
    minor_radius: f64,
}

impl ShapePlugin for Torus {
    const TAG: &'static str = "Torus";
    fn sdf(&self, p: DVec3) -> (f64, DVec3) {
        let rho = p.x.hypot(p.z).max(1e-300);
        let (a, b) = (rho - self.major_radius, p.y);
        let d = a.hypot(b).max(1e-300);
        let n = DVec3::new(p.x / rho * a, b, p.z / rho * a) / d;
        (d - self.minor_radius, n)
    }
    fn sdf_hessian(&self, p: DVec3) -> Option<DMat3> {
        // The distance to the core circle less a constant.
        Some(circle_distance_hessian(p, self.major_radius, 0.0))
    }
    fn bounding_radius(&self) -> f64 {
        self.major_radius + self.minor_radius
    }
    fn lowest_local_point(&self) -> DVec3 {
        DVec3::new(self.major_radius, -self.minor_radius, 0.0)
    }
    fn validate(&self) -> Result<(), FieldError> {
        if self.minor_radius > 0.0 && self.major_radius > self.minor_radius {
            return Ok(());
        }
        Err(FieldError::new(
            "minor_radius",
            self.minor_radius.to_string(),
            "> 0 m and < major_radius",
        ))
    }
}

/// A block of the toy material, and the torus pressed into it from above.
const SCENE: &str = r#"Scene(
    simulation: (cells: (16, 16, 16), dx: 0.01, dt: 0.01, substeps: 10, steps: Some(8)),
    materials: { "toy": StVenantKirchhoff((density: 1000.0, youngs_modulus: 1e4, poisson_ratio: 0.3)) },
    bodies: [(name: "block", material: "toy", fill: Box(min: (0.05, 0.04, 0.05), max: (0.10, 0.08, 0.10)))],
    colliders: [(name: "ring", kind: Tool, shape: Custom(Torus((major_radius: 0.02, minor_radius: 0.006))),
                 position: (0.075, 0.095, 0.075), soft_band: true,
                 control: Some(Constant(linear: (0.0, -0.3, 0.0), steps: 8)))],
)"#;

fn scene() -> Scene {
    register::<StVenantKirchhoff>();
    register_shape::<Torus>();
    Scene::parse(SCENE, "extension_points.ron".as_ref()).unwrap()
}

#[test]
fn a_material_and_a_shape_defined_here_run_and_push_each_other() {
    let scene = scene();
    let mut sim = Simulation::new(&scene, &SimOptions::default()).unwrap();
    let names = sim.system_names().join(" ");
    assert!(names.contains("StVenantKirchhoff"), "{names}");
    let top = |sim: &mut Simulation| {
        let b = &sim.body_states()[0];
        b.x.iter().map(|x| x.y).fold(f64::MIN, f64::max)
    };
    let before = top(&mut sim);
    sim.run(sim.horizon, |_| {}).unwrap();
    let after = top(&mut sim);
    // The ring's lowest point ends 2.1 mm below the block's top; the block is pressed down.
    assert!(after < before - 1e-3, "top {before} -> {after}");
    // A bad parameter of the shape is refused with its field.
    let bad = SCENE.replace("minor_radius: 0.006", "minor_radius: 0.03");
    let e = Scene::parse(&bad, "bad.ron".as_ref())
        .unwrap_err()
        .to_string();
    assert!(e.contains("minor_radius"), "{e}");
}

#[test]
fn the_adjoint_through_both_matches_central_differences() {
    let scene = scene();
    let groups = ["material", "tool", "v0"].map(String::from);
    let r = powderlab::lab::gradcheck::run(&scene, 8, &groups, Some(2), 256 << 20).unwrap();
    let rows: Vec<_> = r
        .rows
        .iter()
        .map(|r| {
            format!(
                "{} {:.6e} {:.6e} {:.1e}",
                r.parameter, r.adjoint, r.finite_difference, r.rel_error
            )
        })
        .collect();
    assert!(
        rows.iter()
            .any(|r| r.starts_with("materials.toy.youngs_modulus"))
            && r.rows
                .iter()
                .filter(|r| r.parameter.contains("ring"))
                .count()
                == 3,
        "{rows:#?}"
    );
    eprintln!("{rows:#?}");
    assert!(r.rows.iter().all(|r| r.adjoint.is_finite()));
    assert!(r.max_rel_error <= GRAD_REL_TOL, "{rows:#?}");
}
