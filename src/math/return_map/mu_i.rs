//! The μ(I) rheology's return mapping (Jop, Forterre and Pouliquen 2006, in the elastoplastic
//! form of Dunatunga and Kamrin 2015) in Hencky strain, beside the Drucker–Prager one of the
//! parent module.
//!
//! With `ε̂ = ε − tr ε/3`, the Kirchhoff pressure `p = −K·tr ε` (`K = λ + 2μ/3`) and the
//! equivalent shear stress `τ = √2·μ·‖ε̂‖` (StVK in Hencky strain: `dev τ = 2μ·ε̂`, and a simple
//! shear of stress τ has `‖dev τ‖ = √2·τ`), the yield condition is `τ ≤ μ(I)·p` with
//!
//! ```text
//! μ(I) = μ_s + Δμ·I/(I₀ + I),   Δμ = μ₂ − μ_s,   I = γ̇·d·√(ρ_s/p)
//! ```
//!
//! and `γ̇ = Δγ/Δt` the plastic shear rate of the substep. The return removes the shear strain
//! `Δγ` along the deviator, at constant volume as Klár's cone does: `τ′ = τ − μ·Δγ` and
//! `ε′ = ε − (Δγ/√2)·ε̂/‖ε̂‖`. The yield condition after the return,
//! `(A − μΔγ)(I₀ + kΔγ) = p·Δμ·kΔγ` with `A = τ − μ_s·p` and `k = d·√ρ_s/(Δt·√p)`, is a quadratic
//! in `Δγ` with one positive root, taken in closed form. So:
//! - `tr ε ≥ 0` (no pressure: Dunatunga and Kamrin's separated, stress-free state): `ε′ = 0`;
//! - `A ≤ 0` (below the static friction `μ_s`): elastic, `ε′ = ε`;
//! - otherwise the rate-dependent return above.
//!
//! At `Δμ = 0` this is Klár's return with the cone `α = √2·μ_s/3` (`mu_i_without_rate_is_klar`).
//! The rate `k` makes the yield stress depend on the substep: that is the rheology, not a
//! discretisation, since `Δγ/Δt` is the flow's shear rate.

use super::DEV_NORM_SQ_MIN;
use glam::DVec3;

/// The μ(I) law's constants as the return mapping uses them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MuIConsts {
    /// Lamé parameters (Pa).
    pub mu: f64,
    pub lambda: f64,
    /// Static friction coefficient μ_s.
    pub mu_s: f64,
    /// `μ₂ − μ_s`, at least 0.
    pub d_mu: f64,
    /// I₀, above 0.
    pub i0: f64,
    /// `d·√ρ_s/Δt` (grain diameter, grain density, substep): `I = rate·Δγ/√p`.
    pub rate: f64,
}

/// Which branch of the μ(I) return applied.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MuICase {
    Elastic,
    Flow,
    Separated,
}

/// The intermediates of a flowing return that its adjoint reads.
#[derive(Clone, Copy, Debug)]
pub struct Flow {
    dev: DVec3,
    dn: f64,
    p: f64,
    a: f64,
    k: f64,
    dgamma: f64,
}

/// The plastic shear strain `Δγ ≥ 0` of the return: the positive root of
/// `μ·k·Δγ² − b·Δγ − A·I₀ = 0`, `b = A·k − μ·I₀ − p·Δμ·k`, in the form without cancellation for
/// either sign of `b`.
#[inline(always)]
fn shear_increment(a: f64, k: f64, p: f64, c: &MuIConsts) -> f64 {
    let g = c.mu;
    let b = a * k - g * c.i0 - p * c.d_mu * k;
    let root = (b * b + 4.0 * g * k * a * c.i0).sqrt();
    if b >= 0.0 {
        (b + root) / (2.0 * g * k)
    } else {
        2.0 * a * c.i0 / (root - b)
    }
}

