//! Constitutive maths in principal (singular-value) space: StVK in Hencky strain and the
//! Drucker–Prager return mapping of Klár et al. 2016.
//!
//! With `F = U·diag(σ)·Vᵀ` and Hencky strain `ε = ln σ`, the Kirchhoff stress is
//! `τ = U·diag(2μ·ε + λ·tr ε)·Uᵀ`. The Drucker–Prager projection acts on `ε` only:
//! - `tr ε ≥ 0` (expansion): project to the cone tip, `ε′ = 0`;
//! - `δγ = ‖ε̂‖ + (3λ + 2μ)/(2μ)·α·tr ε ≤ 0`: inside the cone, elastic, `ε′ = ε`;
//! - otherwise return to the yield surface along the deviator: `ε′ = ε − δγ·ε̂/‖ε̂‖`,
//!
//! with `ε̂ = ε − tr ε/3` and `α = √(2/3)·2 sin φ/(3 − sin φ)`.
//! Guards (as in the Taichi reference): `σ` is clamped below at [`SIGMA_MIN`] before the log and
//! `‖ε̂‖` at `√`[`DEV_NORM_SQ_MIN`], so `F = I` and inverted elements give finite values.

use crate::math::elementary::{exp, ln};
use glam::DVec3;

pub mod lanes;
pub mod mu_i;

/// Lower clamp on singular values before `ln`: an inverted or crushed element is treated as
/// compressed to 1e-6 of its volume along that axis instead of producing `ln(≤0)`.
pub const SIGMA_MIN: f64 = 1e-6;
/// Lower clamp on `‖ε̂‖²` so the deviator direction is defined at `ε̂ = 0`.
pub const DEV_NORM_SQ_MIN: f64 = 1e-30;

/// Lamé parameters from Young's modulus and Poisson's ratio.
pub fn lame(youngs: f64, poisson: f64) -> (f64, f64) {
    let mu = youngs / (2.0 * (1.0 + poisson));
    let lambda = youngs * poisson / ((1.0 + poisson) * (1.0 - 2.0 * poisson));
    (mu, lambda)
}

/// Drucker–Prager cone coefficient `α(φ)` for a friction angle in degrees.
pub fn dp_alpha(friction_deg: f64) -> f64 {
    let s = friction_deg.to_radians().sin();
    (2.0f64 / 3.0).sqrt() * 2.0 * s / (3.0 - s)
}

/// Klár 2016 hardening: friction angle (degrees) after accumulated plastic strain `q`.
pub fn hardened_friction_deg(h: [f64; 4], q: f64) -> f64 {
    h[0] + (h[1] * q - h[3]) * (-h[2] * q).exp()
}

/// Hencky strain of singular values, with the [`SIGMA_MIN`] guard (`ln` is
/// [`crate::math::elementary::ln`], so that [`lanes`] gives these bits four particles at once).
#[inline(always)]
pub fn hencky(sigma: DVec3) -> DVec3 {
    let s = sigma.max(DVec3::splat(SIGMA_MIN));
    DVec3::new(ln(s.x), ln(s.y), ln(s.z))
}

/// The singular values `exp ε′` of a projected Hencky strain ([`crate::math::elementary::exp`]).
#[inline(always)]
pub fn stretch(eps: DVec3) -> DVec3 {
    DVec3::new(exp(eps.x), exp(eps.y), exp(eps.z))
}

/// Principal Kirchhoff stresses of StVK in Hencky strain: `2μ·ε + λ·tr ε`.
#[inline(always)]
pub fn kirchhoff_principal(eps: DVec3, mu: f64, lambda: f64) -> DVec3 {
    2.0 * mu * eps + DVec3::splat(lambda * (eps.x + eps.y + eps.z))
}

/// Stored energy density per reference volume of StVK in Hencky strain,
/// `ψ = μ·‖ε‖² + ½λ·(tr ε)²`, whose derivative in `ε` is [`kirchhoff_principal`]. A diagnostic
/// (energy budgets, the vibrating bar), not differentiated.
#[inline(always)]
pub fn hencky_energy(eps: DVec3, mu: f64, lambda: f64) -> f64 {
    let tr = eps.x + eps.y + eps.z;
    mu * eps.length_squared() + 0.5 * lambda * tr * tr
}

