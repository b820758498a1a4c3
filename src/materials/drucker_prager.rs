//! Drucker–Prager sand: StVK in Hencky strain with the Klár et al. 2016 return mapping and
//! optional hardening. The maths is in `crate::math::return_map`.

use super::{
    check_elastic, check_range, material_adj, FdStep, Group, Material, Param, Saved, UpdateAdj,
    Updated, POISSON_RATIO, YOUNGS_MODULUS,
};
use crate::error::FieldError;
use crate::math::return_map::lanes::{dp_update_group, LANES};
use crate::math::return_map::{
    cohesion_trace, cohesion_trace_adj, dp_alpha, dp_alpha_adj, dp_project_adj,
    dp_project_cohesive_adj, dp_update, hardened_friction_deg, hencky_adj, kirchhoff_principal,
    kirchhoff_principal_adj, lame, Cone, DpUpdate,
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
    cache: Option<ConeCache>,
}

/// What both Drucker–Prager materials precompute once per body (`prepared`), and the update and
/// adjoint they share around it.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct ConeCache {
    pub(super) mu: f64,
    pub(super) lambda: f64,
    pub(super) alpha: f64,
    /// The apex's strain trace `c·cot φ/K` (0 without cohesion).
    pub(super) tr_c: f64,
    /// `(∂(μ, λ)/∂E, ∂(μ, λ)/∂ν)`: the parameter gradient is linear in `(∂L/∂μ, ∂L/∂λ)`, so
    /// the per-particle adjoint applies these instead of evaluating [`lame_adj`].
    d_lame: [(f64, f64); 2],
    /// `∂α/∂φ` per degree, likewise (one sine and cosine per body, not per particle).
    d_alpha: f64,
    /// `(c, φ)` of a cohesive cone, whose apex moves with both; `None` without cohesion.
    cohesion: Option<(f64, f64)>,
}

impl ConeCache {
    /// The cone of `(E, ν, φ)`, with its apex at the cohesion `c` (Pa) where one is given.
    pub(super) fn new(e: f64, nu: f64, friction_deg: f64, cohesion: Option<f64>) -> Self {
        let (mu, lambda) = lame(e, nu);
        Self {
            mu,
            lambda,
            alpha: dp_alpha(friction_deg),
            tr_c: cohesion.map_or(0.0, |c| cohesion_trace(c, friction_deg, mu, lambda)),
            d_lame: super::lame_derivatives(e, nu),
            d_alpha: dp_alpha_adj(friction_deg, 1.0),
            cohesion: cohesion.map(|c| (c, friction_deg)),
        }
    }

    /// The forward update at `σ` with the cone's own `α`, and the intermediates its adjoint
    /// reads.
    #[inline(always)]
    pub(super) fn update(&self, sigma: DVec3) -> DpUpdate {
        dp_update(sigma, self.alpha, self.cone())
    }

    pub(super) fn cone(&self) -> Cone {
        Cone {
            mu: self.mu,
            lambda: self.lambda,
            tr_c: self.tr_c,
        }
    }

    /// The update saved as `[ε, ε′, exp ε′]`, with `τ_p` recomputed from `ε′` by the same
    /// function as in the forward, so that its adjoint is the recomputing one's bits.
    pub(super) fn restore(&self, saved: &Saved) -> DpUpdate {
        let [eps, eps_new, sigma_new] = *saved;
        DpUpdate {
            eps,
            eps_new,
            dq: 0.0,
            sigma_new,
            tau: kirchhoff_principal(eps_new, self.mu, self.lambda),
        }
    }