/// The return's case and, when flowing, the intermediates [`mu_i_project_adj`] reads: the
/// forward computes them once and hands them to the adjoint.
#[inline(always)]
pub fn classify(eps: DVec3, c: &MuIConsts) -> (MuICase, Option<Flow>) {
    let tr = eps.x + eps.y + eps.z;
    if tr >= 0.0 {
        return (MuICase::Separated, None);
    }
    let dev = eps - DVec3::splat(tr / 3.0);
    let dn = dev.length_squared().max(DEV_NORM_SQ_MIN).sqrt();
    let p = -(c.lambda + 2.0 * c.mu / 3.0) * tr;
    let a = std::f64::consts::SQRT_2 * c.mu * dn - c.mu_s * p;
    if a <= 0.0 {
        return (MuICase::Elastic, None);
    }
    let k = c.rate / p.sqrt();
    let dgamma = shear_increment(a, k, p, c);
    (
        MuICase::Flow,
        Some(Flow {
            dev,
            dn,
            p,
            a,
            k,
            dgamma,
        }),
    )
}

/// The μ(I) return of a Hencky strain: the projected strain, the plastic shear strain `Δγ` of
/// the substep (0 unless flowing) and the case.
#[inline(always)]
pub fn mu_i_project(eps: DVec3, c: &MuIConsts) -> (DVec3, f64, MuICase) {
    project_classified(eps, classify(eps, c))
}

/// [`mu_i_project`] from the return's [`classify`].
#[inline(always)]
pub fn project_classified(
    eps: DVec3,
    classified: (MuICase, Option<Flow>),
) -> (DVec3, f64, MuICase) {
    match classified {
        (MuICase::Flow, Some(f)) => {
            let scale = f.dgamma / std::f64::consts::SQRT_2 / f.dn;
            (eps - f.dev * scale, f.dgamma, MuICase::Flow)
        }
        (MuICase::Separated, _) => (DVec3::ZERO, 0.0, MuICase::Separated),
        (case, _) => (eps, 0.0, case),
    }
}

/// The gradient of a μ(I) return with respect to its strain and constants.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MuIAdj {
    pub g_eps: DVec3,
    pub g_mu: f64,
    pub g_lambda: f64,
    pub g_mu_s: f64,
    pub g_d_mu: f64,
}

