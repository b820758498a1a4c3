//! Drucker–Prager sand: StVK in Hencky strain with the Klár et al. 2016 return mapping and
//! optional hardening. The maths is in `crate::math::return_map`.

use super::{check_range, Material};
use crate::error::FieldError;
use crate::math::return_map::{
    dp_alpha, dp_project, hardened_friction_deg, hencky, kirchhoff_principal, lame,
};
use bevy_ecs::prelude::*;
use glam::DVec3;
use serde::{Deserialize, Serialize};

/// Parameters of Drucker–Prager sand (SI units).
#[derive(Component, Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DruckerPrager {
    /// Density (kg/m³). Default 1500.
    #[serde(default = "default_density")]
    pub density: f64,
    /// Young's modulus E (Pa).
    pub youngs_modulus: f64,
    /// Poisson's ratio ν. Default 0.3.
    #[serde(default = "default_poisson")]
    pub poisson_ratio: f64,
    /// Friction angle φ in degrees, in [0, 80). Default 30. Ignored when `hardening` is set.
    #[serde(default = "default_friction")]
    pub friction_deg: f64,
    /// Klár 2016 hardening `[h0, h1, h2, h3]` (degrees, degrees, -, degrees), e.g.
    /// `Some((35, 9, 0.2, 10))`. Default: none (constant friction angle).
    #[serde(default)]
    pub hardening: Option<(f64, f64, f64, f64)>,
    #[serde(skip)]
    cache: Option<Cache>,
}

#[derive(Clone, Debug, PartialEq)]
struct Cache {
    mu: f64,
    lambda: f64,
    alpha: f64,
}

fn default_density() -> f64 {
    1500.0
}
fn default_poisson() -> f64 {
    0.3
}
fn default_friction() -> f64 {
    30.0
}

impl DruckerPrager {
    pub fn new(youngs_modulus: f64, poisson_ratio: f64, friction_deg: f64) -> Self {
        Self {
            density: 1500.0,
            youngs_modulus,
            poisson_ratio,
            friction_deg,
            hardening: None,
            cache: None,
        }
    }

    /// Precomputes μ, λ and α; called once when the body is built.
    pub fn prepared(mut self) -> Self {
        let (mu, lambda) = lame(self.youngs_modulus, self.poisson_ratio);
        self.cache = Some(Cache {
            mu,
            lambda,
            alpha: dp_alpha(self.friction_deg),
        });
        self
    }
}

impl Material for DruckerPrager {
    const NAME: &'static str = "drucker_prager";

    fn density(&self) -> f64 {
        self.density
    }
    fn lame(&self) -> (f64, f64) {
        lame(self.youngs_modulus, self.poisson_ratio)
    }
    fn hardens(&self) -> bool {
        self.hardening.is_some()
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
        )?;
        check_range(
            "friction_deg",
            self.friction_deg,
            (0.0..80.0).contains(&self.friction_deg),
            "in [0, 80) degrees",
        )?;
        if let Some((h0, h1, h2, h3)) = self.hardening {
            check_range(
                "hardening.h0",
                h0,
                (0.0..80.0).contains(&h0),
                "in [0, 80) degrees",
            )?;
            check_range("hardening.h1", h1, h1 >= 0.0, ">= 0 degrees")?;
            check_range("hardening.h2", h2, h2 >= 0.0, ">= 0")?;
            check_range(
                "hardening.h3",
                h3,
                (0.0..=h0).contains(&h3),
                "in [0, h0] degrees",
            )?;
        }
        Ok(())
    }

    #[inline(always)]
    fn update(&self, sigma: DVec3, q: &mut f64) -> (Option<DVec3>, DVec3) {
        let c = self
            .cache
            .as_ref()
            .expect("DruckerPrager::prepared() is called when the body is built");
        let alpha = match self.hardening {
            None => c.alpha,
            Some((h0, h1, h2, h3)) => {
                dp_alpha(hardened_friction_deg([h0, h1, h2, h3], *q).clamp(0.0, 89.0))
            }
        };
        let eps = hencky(sigma);
        let (eps_new, dq, _) = dp_project(eps, c.mu, c.lambda, alpha);
        *q += dq;
        let s_new = DVec3::new(eps_new.x.exp(), eps_new.y.exp(), eps_new.z.exp());
        (Some(s_new), kirchhoff_principal(eps_new, c.mu, c.lambda))
    }
}
