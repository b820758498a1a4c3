//! A granular material with the μ(I) rheology (Jop, Forterre and Pouliquen 2006), in the
//! elastoplastic form Dunatunga and Kamrin 2015 run in MPM: StVK in Hencky strain, a yield
//! stress `μ(I)·p` that rises with the inertial number `I = γ̇·d·√(ρ_s/p)`, and a stress-free,
//! separated state without pressure. The maths is `crate::math::return_map::mu_i`.
//!
//! The shear rate is the return's plastic strain over the substep, so the material reads the
//! substep when its body is built ([`Material::with_substep`]). No hardening. The differentiable
//! parameters are E, ν, μ_s and μ₂; I₀, the grain diameter and the grain density are not (the
//! tape has room for four per material).

use super::{
    check_elastic, check_range, material_adj, FdStep, Material, Param, UpdateAdj, Updated,
    MAX_DENSITY, POISSON_RATIO, YOUNGS_MODULUS,
};
use crate::error::FieldError;
use crate::math::return_map::mu_i::{classify, mu_i_project_adj, project_classified, MuIConsts};
use crate::math::return_map::{
    hencky, hencky_adj, kirchhoff_principal, kirchhoff_principal_adj, lame, stretch,
};
use bevy_ecs::prelude::*;
use glam::DVec3;
use serde::{Deserialize, Serialize};

/// Parameters of a μ(I) powder (SI units). The defaults are Jop et al.'s glass beads.
#[derive(Component, Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MuI {
    /// Bulk density (kg/m³). Default 1500.
    #[serde(default = "super::drucker_prager::default_density")]
    pub density: f64,
    /// Young's modulus E (Pa).
    pub youngs_modulus: f64,
    /// Poisson's ratio ν. Default 0.3.
    #[serde(default = "super::drucker_prager::default_poisson")]
    pub poisson_ratio: f64,
    /// Static friction coefficient μ_s. Default tan 20.9° = 0.382 (glass beads).
    #[serde(default = "default_mu_s")]
    pub mu_s: f64,
    /// Limiting friction coefficient μ₂ at large I, at least μ_s. Default tan 32.76° = 0.643.
    #[serde(default = "default_mu_2")]
    pub mu_2: f64,
    /// I₀. Default 0.279.
    #[serde(default = "default_i_0")]
    pub i_0: f64,
    /// Grain diameter d (m). Default 0.5 mm.
    #[serde(default = "default_grain_diameter")]
    pub grain_diameter: f64,
    /// Density of the grains' own material ρ_s (kg/m³), at least the bulk density. Default 2450
    /// (glass).
    #[serde(default = "default_grain_density")]
    pub grain_density: f64,
    #[serde(skip)]
    cache: Option<MuICache>,
}

fn default_mu_s() -> f64 {
    20.9f64.to_radians().tan()
}
fn default_mu_2() -> f64 {
    32.76f64.to_radians().tan()
}
fn default_i_0() -> f64 {
    0.279
}
fn default_grain_diameter() -> f64 {
    0.5e-3
}
fn default_grain_density() -> f64 {
    2450.0
}

/// What the material derives once per body: the return's constants (with the substep's rate
/// once [`Material::with_substep`] has run) and the Lamé derivatives.
#[derive(Clone, Debug, PartialEq)]
struct MuICache {
    consts: MuIConsts,
    d_lame: [(f64, f64); 2],
}

/// What [`MuI::forward`] returns.
type Forward = (
    DVec3,
    (
        crate::math::return_map::mu_i::MuICase,
        Option<crate::math::return_map::mu_i::Flow>,
    ),
    DVec3,
    DVec3,
    DVec3,
);

impl MuI {
    pub fn new(youngs_modulus: f64, poisson_ratio: f64, mu_s: f64, mu_2: f64) -> Self {
        Self {
            density: 1500.0,
            youngs_modulus,
            poisson_ratio,
            mu_s,
            mu_2,
            i_0: default_i_0(),
            grain_diameter: default_grain_diameter(),
            grain_density: default_grain_density(),
            cache: None,
        }
    }

    fn consts(&self) -> &MuIConsts {
        let c = self
            .cache
            .as_ref()
            .expect("MuI::prepared() is called when the body is built");
        // The rate d·√ρ_s/Δt is positive once set (the parameters are validated positive).
        assert!(
            c.consts.rate > 0.0,
            "MuI::with_substep() is called when the body is built"
        );
        &c.consts
    }