/// Which branch of the return mapping applied (a kink in the map, see the adjoint docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DpCase {
    Elastic,
    YieldSurface,
    Tip,
}

/// Drucker–Prager projection of a Hencky strain. Returns the projected strain, the increment of
/// the hardening variable `δq` (Klár 2016 eq. 27) and the case.
#[inline(always)]
pub fn dp_project(eps: DVec3, mu: f64, lambda: f64, alpha: f64) -> (DVec3, f64, DpCase) {
    let tr = eps.x + eps.y + eps.z;
    if tr >= 0.0 {
        return (DVec3::ZERO, eps.length(), DpCase::Tip);
    }
    let dev = eps - DVec3::splat(tr / 3.0);
    let dev_norm = dev.length_squared().max(DEV_NORM_SQ_MIN).sqrt();
    let dgamma = dev_norm + (3.0 * lambda + 2.0 * mu) / (2.0 * mu) * alpha * tr;
    if dgamma <= 0.0 {
        (eps, 0.0, DpCase::Elastic)
    } else {
        (
            eps - dev * (dgamma / dev_norm),
            dgamma,
            DpCase::YieldSurface,
        )
    }
}

/// The trace of the Hencky strain at the apex of a cohesive Drucker–Prager cone:
/// `tr ε_c = c·cot φ / K`, `K = λ + 2μ/3` the bulk modulus. The cone of cohesion `c` is the
/// cohesionless one moved along the hydrostatic axis so that its apex sits at the tensile mean
/// stress `p_t = c·cot φ`: the Mohr–Coulomb apex, through which both the Drucker–Prager cone
/// and the Mohr–Coulomb pyramid it is fitted to pass. That apex is the tensile cut-off: beyond
/// it the return goes to the apex, a hydrostatic tension of `p_t` (the cohesionless cone's
/// tip, `ε′ = 0`, is the case `c = 0`). `φ` must be above 0 when `c > 0` (the material
/// refuses otherwise).
#[inline(always)]
pub fn cohesion_trace(cohesion: f64, friction_deg: f64, mu: f64, lambda: f64) -> f64 {
    cohesion / (friction_deg.to_radians().tan() * (lambda + 2.0 * mu / 3.0))
}

/// [`dp_project`] of the cone whose apex is at the strain trace `tr_c` ([`cohesion_trace`]):
/// the cohesionless projection of `ε − tr_c/3`, moved back by `tr_c/3`. At `tr_c = 0` it is
/// [`dp_project`] itself, bit for bit.
#[inline(always)]
pub fn dp_project_cohesive(
    eps: DVec3,
    mu: f64,
    lambda: f64,
    alpha: f64,
    tr_c: f64,
) -> (DVec3, f64, DpCase) {
    if tr_c == 0.0 {
        return dp_project(eps, mu, lambda, alpha);
    }
    let shift = DVec3::splat(tr_c / 3.0);
    let (e, dq, case) = dp_project(eps - shift, mu, lambda, alpha);
    (e + shift, dq, case)
}

/// A Drucker–Prager cone's constants, besides each particle's `α`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cone {
    /// The Lamé parameters.
    pub mu: f64,
    pub lambda: f64,
    /// The apex's strain trace ([`cohesion_trace`]; 0 without cohesion).
    pub tr_c: f64,
}

/// One particle's Drucker–Prager update, with the intermediates its adjoint reads.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DpUpdate {
    /// Hencky strain `ln σ`.
    pub eps: DVec3,
    /// The strain after the return mapping.
    pub eps_new: DVec3,
    /// Increment of the hardening variable.
    pub dq: f64,
    /// `exp ε′`.
    pub sigma_new: DVec3,
    /// Principal Kirchhoff stresses of `ε′`.
    pub tau: DVec3,
}

