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

use glam::DVec3;

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

/// Hencky strain of singular values, with the [`SIGMA_MIN`] guard.
#[inline(always)]
pub fn hencky(sigma: DVec3) -> DVec3 {
    let s = sigma.max(DVec3::splat(SIGMA_MIN));
    DVec3::new(s.x.ln(), s.y.ln(), s.z.ln())
}

/// Principal Kirchhoff stresses of StVK in Hencky strain: `2μ·ε + λ·tr ε`.
#[inline(always)]
pub fn kirchhoff_principal(eps: DVec3, mu: f64, lambda: f64) -> DVec3 {
    2.0 * mu * eps + DVec3::splat(lambda * (eps.x + eps.y + eps.z))
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn klar_parameters() {
        let (mu, lambda) = lame(3.537e5, 0.3);
        assert!((mu - 136038.46).abs() < 0.01);
        assert!((lambda - 204057.69).abs() < 0.01);
        assert!((dp_alpha(30.0) - 0.32660).abs() < 1e-5);
        // Hardening at q = 0: h0 - h3 = 25 degrees.
        assert!((hardened_friction_deg([35.0, 9.0, 0.2, 10.0], 0.0) - 25.0).abs() < 1e-12);
    }

    #[test]
    fn projection_lands_on_the_cone() {
        let (mu, lambda) = lame(1e5, 0.3);
        let alpha = dp_alpha(30.0);
        let eps = DVec3::new(-0.05, 0.02, -0.001);
        let (e, dq, case) = dp_project(eps, mu, lambda, alpha);
        assert_eq!(case, DpCase::YieldSurface);
        assert!(dq > 0.0);
        let tr = e.x + e.y + e.z;
        let dev = e - DVec3::splat(tr / 3.0);
        // On the yield surface: ‖ε̂‖ + (3λ+2μ)/(2μ) α tr ε = 0, and the trace is unchanged.
        let f = dev.length() + (3.0 * lambda + 2.0 * mu) / (2.0 * mu) * alpha * tr;
        assert!(f.abs() < 1e-14, "{f}");
        assert!((tr - (eps.x + eps.y + eps.z)).abs() < 1e-15);
    }

    #[test]
    fn expansion_goes_to_the_tip_and_compression_stays_elastic() {
        let (mu, lambda) = lame(1e5, 0.3);
        let alpha = dp_alpha(30.0);
        let (e, _, case) = dp_project(DVec3::new(0.01, 0.0, 0.0), mu, lambda, alpha);
        assert_eq!((e, case), (DVec3::ZERO, DpCase::Tip));
        let eps = DVec3::splat(-0.01);
        assert_eq!(
            dp_project(eps, mu, lambda, alpha),
            (eps, 0.0, DpCase::Elastic)
        );
    }

    #[test]
    fn guards_keep_degenerate_inputs_finite() {
        let e = hencky(DVec3::new(1.0, 0.0, -0.5));
        assert!(e.is_finite());
        let (p, dq, _) = dp_project(e, 1e5, 1e5, 0.3);
        assert!(p.is_finite() && dq.is_finite());
    }
}
