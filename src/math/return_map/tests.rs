//! The return mapping's maths against finite differences and its invariants.

use super::*;

#[test]
fn hencky_energy_is_the_potential_of_the_kirchhoff_stress() {
    let (mu, lambda) = lame(3.5e5, 0.3);
    let eps = DVec3::new(-0.021, 0.013, 0.004);
    let tau = kirchhoff_principal(eps, mu, lambda);
    for k in 0..3 {
        let mut e = DVec3::ZERO;
        e[k] = FD_EPS;
        let fd = (hencky_energy(eps + e, mu, lambda) - hencky_energy(eps - e, mu, lambda))
            / (2.0 * e[k]);
        close(fd, tau[k], "dψ/dε");
    }
}

/// Central-difference step and the required agreement, f64, away from kinks.
const FD_EPS: f64 = 1e-6;
const ADJ_REL_TOL: f64 = 1e-6;

fn close(fd: f64, ad: f64, what: &str) {
    let scale = fd.abs().max(ad.abs()).max(1e-6);
    assert!(
        (fd - ad).abs() <= ADJ_REL_TOL * scale,
        "{what}: fd {fd} ad {ad}"
    );
}

/// The tests' fixed stream in [−1, 1) ([`crate::util::Lcg`]).
use crate::util::lcg_symmetric as lcg;

#[test]
fn lame_and_alpha_adjoints() {
    let (e, nu) = (3.5e5, 0.3);
    let (gm, gl) = (0.7, -1.3);
    let f = |e: f64, nu: f64| {
        let (m, l) = lame(e, nu);
        gm * m + gl * l
    };
    let (ge, gn) = lame_adj(e, nu, gm, gl);
    close(
        (f(e * (1.0 + FD_EPS), nu) - f(e * (1.0 - FD_EPS), nu)) / (2.0 * e * FD_EPS),
        ge,
        "dE",
    );
    close(
        (f(e, nu + FD_EPS) - f(e, nu - FD_EPS)) / (2.0 * FD_EPS),
        gn,
        "dnu",
    );
    for phi in [5.0, 30.0, 60.0] {
        let fd = (dp_alpha(phi + FD_EPS) - dp_alpha(phi - FD_EPS)) / (2.0 * FD_EPS);
        close(fd, dp_alpha_adj(phi, 1.0), "dalpha/dphi");
    }
}

#[test]
fn hencky_and_kirchhoff_adjoints() {
    let mut seed = 4;
    for _ in 0..100 {
        let s = DVec3::new(
            1.0 + 0.3 * lcg(&mut seed),
            1.0 + 0.3 * lcg(&mut seed),
            1.0 + 0.3 * lcg(&mut seed),
        );
        let w = DVec3::new(lcg(&mut seed), lcg(&mut seed), lcg(&mut seed));
        let (mu, lambda) = (1e5 * (1.5 + lcg(&mut seed)), 1e5 * (1.5 + lcg(&mut seed)));
        let g_s = hencky_adj(s, kirchhoff_principal_adj(hencky(s), mu, lambda, w).0);
        let f = |s: DVec3, mu: f64, lambda: f64| kirchhoff_principal(hencky(s), mu, lambda).dot(w);
        for a in 0..3 {
            let mut e = DVec3::ZERO;
            e[a] = FD_EPS;
            close(
                (f(s + e, mu, lambda) - f(s - e, mu, lambda)) / (2.0 * FD_EPS),
                g_s[a],
                "dsigma",
            );
        }
        let (_, gm, gl) = kirchhoff_principal_adj(hencky(s), mu, lambda, w);
        let h = FD_EPS * mu;
        close(
            (f(s, mu + h, lambda) - f(s, mu - h, lambda)) / (2.0 * h),
            gm,
            "dmu",
        );
        close(
            (f(s, mu, lambda + h) - f(s, mu, lambda - h)) / (2.0 * h),
            gl,
            "dlambda",
        );
    }
}

#[test]
fn without_cohesion_the_cohesive_projection_is_the_cohesionless_one() {
    let mut seed = 3;
    let (mu, lambda) = lame(1e5, 0.3);
    for _ in 0..200 {
        let eps = 0.05 * DVec3::new(lcg(&mut seed), lcg(&mut seed), lcg(&mut seed));
        let a = dp_project(eps, mu, lambda, dp_alpha(30.0));
        let b = dp_project_cohesive(eps, mu, lambda, dp_alpha(30.0), 0.0);
        assert_eq!(
            a.0.to_array().map(f64::to_bits),
            b.0.to_array().map(f64::to_bits)
        );
        assert_eq!((a.1.to_bits(), a.2), (b.1.to_bits(), b.2));
    }
}