/// The Drucker–Prager update of one particle at singular values `σ` with cone coefficient
/// `alpha`: [`hencky`], [`dp_project_cohesive`] (at `tr_c = 0`, [`dp_project`] itself),
/// [`stretch`] and [`kirchhoff_principal`]. Both Drucker–Prager materials run it one particle
/// at a time, and [`lanes::dp_update_group`] gives its bits four particles at once.
#[inline(always)]
pub fn dp_update(sigma: DVec3, alpha: f64, cone: Cone) -> DpUpdate {
    let eps = hencky(sigma);
    let (eps_new, dq, _) = dp_project_cohesive(eps, cone.mu, cone.lambda, alpha, cone.tr_c);
    DpUpdate {
        eps,
        eps_new,
        dq,
        sigma_new: stretch(eps_new),
        tau: kirchhoff_principal(eps_new, cone.mu, cone.lambda),
    }
}

// ---------------------------------------------------------------------------------------------
// Adjoints. Each takes the forward inputs plus the adjoint of the outputs and returns the
// adjoints of the inputs (the caller accumulates them with `+=`).
// ---------------------------------------------------------------------------------------------

/// Adjoint of [`lame`]: `(∂L/∂μ, ∂L/∂λ)` → `(∂L/∂E, ∂L/∂ν)`. Exact.
pub fn lame_adj(youngs: f64, poisson: f64, g_mu: f64, g_lambda: f64) -> (f64, f64) {
    let (a, b) = (1.0 + poisson, 1.0 - 2.0 * poisson);
    let g_e = g_mu / (2.0 * a) + g_lambda * poisson / (a * b);
    let g_nu = -g_mu * youngs / (2.0 * a * a)
        + g_lambda * youngs * (1.0 + 2.0 * poisson * poisson) / (a * b).powi(2);
    (g_e, g_nu)
}

/// Adjoint of [`dp_alpha`]: `∂L/∂α` → `∂L/∂φ` (per degree). Exact.
pub fn dp_alpha_adj(friction_deg: f64, g_alpha: f64) -> f64 {
    let phi = friction_deg.to_radians();
    let s = phi.sin();
    let c = (2.0f64 / 3.0).sqrt();
    g_alpha * 6.0 * c / ((3.0 - s) * (3.0 - s)) * phi.cos() * std::f64::consts::PI / 180.0
}

/// Adjoint of [`hencky`]: `∂L/∂ε` → `∂L/∂σ`. Exact where `σ > SIGMA_MIN`; where the clamp acts
/// the gradient is the one-sided (constant-branch) zero.
#[inline(always)]
pub fn hencky_adj(sigma: DVec3, g_eps: DVec3) -> DVec3 {
    let g = |s: f64, g: f64| if s > SIGMA_MIN { g / s } else { 0.0 };
    DVec3::new(
        g(sigma.x, g_eps.x),
        g(sigma.y, g_eps.y),
        g(sigma.z, g_eps.z),
    )
}

/// Adjoint of [`kirchhoff_principal`]: `∂L/∂τ_p` → `(∂L/∂ε, ∂L/∂μ, ∂L/∂λ)`. Exact (linear).
#[inline(always)]
pub fn kirchhoff_principal_adj(
    eps: DVec3,
    mu: f64,
    lambda: f64,
    g_tau: DVec3,
) -> (DVec3, f64, f64) {
    let sum_g = g_tau.x + g_tau.y + g_tau.z;
    let tr = eps.x + eps.y + eps.z;
    (
        2.0 * mu * g_tau + DVec3::splat(lambda * sum_g),
        2.0 * eps.dot(g_tau),
        tr * sum_g,
    )
}