    /// The adjoint of the update `p` made at `σ` (see [`Material::update_adj`]), with the
    /// parameter gradient in the order `E, ν, φ` (and `c` for a cohesive cone).
    #[inline(always)]
    pub(super) fn adjoint_of(
        &self,
        sigma: DVec3,
        p: &DpUpdate,
        g_sigma_new: DVec3,
        g_tau: DVec3,
    ) -> UpdateAdj {
        let (g_eps_k, mut g_mu, mut g_lambda) =
            kirchhoff_principal_adj(p.eps_new, self.mu, self.lambda, g_tau);
        let g_eps_new = g_sigma_new * p.sigma_new + g_eps_k;
        // (∂L/∂ε, ∂L/∂μ, ∂L/∂λ, ∂L/∂φ beyond α's, ∂L/∂c) of the projection and, for a
        // cohesive cone, of its apex.
        let (g_eps, gm, gl, g_alpha, apex) = match self.cohesion {
            None => {
                let (g_eps, gm, gl, g_alpha) =
                    dp_project_adj(p.eps, self.mu, self.lambda, self.alpha, g_eps_new, 0.0);
                (g_eps, gm, gl, g_alpha, None)
            }
            Some((c, phi)) => {
                let (g_eps, gm, gl, g_alpha, g_trc) = dp_project_cohesive_adj(
                    p.eps,
                    self.mu,
                    self.lambda,
                    self.alpha,
                    self.tr_c,
                    g_eps_new,
                    0.0,
                );
                let (g_c, g_phi_trc, gm_t, gl_t) =
                    cohesion_trace_adj(c, phi, self.mu, self.lambda, g_trc);
                (g_eps, gm + gm_t, gl + gl_t, g_alpha, Some((g_phi_trc, g_c)))
            }
        };
        g_mu += gm;
        g_lambda += gl;
        let [(mu_e, lambda_e), (mu_nu, lambda_nu)] = self.d_lame;
        let g_phi = g_alpha * self.d_alpha;
        let g = [
            g_mu * mu_e + g_lambda * lambda_e,
            g_mu * mu_nu + g_lambda * lambda_nu,
            apex.map_or(g_phi, |(g_phi_trc, _)| g_phi + g_phi_trc),
            apex.map_or(0.0, |(_, g_c)| g_c),
        ];
        let g_material = material_adj(&g[..if apex.is_some() { 4 } else { 3 }]);
        UpdateAdj {
            sigma_new: Some(p.sigma_new),
            tau: p.tau,
            g_sigma: hencky_adj(sigma, g_eps),
            g_material,
        }
    }
}

/// [`Material::update_many`] of the Drucker–Prager materials: `return_map::lanes` on groups of
/// four, `alpha_at(q)` each particle's cone coefficient at its hardening variable, `δq` added to
/// it where the material `hardens` (as `DruckerPrager::update` does; the cohesive material
/// keeps none), saving `[ε, ε′, exp ε′]` where asked.
pub(super) fn update_many_lanes(
    g: Group<'_>,
    cone: Cone,
    hardens: bool,
    alpha_at: impl Fn(f64) -> f64,
) {
    let Group {
        sigma,
        q,
        mut saved,
        out,
    } = g;
    let n = sigma.len();
    assert!(q.len() == n && out.len() == n, "update_many: one length");
    for g in (0..n).step_by(LANES) {
        let m = LANES.min(n - g);
        // A short last group is padded with particles at rest; their lanes are dropped.
        let mut s = [DVec3::ONE; LANES];
        s[..m].copy_from_slice(&sigma[g..g + m]);
        let alpha: [f64; LANES] = std::array::from_fn(|l| alpha_at(q[g + l.min(m - 1)]));
        for (l, u) in dp_update_group(&s, &alpha, cone).iter().take(m).enumerate() {
            if hardens {
                q[g + l] += u.dq;
            }
            if let Some(sv) = saved.as_deref_mut() {
                sv[g + l] = [u.eps, u.eps_new, u.sigma_new];
            }
            out[g + l] = (Some(u.sigma_new), u.tau);
        }
    }
}

pub(super) fn default_density() -> f64 {
    1500.0
}
pub(super) fn default_poisson() -> f64 {
    0.3
}
pub(super) fn default_friction() -> f64 {
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

    fn cache(&self) -> &ConeCache {
        self.cache
            .as_ref()
            .expect("DruckerPrager::prepared() is called when the body is built")
    }
}