/// Adjoint of [`mu_i_project`]: `∂L/∂ε′` → [`MuIAdj`]. Exact inside each case; at the case
/// switches (`tr ε = 0`, `A = 0`) the gradient is the one-sided one of the case the forward took.
/// `Δγ` is differentiated through its defining relation `R = (A − μΔγ)(I₀ + kΔγ) − p·Δμ·kΔγ = 0`
/// (`dΔγ = −dR/(∂R/∂Δγ)`, with `∂R/∂Δγ ≤ −μ·I₀ < 0`), which needs no derivative of the root's
/// closed form.
/// `classified` is [`classify`] at `eps`, as the forward computed it.
pub fn mu_i_project_adj(
    eps: DVec3,
    c: &MuIConsts,
    classified: (MuICase, Option<Flow>),
    g_new: DVec3,
) -> MuIAdj {
    let zero = MuIAdj {
        g_eps: DVec3::ZERO,
        g_mu: 0.0,
        g_lambda: 0.0,
        g_mu_s: 0.0,
        g_d_mu: 0.0,
    };
    let f = match classified {
        (MuICase::Separated, _) => return zero,
        (MuICase::Flow, Some(f)) => f,
        _ => {
            return MuIAdj {
                g_eps: g_new,
                ..zero
            }
        }
    };
    let sqrt2 = std::f64::consts::SQRT_2;
    // ε′ = ε − dev·s, s = Δγ/(√2·dn).
    let s = f.dgamma / sqrt2 / f.dn;
    let mut g_dev = g_new * -s;
    let g_s = -g_new.dot(f.dev);
    let g_dgamma = g_s / (sqrt2 * f.dn);
    let mut g_dn = -g_s * s / f.dn;
    // Δγ through R(Δγ; A, μ, k, p, Δμ) = 0.
    let (g, i0, dmu, x) = (c.mu, c.i0, c.d_mu, f.dgamma);
    let dr_dx = -g * (i0 + f.k * x) + f.k * (f.a - g * x - f.p * dmu);
    let w = -g_dgamma / dr_dx;
    let g_a = w * (i0 + f.k * x);
    let mut g_mu = w * (-x * (i0 + f.k * x));
    let g_k = w * ((f.a - g * x) * x - f.p * dmu * x);
    let mut g_p = w * (-dmu * f.k * x);
    let g_d_mu = w * (-f.p * f.k * x);
    // k = rate/√p.
    g_p += g_k * (-0.5 * f.k / f.p);
    // A = √2·μ·dn − μ_s·p.
    g_mu += g_a * sqrt2 * f.dn;
    g_dn += g_a * sqrt2 * g;
    let g_mu_s = -g_a * f.p;
    g_p += -g_a * c.mu_s;
    // p = −K·tr, K = λ + 2μ/3.
    let tr = eps.x + eps.y + eps.z;
    let bulk = c.lambda + 2.0 * g / 3.0;
    let g_bulk = -g_p * tr;
    let g_tr = -g_p * bulk;
    g_mu += g_bulk * 2.0 / 3.0;
    let g_lambda = g_bulk;
    // dn = ‖dev‖ (constant below the clamp: the one-sided zero).
    if f.dev.length_squared() > DEV_NORM_SQ_MIN {
        g_dev += f.dev * (g_dn / f.dn);
    }
    // dev = ε − tr/3, and ε′'s own ε.
    let sum_dev = g_dev.x + g_dev.y + g_dev.z;
    let g_eps = g_new + g_dev - DVec3::splat(sum_dev / 3.0) + DVec3::splat(g_tr);
    MuIAdj {
        g_eps,
        g_mu,
        g_lambda,
        g_mu_s,
        g_d_mu,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::return_map::{dp_project, DpCase};
    use crate::util::Lcg;

    /// Glass beads (Jop et al. 2006) at d = 0.5 mm, ρ_s = 2450 kg/m³, E = 1 MPa, ν = 0.3, Δt =
    /// 1e-4 s: the constants of a flowing powder at the scale of the collapse cases.
    fn glass(d_mu_scale: f64) -> MuIConsts {
        let (mu, lambda) = super::super::lame(1e6, 0.3);
        MuIConsts {
            mu,
            lambda,
            mu_s: 20.9f64.to_radians().tan(),
            d_mu: d_mu_scale * (32.76f64.to_radians().tan() - 20.9f64.to_radians().tan()),
            i0: 0.279,
            rate: 0.5e-3 * 2450f64.sqrt() / 1e-4,
        }
    }

    /// A strain with a compressive trace and a deviator that yields: a few 1e-3.
    fn flowing_strain(r: &mut Lcg) -> DVec3 {
        let dev = DVec3::new(r.symmetric(), r.symmetric(), r.symmetric()) * 4e-3;
        dev - DVec3::splat((dev.x + dev.y + dev.z) / 3.0)
            - DVec3::splat(1e-3 * (1.0 + 0.5 * r.symmetric()))
    }

    /// Without a rate term (Δμ = 0) the return is Klár's onto the cone `α = √2·μ_s/3`: the same
    /// strain to round-off.
    #[test]
    fn mu_i_without_rate_is_klar() {
        let c = glass(0.0);
        let alpha = std::f64::consts::SQRT_2 * c.mu_s / 3.0;
        let mut r = Lcg(7);
        let mut flowed = 0;
        for _ in 0..200 {
            let eps = flowing_strain(&mut r);
            let (a, _, case) = mu_i_project(eps, &c);
            let (b, _, dp_case) = dp_project(eps, c.mu, c.lambda, alpha);
            flowed += (case == MuICase::Flow) as usize;
            assert_eq!(case == MuICase::Flow, dp_case == DpCase::YieldSurface);
            // Round-off of a few operations on strains of 1e-3.
            assert!((a - b).abs().max_element() < 1e-15, "{a} vs {b}");
        }
        assert!(
            flowed > 50,
            "the sample must exercise the flow branch: {flowed}"
        );
    }

    /// After a flowing return, the stress lies on μ(I)·p at the shear rate the return removed.
    #[test]
    fn the_return_lands_on_the_rate_dependent_yield_surface() {
        let c = glass(1.0);
        let mut r = Lcg(11);
        let mut checked = 0;
        for _ in 0..200 {
            let eps = flowing_strain(&mut r);
            let (e, dgamma, case) = mu_i_project(eps, &c);
            if case != MuICase::Flow {
                continue;
            }
            let tr = e.x + e.y + e.z;
            let dev = e - DVec3::splat(tr / 3.0);
            let tau = std::f64::consts::SQRT_2 * c.mu * dev.length();
            let p = -(c.lambda + 2.0 * c.mu / 3.0) * tr;
            let i = c.rate * dgamma / p.sqrt();
            let mu_i = c.mu_s + c.d_mu * i / (c.i0 + i);
            // Relative round-off of the quadratic's root and the strains' differences.
            assert!(
                (tau - mu_i * p).abs() <= 1e-9 * tau,
                "{tau} vs {}",
                mu_i * p
            );
            assert!((tr - (eps.x + eps.y + eps.z)).abs() < 1e-16, "volume kept");
            checked += 1;
        }
        assert!(checked > 50, "{checked}");
    }

    /// Central-difference step in strain and its tolerance: the return is smooth inside each
    /// case, so the error is O(h²) of curvatures of order 1/‖ε̂‖ ≈ 1e3, plus round-off
    /// ε/h ≈ 1e-8 relative on strains of 1e-3.
    const FD_H: f64 = 1e-9;
    const FD_REL_TOL: f64 = 1e-5;

    /// The adjoint of the return against central differences in the strain and in each
    /// constant, on flowing, elastic and separated strains.
    #[test]
    fn mu_i_adjoint_matches_central_differences() {
        let c0 = glass(1.0);
        let mut r = Lcg(3);
        let mut cases = [0usize; 3];
        for n in 0..120 {
            let eps = match n % 6 {
                // Elastic: a small deviator under pressure.
                4 => DVec3::new(-1e-3, -1.1e-3, -0.9e-3),
                // Separated: expansion.
                5 => DVec3::new(1e-4, -0.5e-4, 0.2e-4),
                _ => flowing_strain(&mut r),
            };
            let g_new = DVec3::new(r.symmetric(), r.symmetric(), r.symmetric());
            let loss = |e: DVec3, c: &MuIConsts| mu_i_project(e, c).0.dot(g_new);
            let case = mu_i_project(eps, &c0).2;
            cases[case as usize] += 1;
            let adj = mu_i_project_adj(eps, &c0, classify(eps, &c0), g_new);
            let scale = g_new.length() * (1.0 + adj.g_eps.length());
            for k in 0..3 {
                let mut d = DVec3::ZERO;
                d[k] = FD_H;
                let fd = (loss(eps + d, &c0) - loss(eps - d, &c0)) / (2.0 * FD_H);
                assert!(
                    (fd - adj.g_eps[k]).abs() <= FD_REL_TOL * scale,
                    "{case:?} ∂/∂ε{k}: fd {fd} adjoint {}",
                    adj.g_eps[k]
                );
            }
            type Set = fn(&mut MuIConsts, f64);
            let consts: [(&str, Set, f64, f64); 4] = [
                ("mu", |c, h| c.mu += h, adj.g_mu, c0.mu),
                ("lambda", |c, h| c.lambda += h, adj.g_lambda, c0.lambda),
                ("mu_s", |c, h| c.mu_s += h, adj.g_mu_s, c0.mu_s),
                ("d_mu", |c, h| c.d_mu += h, adj.g_d_mu, c0.d_mu),
            ];
            for (name, set, want, size) in consts {
                let h = 1e-6 * size;
                let (mut up, mut down) = (c0, c0);
                set(&mut up, h);
                set(&mut down, -h);
                let fd = (loss(eps, &up) - loss(eps, &down)) / (2.0 * h);
                // The strain's response to a constant scales as strain/constant.
                let tol = FD_REL_TOL * g_new.length() * 1e-2 / size;
                assert!(
                    (fd - want).abs() <= tol.max(FD_REL_TOL * want.abs()),
                    "{case:?} ∂/∂{name}: fd {fd} adjoint {want}"
                );
            }
        }
        assert!(
            cases.iter().all(|&n| n > 0),
            "every case exercised: {cases:?}"
        );
    }
}