#[test]
fn cohesion_moves_the_apex_to_the_mohr_coulomb_tension() {
    // A stretch beyond the apex returns to it: a hydrostatic tension of c·cot φ.
    let (mu, lambda) = lame(1e5, 0.3);
    let (c, phi) = (200.0, 35.0);
    let tr_c = cohesion_trace(c, phi, mu, lambda);
    let (e, _, case) = dp_project_cohesive(DVec3::splat(0.01), mu, lambda, dp_alpha(phi), tr_c);
    assert_eq!(case, DpCase::Tip);
    let tau = kirchhoff_principal(e, mu, lambda);
    let p_t = c / phi.to_radians().tan();
    for t in tau.to_array() {
        assert!((t - p_t).abs() < 1e-9 * p_t, "{t} against {p_t}");
    }
    // A shear the cohesionless cone yields under stands with cohesion: at zero mean stress
    // the cone admits ‖s‖ up to 3α·p_t.
    let eps = DVec3::new(1e-4, -1e-4, 0.0);
    assert_eq!(dp_project(eps, mu, lambda, dp_alpha(phi)).2, DpCase::Tip);
    assert_eq!(
        dp_project_cohesive(eps, mu, lambda, dp_alpha(phi), tr_c).2,
        DpCase::Elastic
    );
}

#[test]
fn cohesive_projection_adjoint_in_every_case() {
    // Each derivative against central differences at steps h and h/2, within 3× their
    // difference (the difference's own error estimate: truncation leaves D(h) 4/3 of it
    // off, round-off at least about it; the rule of `tests/common::check_fd`), plus 1e-6
    // of the derivative and an absolute floor of 1e-10 for the round-off of a loss of about
    // 0.1 over a step of 1e-6 when a parameter does not enter the case at all.
    const ESTIMATE_FACTOR: f64 = 3.0;
    const FLOOR: f64 = 1e-10;
    let check = |f: &dyn Fn(f64) -> f64, h: f64, ad: f64, what: &str| {
        let d = |h: f64| (f(h) - f(-h)) / (2.0 * h);
        let (d1, d2) = (d(h), d(h / 2.0));
        let tol = ESTIMATE_FACTOR * (d1 - d2).abs() + ADJ_REL_TOL * ad.abs() + FLOOR;
        assert!((d2 - ad).abs() <= tol, "{what}: fd {d1}, {d2} ad {ad}");
    };
    let mut seed = 11;
    let mut seen = [0usize; 3];
    for _ in 0..3000 {
        let eps = 0.05 * DVec3::new(lcg(&mut seed), lcg(&mut seed), lcg(&mut seed));
        let (mu, lambda) = lame(1e5, 0.3);
        let phi = 20.0 + 20.0 * lcg(&mut seed).abs();
        let c = 2000.0 * lcg(&mut seed).abs();
        let alpha = dp_alpha(phi);
        let (w, wq) = (
            DVec3::new(lcg(&mut seed), lcg(&mut seed), lcg(&mut seed)),
            lcg(&mut seed),
        );
        // The loss through the cohesion's trace, so that its adjoint is checked too.
        let f = |eps: DVec3, mu: f64, lambda: f64, phi: f64, c: f64| {
            let tr_c = cohesion_trace(c, phi, mu, lambda);
            let (e, dq, _) = dp_project_cohesive(eps, mu, lambda, dp_alpha(phi), tr_c);
            e.dot(w) + wq * dq
        };
        let tr_c = cohesion_trace(c, phi, mu, lambda);
        let case_at = |eps: DVec3, mu: f64, lambda: f64, phi: f64, c: f64| {
            let tr_c = cohesion_trace(c, phi, mu, lambda);
            dp_project_cohesive(eps, mu, lambda, dp_alpha(phi), tr_c).2
        };
        let case = case_at(eps, mu, lambda, phi, c);
        let robust = (0..3).all(|a| {
            let mut e = DVec3::ZERO;
            e[a] = 100.0 * FD_EPS;
            case_at(eps + e, mu, lambda, phi, c) == case
                && case_at(eps - e, mu, lambda, phi, c) == case
        }) && [
            (1.001, 1.0, 1.0),
            (0.999, 1.0, 1.0),
            (1.0, 1.001, 1.001),
            (1.0, 0.999, 0.999),
        ]
        .iter()
        .all(|(fp, fc, fm)| case_at(eps, mu * fm, lambda * fm, phi * fp, c * fc) == case);
        if !robust {
            continue;
        }
        seen[case as usize] += 1;
        let (ge, gm, gl, ga, gt) = dp_project_cohesive_adj(eps, mu, lambda, alpha, tr_c, w, wq);
        let (gc, gphi_t, gm_t, gl_t) = cohesion_trace_adj(c, phi, mu, lambda, gt);
        let gphi = ga * dp_alpha_adj(phi, 1.0) + gphi_t;
        for a in 0..3 {
            let mut e = DVec3::ZERO;
            e[a] = 1.0;
            check(
                &|h| f(eps + e * h, mu, lambda, phi, c),
                FD_EPS,
                ge[a],
                "deps",
            );
        }
        let h = FD_EPS * mu;
        check(&|d| f(eps, mu + d, lambda, phi, c), h, gm + gm_t, "dmu");
        check(&|d| f(eps, mu, lambda + d, phi, c), h, gl + gl_t, "dlambda");
        check(&|d| f(eps, mu, lambda, phi + d, c), FD_EPS, gphi, "dphi");
        check(
            &|d| f(eps, mu, lambda, phi, c + d),
            1e-6 * c.max(1.0),
            gc,
            "dc",
        );
    }
    assert!(
        seen.iter().all(|&n| n > 50),
        "every case exercised: {seen:?}"
    );
}