/// Adjoint of [`dp_project`]: `(∂L/∂ε′, ∂L/∂δq)` → `(∂L/∂ε, ∂L/∂μ, ∂L/∂λ, ∂L/∂α)`.
///
/// Exact inside each of the three cases. The case switches (`tr ε = 0`: tip versus cone;
/// `δγ = 0`: elastic versus yield) are kinks: there the gradient is that of the case the
/// forward pass took, i.e. one-sided. On the yield surface, with `n̂ = ε̂/‖ε̂‖` and
/// `k = (3λ+2μ)/(2μ)`, the projection is `ε′ = (tr ε/3)·1 − k·α·tr ε·n̂`.
pub fn dp_project_adj(
    eps: DVec3,
    mu: f64,
    lambda: f64,
    alpha: f64,
    g_new: DVec3,
    g_dq: f64,
) -> (DVec3, f64, f64, f64) {
    let tr = eps.x + eps.y + eps.z;
    let (_, _, case) = dp_project(eps, mu, lambda, alpha);
    match case {
        DpCase::Tip => {
            // ε′ = 0, δq = ‖ε‖.
            let l = eps.length();
            let g = if l > 0.0 {
                eps * (g_dq / l)
            } else {
                DVec3::ZERO
            };
            (g, 0.0, 0.0, 0.0)
        }
        DpCase::Elastic => (g_new, 0.0, 0.0, 0.0),
        DpCase::YieldSurface => {
            let dev = eps - DVec3::splat(tr / 3.0);
            let dn2 = dev.length_squared();
            let dn = dn2.max(DEV_NORM_SQ_MIN).sqrt();
            let n = dev / dn;
            let k = (3.0 * lambda + 2.0 * mu) / (2.0 * mu);
            let ka = k * alpha;
            // ε′ = (tr/3)·1 − kα·tr·n̂ ;  δq = dn + kα·tr
            let sum_g = g_new.x + g_new.y + g_new.z;
            let g_nd = g_new.dot(n);
            let g_tr = sum_g / 3.0 - ka * g_nd + ka * g_dq;
            let g_ka = -tr * g_nd + tr * g_dq;
            let g_n = g_new * (-ka * tr);
            // n̂ = dev/dn and dn = ‖dev‖ (both constant in dev below the clamp: one-sided zero).
            let g_dev = if dn2 > DEV_NORM_SQ_MIN {
                (g_n - n * n.dot(g_n)) / dn + n * g_dq
            } else {
                DVec3::ZERO
            };
            let sum_dev = g_dev.x + g_dev.y + g_dev.z;
            let g_eps = g_dev - DVec3::splat(sum_dev / 3.0) + DVec3::splat(g_tr);
            let g_k = g_ka * alpha;
            let g_alpha = g_ka * k;
            let g_lambda = g_k * 3.0 / (2.0 * mu);
            let g_mu = -g_k * 3.0 * lambda / (2.0 * mu * mu);
            (g_eps, g_mu, g_lambda, g_alpha)
        }
    }
}

/// Adjoint of [`cohesion_trace`]: `∂L/∂tr_c` → `(∂L/∂c, ∂L/∂φ (per degree), ∂L/∂μ, ∂L/∂λ)`.
pub fn cohesion_trace_adj(
    cohesion: f64,
    friction_deg: f64,
    mu: f64,
    lambda: f64,
    g_trc: f64,
) -> (f64, f64, f64, f64) {
    let phi = friction_deg.to_radians();
    let (t, k) = (phi.tan(), lambda + 2.0 * mu / 3.0);
    let tr_c = cohesion / (t * k);
    let g_c = g_trc / (t * k);
    // d(1/tan φ)/dφ = −1/sin²φ.
    let g_phi = g_trc * cohesion / k * (-1.0 / (phi.sin() * phi.sin())) * (1f64).to_radians();
    let g_k = -g_trc * tr_c / k;
    (g_c, g_phi, g_k * 2.0 / 3.0, g_k)
}

/// Adjoint of [`dp_project_cohesive`]: `(∂L/∂ε′, ∂L/∂δq)` →
/// `(∂L/∂ε, ∂L/∂μ, ∂L/∂λ, ∂L/∂α, ∂L/∂tr_c)`, with [`dp_project_adj`]'s one-sidedness at the
/// case switches.
pub fn dp_project_cohesive_adj(
    eps: DVec3,
    mu: f64,
    lambda: f64,
    alpha: f64,
    tr_c: f64,
    g_new: DVec3,
    g_dq: f64,
) -> (DVec3, f64, f64, f64, f64) {
    let shift = DVec3::splat(tr_c / 3.0);
    let (g_e, g_mu, g_lambda, g_alpha) =
        dp_project_adj(eps - shift, mu, lambda, alpha, g_new, g_dq);
    // ε′ = P(ε − tr_c/3) + tr_c/3: the shift enters once through P's input and once added.
    let sum = |v: DVec3| v.x + v.y + v.z;
    let g_trc = (sum(g_new) - sum(g_e)) / 3.0;
    (g_e, g_mu, g_lambda, g_alpha, g_trc)
}

#[cfg(test)]
mod tests;