impl Material for DruckerPrager {
    const NAME: &'static str = "drucker_prager";
    const TAG: &'static str = "DruckerPrager";
    const PARAMS: &'static [Param] = &[
        YOUNGS_MODULUS,
        POISSON_RATIO,
        Param {
            name: "friction_deg",
            fd_step: FdStep::Absolute(1e-6),
        },
    ];

    fn param(&self, i: usize) -> f64 {
        [self.youngs_modulus, self.poisson_ratio, self.friction_deg][i]
    }
    fn set_param(&mut self, i: usize, value: f64) {
        *[
            &mut self.youngs_modulus,
            &mut self.poisson_ratio,
            &mut self.friction_deg,
        ][i] = value;
    }
    fn prepared(&self) -> Self {
        let mut m = self.clone();
        m.cache = Some(ConeCache::new(
            m.youngs_modulus,
            m.poisson_ratio,
            m.friction_deg,
            None,
        ));
        m
    }

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
        check_elastic(self.density, self.youngs_modulus, self.poisson_ratio)?;
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
        let p = self.project_at(sigma, *q);
        *q += p.dq;
        (Some(p.sigma_new), p.tau)
    }

    /// Saves `[ε, ε′, exp ε′]`.
    #[inline(always)]
    fn update_saving(&self, sigma: DVec3, q: &mut f64, saved: &mut Saved) -> Updated {
        let p = self.project_at(sigma, *q);
        *q += p.dq;
        *saved = [p.eps, p.eps_new, p.sigma_new];
        (Some(p.sigma_new), p.tau)
    }

    /// Four particles at a time in vector registers (`return_map::lanes`), each the scalar
    /// update's result to the bit.
    fn update_many(&self, g: Group<'_>) {
        update_many_lanes(g, self.cache().cone(), true, |q| self.alpha_at(q));
    }

    /// Exact within each return-mapping case; one-sided at the case switches (see
    /// `dp_project_adj`). With hardening the friction angle's dependence on `q` is not
    /// differentiated (the backward pass refuses such scenes).
    fn update_adj(&self, sigma: DVec3, _q: f64, g_sigma_new: DVec3, g_tau: DVec3) -> UpdateAdj {
        let c = self.cache();
        c.adjoint_of(
            sigma,
            &dp_update(sigma, c.alpha, c.cone()),
            g_sigma_new,
            g_tau,
        )
    }

    /// [`Material::update_adj`] from the saved `[ε, ε′, exp ε′]`; `τ_p` is recomputed from `ε′`
    /// by the same function as in the forward, so the result is the same bits.
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

impl DruckerPrager {
    /// The cone coefficient `α` at hardening state `q` (the friction angle's, without
    /// hardening).
    #[inline(always)]
    fn alpha_at(&self, q: f64) -> f64 {
        let c = self.cache();
        match self.hardening {
            None => c.alpha,
            Some(h) => dp_alpha(hardened_friction_deg(h.into(), q).clamp(0.0, 89.0)),
        }
    }

