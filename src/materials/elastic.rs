//! Elastic solid: StVK in Hencky strain, no plasticity (no return mapping runs).

use super::{
    check_elastic, material_adj, Material, Param, UpdateAdj, POISSON_RATIO, YOUNGS_MODULUS,
};
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
    const TAG: &'static str = "Elastic";
    const PARAMS: &'static [Param] = &[YOUNGS_MODULUS, POISSON_RATIO];

    fn param(&self, i: usize) -> f64 {
        [self.youngs_modulus, self.poisson_ratio][i]
    }
    fn set_param(&mut self, i: usize, value: f64) {
        *[&mut self.youngs_modulus, &mut self.poisson_ratio][i] = value;
    }

    fn density(&self) -> f64 {
        self.density
    }
    fn lame(&self) -> (f64, f64) {
        lame(self.youngs_modulus, self.poisson_ratio)
    }
    fn validate(&self) -> Result<(), FieldError> {
        check_elastic(self.density, self.youngs_modulus, self.poisson_ratio)
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
            g_material: material_adj(&[g_e, g_nu]),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Central-difference step in σ and ν (O(1) quantities).
    const FD_EPS: f64 = 1e-7;
    /// Central-difference step in E (Pa; E is 1e5 here). τ is linear in E, so the difference
    /// has no truncation error and a large step keeps cancellation small.
    const FD_EPS_E: f64 = 10.0;
    /// Adjoint against central differences in f64, away from the `SIGMA_MIN` clamp.
    const ADJ_REL_TOL: f64 = 1e-6;

    #[test]
    fn update_adjoint_matches_central_differences() {
        let w_t = DVec3::new(1e-5, 2e-5, -1.5e-5);
        let loss = |m: &Elastic, s: DVec3| m.update(s, &mut 0.0).1.dot(w_t);
        let base = Elastic {
            density: 1000.0,
            youngs_modulus: 1e5,
            poisson_ratio: 0.3,
        };
        for sigma in [
            DVec3::new(1.02, 0.97, 0.99),
            DVec3::new(0.6, 1.4, 0.93),
            DVec3::new(0.99, 0.99, 0.985),
        ] {
            let out = base.update_adj(sigma, 0.0, DVec3::ZERO, w_t);
            // The update it returns is the forward's, bit for bit.
            assert_eq!(
                (out.sigma_new, out.tau),
                base.update(sigma, &mut 0.0),
                "σ {sigma:?}"
            );
            let close = |fd: f64, ad: f64, what: &str| {
                assert!(
                    (fd - ad).abs() <= ADJ_REL_TOL * fd.abs().max(ad.abs()).max(1e-12),
                    "σ {sigma:?} {what}: fd {fd} ad {ad}"
                );
            };
            for a in 0..3 {
                let mut e = DVec3::ZERO;
                e[a] = FD_EPS;
                close(
                    (loss(&base, sigma + e) - loss(&base, sigma - e)) / (2.0 * FD_EPS),
                    out.g_sigma[a],
                    "σ",
                );
            }
            let with = |e: f64, nu: f64| {
                let m = Elastic {
                    youngs_modulus: base.youngs_modulus + e,
                    poisson_ratio: base.poisson_ratio + nu,
                    ..base.clone()
                };
                loss(&m, sigma)
            };
            close(
                (with(FD_EPS_E, 0.0) - with(-FD_EPS_E, 0.0)) / (2.0 * FD_EPS_E),
                out.g_material.0[0],
                "E",
            );
            close(
                (with(0.0, FD_EPS) - with(0.0, -FD_EPS)) / (2.0 * FD_EPS),
                out.g_material.0[1],
                "ν",
            );
            assert_eq!(out.g_material.0[2], 0.0);
        }
    }
}
