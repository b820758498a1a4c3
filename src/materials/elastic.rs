//! Elastic solid: StVK in Hencky strain, no plasticity (no return mapping runs).

use super::{check_range, Material, UpdateAdj};
use crate::components::MaterialAdj;
use crate::error::FieldError;
use crate::math::return_map::{
    hencky, hencky_adj, kirchhoff_principal, kirchhoff_principal_adj, lame, lame_adj,
};
use bevy_ecs::prelude::*;
use glam::DVec3;
use serde::{Deserialize, Serialize};

/// Parameters of the elastic material (SI units).
#[derive(Component, Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Elastic {
    /// Density (kg/m³). Default 1000.
    #[serde(default = "default_density")]
    pub density: f64,
    /// Young's modulus E (Pa).
    pub youngs_modulus: f64,
    /// Poisson's ratio ν. Default 0.3.
    #[serde(default = "default_poisson")]
    pub poisson_ratio: f64,
}

fn default_density() -> f64 {
    1000.0
}
fn default_poisson() -> f64 {
    0.3
}

impl Material for Elastic {
    const NAME: &'static str = "elastic";

    fn density(&self) -> f64 {
        self.density
    }
    fn lame(&self) -> (f64, f64) {
        lame(self.youngs_modulus, self.poisson_ratio)
    }
    fn validate(&self) -> Result<(), FieldError> {
        check_range("density", self.density, self.density > 0.0, "> 0 kg/m³")?;
        check_range(
            "youngs_modulus",
            self.youngs_modulus,
            self.youngs_modulus > 0.0,
            "> 0 Pa",
        )?;
        check_range(
            "poisson_ratio",
            self.poisson_ratio,
            self.poisson_ratio > -1.0 && self.poisson_ratio < 0.5,
            "in (-1, 0.5)",
        )
    }
    #[inline(always)]
    fn update(&self, sigma: DVec3, _q: &mut f64) -> (Option<DVec3>, DVec3) {
        let (mu, lambda) = self.lame();
        (None, kirchhoff_principal(hencky(sigma), mu, lambda))
    }

    /// Exact (away from the `SIGMA_MIN` clamp of the Hencky strain).
    fn update_adj(&self, sigma: DVec3, _q: f64, _g_sigma_new: DVec3, g_tau: DVec3) -> UpdateAdj {
        let (mu, lambda) = self.lame();
        let eps = hencky(sigma);
        let (g_eps, g_mu, g_lambda) = kirchhoff_principal_adj(eps, mu, lambda, g_tau);
        let (g_e, g_nu) = lame_adj(self.youngs_modulus, self.poisson_ratio, g_mu, g_lambda);
        UpdateAdj {
            sigma_new: None,
            tau: kirchhoff_principal(eps, mu, lambda),
            g_sigma: hencky_adj(sigma, g_eps),
            g_material: MaterialAdj {
                youngs_modulus: g_e,
                poisson_ratio: g_nu,
                friction_deg: 0.0,
            },
        }
    }
}
