//! Cohesive Drucker–Prager powder: [`super::drucker_prager`]'s model with a cohesion `c` (Pa)
//! that moves the yield cone along the hydrostatic axis, its apex to the tensile mean stress
//! `c·cot φ` (`crate::math::return_map::cohesion_trace`). At `c = 0` it is the cohesionless
//! material bit for bit. No hardening.
//!
//! **Tensile cut-off**: the cone's apex, `p_t = c·cot φ`, the tension at which the Mohr–Coulomb
//! criterion the cone is fitted to also fails in pure tension. A stretch beyond it returns to
//! the apex (the grains separate, holding that tension, as the cohesionless cone's tip holds
//! none). A separate, lower cut-off would be a second parameter no test a laboratory runs on a
//! powder (an angle of repose, a shear cell) identifies.

use super::drucker_prager::{update_many_lanes, ConeCache};
use super::{
    check_elastic, check_range, FdStep, Group, Material, Param, Saved, UpdateAdj, Updated,
    POISSON_RATIO, YOUNGS_MODULUS,
};
use crate::error::FieldError;
use crate::math::return_map::lame;
use bevy_ecs::prelude::*;
use glam::DVec3;
use serde::{Deserialize, Serialize};

/// Parameters of a cohesive Drucker–Prager powder (SI units).
#[derive(Component, Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CohesiveDruckerPrager {
    /// Density (kg/m³). Default 1500.
    #[serde(default = "super::drucker_prager::default_density")]
    pub density: f64,
    /// Young's modulus E (Pa).
    pub youngs_modulus: f64,
    /// Poisson's ratio ν. Default 0.3.
    #[serde(default = "super::drucker_prager::default_poisson")]
    pub poisson_ratio: f64,
    /// Friction angle φ in degrees, in (0, 80). Default 30.
    #[serde(default = "super::drucker_prager::default_friction")]
    pub friction_deg: f64,
    /// Cohesion c (Pa), in [0, E]. Default 0.
    #[serde(default)]
    pub cohesion: f64,
    #[serde(skip)]
    cache: Option<ConeCache>,
}

impl CohesiveDruckerPrager {
    pub fn new(youngs_modulus: f64, poisson_ratio: f64, friction_deg: f64, cohesion: f64) -> Self {
        Self {
            density: 1500.0,
            youngs_modulus,
            poisson_ratio,
            friction_deg,
            cohesion,
            cache: None,
        }
    }

    fn cache(&self) -> &ConeCache {
        self.cache
            .as_ref()
            .expect("CohesiveDruckerPrager::prepared() is called when the body is built")
    }
}