    /// The forward update at `σ` with the friction angle of hardening state `q`.
    #[inline(always)]
    fn project_at(&self, sigma: DVec3, q: f64) -> DpUpdate {
        dp_update(sigma, self.alpha_at(q), self.cache().cone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::return_map::{dp_project, hencky};

    /// f64 central differences away from the return-mapping kinks.
    const FD_EPS: f64 = 1e-7;
    const ADJ_REL_TOL: f64 = 1e-6;

    #[test]
    fn update_adjoint_matches_central_differences() {
        let w_s = DVec3::new(0.3, -0.8, 0.5);
        let w_t = DVec3::new(1e-5, 2e-5, -1.5e-5);
        let loss = |m: &DruckerPrager, s: DVec3| {
            let m = m.clone().prepared();
            let (sn, t) = m.update(s, &mut 0.0);
            sn.unwrap().dot(w_s) + t.dot(w_t)
        };
        for sigma in [
            DVec3::new(1.02, 0.97, 0.99),
            DVec3::new(0.95, 0.99, 0.93),
            DVec3::new(0.99, 0.99, 0.985),
        ] {
            let m = DruckerPrager::new(1e5, 0.3, 30.0).prepared();
            let out = m.update_adj(sigma, 0.0, w_s, w_t);
            // The update it returns is the forward's, bit for bit.
            let (sn, tau) = m.update(sigma, &mut 0.0);
            assert_eq!((out.sigma_new, out.tau), (sn, tau));
            let (g_s, g_m) = (out.g_sigma, out.g_material);
            let close = |fd: f64, ad: f64, what: &str| {
                assert!(
                    (fd - ad).abs() <= ADJ_REL_TOL * fd.abs().max(ad.abs()).max(1e-9),
                    "σ {sigma:?} {what}: fd {fd} ad {ad}"
                );
            };
            for a in 0..3 {
                let mut e = DVec3::ZERO;
                e[a] = FD_EPS;
                close(
                    (loss(&m, sigma + e) - loss(&m, sigma - e)) / (2.0 * FD_EPS),
                    g_s[a],
                    "σ",
                );
            }
            let with = |f: &dyn Fn(&mut DruckerPrager)| {
                let mut x = m.clone();
                f(&mut x);
                loss(&x, sigma)
            };
            let h = 1e-3;
            close(
                (with(&|x| x.youngs_modulus += h) - with(&|x| x.youngs_modulus -= h)) / (2.0 * h),
                g_m.0[0],
                "E",
            );
            close(
                (with(&|x| x.poisson_ratio += FD_EPS) - with(&|x| x.poisson_ratio -= FD_EPS))
                    / (2.0 * FD_EPS),
                g_m.0[1],
                "ν",
            );
            close(
                (with(&|x| x.friction_deg += FD_EPS) - with(&|x| x.friction_deg -= FD_EPS))
                    / (2.0 * FD_EPS),
                g_m.0[2],
                "φ",
            );
        }
    }

    /// The adjoint from the saved update is the recomputing adjoint, bit for bit, in each
    /// return-mapping case (elastic, cone, tip), and `update_saving` is `update`.
    #[test]
    fn saved_update_gives_the_same_adjoint() {
        let m = DruckerPrager::new(1e5, 0.3, 30.0).prepared();
        let (g_s, g_t) = (DVec3::new(0.3, -0.8, 0.5), DVec3::new(1e-5, 2e-5, -1.5e-5));
        let mut cases = std::collections::HashSet::new();
        for sigma in [
            DVec3::new(0.99, 0.9901, 0.99),
            DVec3::new(1.02, 0.97, 0.99),
            DVec3::new(1.05, 1.04, 1.06),
        ] {
            let c = m.cache.as_ref().unwrap();
            cases.insert(format!(
                "{:?}",
                dp_project(hencky(sigma), c.mu, c.lambda, c.alpha).2
            ));
            let mut saved = [DVec3::ZERO; 3];
            let (mut q0, mut q1) = (0.0, 0.0);
            assert_eq!(
                m.update_saving(sigma, &mut q0, &mut saved),
                m.update(sigma, &mut q1)
            );
            let a = m.update_adj(sigma, 0.0, g_s, g_t);
            let b = m.update_adj_saved(sigma, 0.0, &saved, g_s, g_t);
            let bits = |u: &UpdateAdj| {
                let mut v: Vec<u64> = [u.sigma_new.unwrap(), u.tau, u.g_sigma]
                    .iter()
                    .flat_map(|d| d.to_array())
                    .map(f64::to_bits)
                    .collect();
                let g = u.g_material;
                v.extend(g.0.map(f64::to_bits));
                v
            };
            assert_eq!(bits(&a), bits(&b), "σ {sigma:?}");
        }
        assert_eq!(cases.len(), 3, "the three return-mapping cases: {cases:?}");
    }
}