    /// The forward update and what its adjoint reads: `(ε, the return's case and
    /// intermediates, ε′, exp ε′, τ_p)`.
    #[inline(always)]
    fn forward(&self, sigma: DVec3) -> Forward {
        let c = self.consts();
        let eps = hencky(sigma);
        let classified = classify(eps, c);
        let (eps_new, _, _) = project_classified(eps, classified);
        (
            eps,
            classified,
            eps_new,
            stretch(eps_new),
            kirchhoff_principal(eps_new, c.mu, c.lambda),
        )
    }
}

impl Material for MuI {
    const NAME: &'static str = "mu_i";
    const TAG: &'static str = "MuI";
    const PARAMS: &'static [Param] = &[
        YOUNGS_MODULUS,
        POISSON_RATIO,
        Param {
            name: "mu_s",
            fd_step: FdStep::Absolute(1e-6),
        },
        Param {
            name: "mu_2",
            fd_step: FdStep::Absolute(1e-6),
        },
    ];

    fn param(&self, i: usize) -> f64 {
        [
            self.youngs_modulus,
            self.poisson_ratio,
            self.mu_s,
            self.mu_2,
        ][i]
    }
    fn set_param(&mut self, i: usize, value: f64) {
        *[
            &mut self.youngs_modulus,
            &mut self.poisson_ratio,
            &mut self.mu_s,
            &mut self.mu_2,
        ][i] = value;
    }
    fn prepared(&self) -> Self {
        let mut m = self.clone();
        let (mu, lambda) = lame(m.youngs_modulus, m.poisson_ratio);
        m.cache = Some(MuICache {
            consts: MuIConsts {
                mu,
                lambda,
                mu_s: m.mu_s,
                d_mu: m.mu_2 - m.mu_s,
                i0: m.i_0,
                rate: 0.0,
            },
            d_lame: super::lame_derivatives(m.youngs_modulus, m.poisson_ratio),
        });
        m
    }
    fn with_substep(&mut self, dt_sub: f64) {
        let (d, rho_s) = (self.grain_diameter, self.grain_density);
        let c = self
            .cache
            .as_mut()
            .expect("MuI::prepared() runs before with_substep()");
        c.consts.rate = d * rho_s.sqrt() / dt_sub;
    }
    fn density(&self) -> f64 {
        self.density
    }
    fn lame(&self) -> (f64, f64) {
        lame(self.youngs_modulus, self.poisson_ratio)
    }
    fn validate(&self) -> Result<(), FieldError> {
        check_elastic(self.density, self.youngs_modulus, self.poisson_ratio)?;
        check_range(
            "mu_s",
            self.mu_s,
            self.mu_s > 0.0 && self.mu_s <= 2.0,
            "in (0, 2] (tan 20.9° = 0.382 for glass beads)",
        )?;
        check_range(
            "mu_2",
            self.mu_2,
            self.mu_2 >= self.mu_s && self.mu_2 <= 3.0,
            "in [mu_s, 3] (tan 32.76° = 0.643 for glass beads)",
        )?;
        check_range(
            "i_0",
            self.i_0,
            self.i_0 > 0.0 && self.i_0 <= 10.0,
            "in (0, 10] (0.279 for glass beads)",
        )?;
        check_range(
            "grain_diameter",
            self.grain_diameter,
            self.grain_diameter > 0.0 && self.grain_diameter <= 0.1,
            "in (0, 0.1] m",
        )?;
        check_range(
            "grain_density",
            self.grain_density,
            self.grain_density >= self.density && self.grain_density <= MAX_DENSITY,
            &format!("in [density, {MAX_DENSITY:e}] kg/m³ (a powder's bulk density is below its grains' own)"),
        )
    }

    #[inline(always)]
    fn update(&self, sigma: DVec3, _q: &mut f64) -> Updated {
        let (_, _, _, sigma_new, tau) = self.forward(sigma);
        (Some(sigma_new), tau)
    }

    /// Exact within each case of the return; one-sided at the case switches.
    fn update_adj(&self, sigma: DVec3, _q: f64, g_sigma_new: DVec3, g_tau: DVec3) -> UpdateAdj {
        let c = self.consts();
        let (eps, classified, eps_new, sigma_new, tau) = self.forward(sigma);
        let (g_eps_k, g_mu_k, g_lambda_k) = kirchhoff_principal_adj(eps_new, c.mu, c.lambda, g_tau);
        let g_eps_new = g_sigma_new * sigma_new + g_eps_k;
        let adj = mu_i_project_adj(eps, c, classified, g_eps_new);
        let (g_mu, g_lambda) = (g_mu_k + adj.g_mu, g_lambda_k + adj.g_lambda);
        let d = &self.cache.as_ref().expect("prepared").d_lame;
        UpdateAdj {
            sigma_new: Some(sigma_new),
            tau,
            g_sigma: hencky_adj(sigma, adj.g_eps),
            g_material: material_adj(&[
                g_mu * d[0].0 + g_lambda * d[0].1,
                g_mu * d[1].0 + g_lambda * d[1].1,
                adj.g_mu_s - adj.g_d_mu,
                adj.g_d_mu,
            ]),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::return_map::mu_i::MuICase;

    const ADJ_REL_TOL: f64 = 1e-6;
    /// The round-off of a loss of order one differenced over a step of 1e-6 (as the
    /// Drucker–Prager materials' tests): where a parameter does not enter the case (μ_s and μ₂
    /// inside the yield surface), the difference measures only this.
    const ROUND_OFF_FLOOR: f64 = 1e-10;

    /// Glass beads at E = 100 kPa, run at a substep of 1e-4 s.
    fn beads(m: &MuI) -> MuI {
        let mut m = m.prepared();
        m.with_substep(1e-4);
        m
    }

    #[test]
    fn update_adjoint_matches_central_differences() {
        let base = MuI::new(1e5, 0.3, default_mu_s(), default_mu_2());
        let mut cases = std::collections::HashSet::new();
        // Flowing under pressure (two shear levels), elastic inside the static surface, and
        // separated (expansion).
        for sigma in [
            DVec3::new(1.02, 0.97, 0.99),
            DVec3::new(1.004, 0.994, 0.999),
            DVec3::new(0.999, 0.9985, 0.999),
            DVec3::new(1.05, 1.04, 1.06),
        ] {
            cases.insert(format!(
                "{:?}",
                classify(hencky(sigma), beads(&base).consts()).0
            ));
            crate::materials::fd::check_update_adjoint(
                &base,
                &beads,
                sigma,
                ADJ_REL_TOL,
                ROUND_OFF_FLOOR,
            );
        }
        for case in [MuICase::Flow, MuICase::Elastic, MuICase::Separated] {
            assert!(
                cases.contains(&format!("{case:?}")),
                "{case:?} not exercised: {cases:?}"
            );
        }
    }

    /// A faster substep (a larger shear rate for the same strain) raises the stress the return
    /// leaves: the yield stress rises with I.
    #[test]
    fn the_yield_stress_rises_with_the_shear_rate() {
        let sigma = DVec3::new(1.02, 0.97, 0.99);
        let base = MuI::new(1e5, 0.3, default_mu_s(), default_mu_2()).prepared();
        let shear = |dt: f64| {
            let mut m = base.clone();
            m.with_substep(dt);
            let (_, t) = m.update(sigma, &mut 0.0);
            let mean = (t.x + t.y + t.z) / 3.0;
            (t - DVec3::splat(mean)).length()
        };
        let (slow, fast) = (shear(1e-2), shear(1e-5));
        assert!(fast > 1.05 * slow, "fast {fast} slow {slow}");
    }

    #[test]
    fn bad_parameters_are_refused_by_name() {
        let ok = MuI::new(1e5, 0.3, 0.38, 0.64);
        assert!(ok.validate().is_ok());
        let mut m = ok.clone();
        m.mu_2 = 0.3;
        assert_eq!(m.validate().unwrap_err().field, "mu_2");
        let mut m = ok.clone();
        m.i_0 = 0.0;
        assert_eq!(m.validate().unwrap_err().field, "i_0");
        let mut m = ok.clone();
        m.grain_density = 1000.0;
        assert_eq!(m.validate().unwrap_err().field, "grain_density");
        let mut m = ok;
        m.mu_s = -0.1;
        assert_eq!(m.validate().unwrap_err().field, "mu_s");
    }
}