impl Material for CohesiveDruckerPrager {
    const NAME: &'static str = "cohesive_drucker_prager";
    const TAG: &'static str = "CohesiveDruckerPrager";
    const PARAMS: &'static [Param] = &[
        YOUNGS_MODULUS,
        POISSON_RATIO,
        Param {
            name: "friction_deg",
            fd_step: FdStep::Absolute(1e-6),
        },
        Param {
            name: "cohesion",
            fd_step: FdStep::Absolute(1e-3),
        },
    ];

    fn param(&self, i: usize) -> f64 {
        [
            self.youngs_modulus,
            self.poisson_ratio,
            self.friction_deg,
            self.cohesion,
        ][i]
    }
    fn set_param(&mut self, i: usize, value: f64) {
        *[
            &mut self.youngs_modulus,
            &mut self.poisson_ratio,
            &mut self.friction_deg,
            &mut self.cohesion,
        ][i] = value;
    }
    fn prepared(&self) -> Self {
        let mut m = self.clone();
        m.cache = Some(ConeCache::new(
            m.youngs_modulus,
            m.poisson_ratio,
            m.friction_deg,
            Some(m.cohesion),
        ));
        m
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
            "friction_deg",
            self.friction_deg,
            self.friction_deg > 0.0 && self.friction_deg < 80.0,
            "in (0, 80) degrees (the cohesive cone's apex sits at c·cot φ)",
        )?;
        // Beyond E the apex's strain c·cot φ/K is of order one and more: a powder that stands
        // in tension like a solid, outside what the Hencky-strain model and the stability
        // guard's elastic wave speed were made for.
        check_range(
            "cohesion",
            self.cohesion,
            self.cohesion >= 0.0 && self.cohesion <= self.youngs_modulus,
            "in [0, youngs_modulus] Pa (0 is the cohesionless powder)",
        )
    }

    #[inline(always)]
    fn update(&self, sigma: DVec3, _q: &mut f64) -> Updated {
        let p = self.cache().update(sigma);
        (Some(p.sigma_new), p.tau)
    }

    /// Saves `[ε, ε′, exp ε′]`.
    #[inline(always)]
    fn update_saving(&self, sigma: DVec3, _q: &mut f64, saved: &mut Saved) -> Updated {
        let p = self.cache().update(sigma);
        *saved = [p.eps, p.eps_new, p.sigma_new];
        (Some(p.sigma_new), p.tau)
    }

    /// Four particles at a time in vector registers (`return_map::lanes`), each the scalar
    /// update's result to the bit.
    fn update_many(&self, g: Group<'_>) {
        let c = self.cache();
        update_many_lanes(g, c.cone(), false, |_| c.alpha);
    }

    /// Exact within each return-mapping case; one-sided at the case switches.
    fn update_adj(&self, sigma: DVec3, _q: f64, g_sigma_new: DVec3, g_tau: DVec3) -> UpdateAdj {
        let c = self.cache();
        c.adjoint_of(sigma, &c.update(sigma), g_sigma_new, g_tau)
    }

    fn update_adj_saved(
        &self,
        sigma: DVec3,
        _q: f64,
        saved: &Saved,
        g_sigma_new: DVec3,
        g_tau: DVec3,
    ) -> UpdateAdj {
        let c = self.cache();
        c.adjoint_of(sigma, &c.restore(saved), g_sigma_new, g_tau)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::materials::drucker_prager::DruckerPrager;
    use crate::math::return_map::{dp_project_cohesive, hencky};

    const ADJ_REL_TOL: f64 = 1e-6;
    /// The round-off of a loss of order one differenced over a step of 1e-6: where a parameter
    /// does not enter the case (φ and c inside the cone), the difference measures only this.
    const ROUND_OFF_FLOOR: f64 = 1e-10;

    fn bits(u: &UpdateAdj) -> Vec<u64> {
        let mut v: Vec<u64> = [u.sigma_new.unwrap(), u.tau, u.g_sigma]
            .iter()
            .flat_map(|d| d.to_array())
            .map(f64::to_bits)
            .collect();
        v.extend(u.g_material.0.iter().take(3).map(|x| x.to_bits()));
        v
    }

    #[test]
    fn without_cohesion_it_is_the_cohesionless_material_bit_for_bit() {
        let a = DruckerPrager::new(1e5, 0.3, 30.0).prepared();
        let b = CohesiveDruckerPrager::new(1e5, 0.3, 30.0, 0.0).prepared();
        let (g_s, g_t) = (DVec3::new(0.3, -0.8, 0.5), DVec3::new(1e-5, 2e-5, -1.5e-5));
        for sigma in [
            DVec3::new(0.99, 0.9901, 0.99),
            DVec3::new(1.02, 0.97, 0.99),
            DVec3::new(1.05, 1.04, 1.06),
            DVec3::new(0.95, 0.99, 0.93),
        ] {
            assert_eq!(a.update(sigma, &mut 0.0), b.update(sigma, &mut 0.0));
            let (ua, ub) = (
                a.update_adj(sigma, 0.0, g_s, g_t),
                b.update_adj(sigma, 0.0, g_s, g_t),
            );
            assert_eq!(bits(&ua), bits(&ub), "σ {sigma:?}");
        }
    }

    #[test]
    fn update_adjoint_matches_central_differences_with_cohesion() {
        use crate::materials::fd::{check_update_adjoint, W_SIGMA, W_TAU};
        // On the cone, elastic inside it, and past the apex (in tension beyond c·cot φ).
        let mut cases = std::collections::HashSet::new();
        for sigma in [
            DVec3::new(1.02, 0.97, 0.99),
            DVec3::new(0.999, 0.9985, 0.999),
            DVec3::new(1.05, 1.04, 1.06),
        ] {
            let base = CohesiveDruckerPrager::new(1e5, 0.3, 30.0, 300.0);
            let m = base.prepared();
            let c = m.cache();
            cases.insert(format!(
                "{:?}",
                dp_project_cohesive(hencky(sigma), c.mu, c.lambda, c.alpha, c.tr_c).2
            ));
            let out = check_update_adjoint(
                &base,
                &|m: &CohesiveDruckerPrager| m.prepared(),
                sigma,
                ADJ_REL_TOL,
                ROUND_OFF_FLOOR,
            );
            let mut saved = [DVec3::ZERO; 3];
            m.update_saving(sigma, &mut 0.0, &mut saved);
            assert_eq!(
                bits(&m.update_adj_saved(sigma, 0.0, &saved, W_SIGMA, W_TAU)),
                bits(&out)
            );
        }
        assert_eq!(cases.len(), 3, "every case exercised: {cases:?}");
    }

    #[test]
    fn bad_parameters_are_refused_by_name() {
        for (m, field) in [
            (CohesiveDruckerPrager::new(1e5, 0.3, 30.0, -1.0), "cohesion"),
            (CohesiveDruckerPrager::new(1e5, 0.3, 30.0, 2e5), "cohesion"),
            (
                CohesiveDruckerPrager::new(1e5, 0.3, 0.0, 10.0),
                "friction_deg",
            ),
        ] {
            assert_eq!(m.validate().unwrap_err().field, field);
        }
    }
}