#[test]
fn dp_projection_adjoint_in_every_case() {
    let mut seed = 8;
    let mut seen = [0usize; 3];
    for _ in 0..3000 {
        let eps = 0.05 * DVec3::new(lcg(&mut seed), lcg(&mut seed), lcg(&mut seed));
        let (mu, lambda) = lame(1e5, 0.3);
        let alpha = dp_alpha(20.0 + 20.0 * lcg(&mut seed).abs());
        let (w, wq) = (
            DVec3::new(lcg(&mut seed), lcg(&mut seed), lcg(&mut seed)),
            lcg(&mut seed),
        );
        let f = |eps: DVec3, mu: f64, lambda: f64, alpha: f64| {
            let (e, dq, _) = dp_project(eps, mu, lambda, alpha);
            e.dot(w) + wq * dq
        };
        // Away from the kinks: the case must not change within 100 FD steps.
        let (_, _, case) = dp_project(eps, mu, lambda, alpha);
        let robust = (0..3).all(|a| {
            let mut e = DVec3::ZERO;
            e[a] = 100.0 * FD_EPS;
            dp_project(eps + e, mu, lambda, alpha).2 == case
                && dp_project(eps - e, mu, lambda, alpha).2 == case
        }) && dp_project(eps, mu, lambda, alpha * 1.001).2 == case
            && dp_project(eps, mu, lambda, alpha * 0.999).2 == case;
        if !robust {
            continue;
        }
        seen[case as usize] += 1;
        let (ge, gm, gl, ga) = dp_project_adj(eps, mu, lambda, alpha, w, wq);
        for a in 0..3 {
            let mut e = DVec3::ZERO;
            e[a] = FD_EPS;
            close(
                (f(eps + e, mu, lambda, alpha) - f(eps - e, mu, lambda, alpha)) / (2.0 * FD_EPS),
                ge[a],
                "deps",
            );
        }
        let h = FD_EPS * mu;
        close(
            (f(eps, mu + h, lambda, alpha) - f(eps, mu - h, lambda, alpha)) / (2.0 * h),
            gm,
            "dmu",
        );
        close(
            (f(eps, mu, lambda + h, alpha) - f(eps, mu, lambda - h, alpha)) / (2.0 * h),
            gl,
            "dlambda",
        );
        close(
            (f(eps, mu, lambda, alpha + FD_EPS) - f(eps, mu, lambda, alpha - FD_EPS))
                / (2.0 * FD_EPS),
            ga,
            "dalpha",
        );
    }
    assert!(
        seen.iter().all(|&n| n > 50),
        "every case exercised: {seen:?}"
    );
}

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
