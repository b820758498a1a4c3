//! Elastic solid: StVK in Hencky strain, no plasticity (no return mapping runs).

use super::{check_range, Material};
use crate::error::FieldError;
use crate::math::return_map::{hencky, kirchhoff_principal, lame};
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
}
