//! Velocity-level contact response against a rigid body, with Coulomb friction.
//!
//! Given a velocity `v`, the body's velocity `v_b` at that point and the outward normal `n`,
//! with `r = v − v_b` and `r_n = r·n`:
//! - `Sticky`: `v′ = v_b`;
//! - `Slip`: the normal part of `r` is removed in both directions;
//! - `Separate`: the normal part is removed only when approaching (`r_n < 0`).
//!
//! When approaching, the tangential part shrinks by Coulomb friction:
//! `r_t′ = max(0, 1 + μ·r_n/‖r_t‖)·r_t`.

use crate::components::ContactMode;
use glam::DVec3;

/// Contact response of one velocity. See the module docs.
#[inline(always)]
pub fn contact_response(v: DVec3, v_body: DVec3, n: DVec3, mode: ContactMode, mu: f64) -> DVec3 {
    let rel = v - v_body;
    let rn = rel.dot(n);
    match mode {
        ContactMode::Sticky => v_body,
        ContactMode::Separate if rn >= 0.0 => v,
        ContactMode::Slip | ContactMode::Separate => {
            let vt = rel - rn * n;
            let vt_len = vt.length();
            let scale = if rn < 0.0 && mu > 0.0 && vt_len > 0.0 {
                (1.0 + mu * rn / vt_len).max(0.0)
            } else {
                1.0
            };
            v_body + scale * vt
        }
    }
}

/// Weight of a grid node's contact response at signed distance `φ` from a collider with band
/// `b` (the node is in contact when `φ < b`), and its derivative `dw/dφ`:
///
/// - hard band: `w = 1` in the band (all or nothing at `φ = b`, a jump in the node's velocity
///   whenever a moving tool brings a node into its band);
/// - soft band (after PlasticineLab's soft contact): `w = clamp(1 − φ/b, 0, 1)`, full inside the
///   body and fading linearly to 0 at the band's edge, so the blended velocity
///   `v′ = v + w·(response(v) − v)` is continuous in the collider's pose and the gradient
///   through a moving tool sees no jumps (kinks at `φ = 0` and `φ = b`: one-sided there).
#[inline(always)]
pub fn band_weight(phi: f64, band: f64, soft: bool) -> (f64, f64) {
    if !soft || phi <= 0.0 || band <= 0.0 {
        (1.0, 0.0)
    } else if phi < band {
        (1.0 - phi / band, -1.0 / band)
    } else {
        (0.0, 0.0)
    }
}

/// Adjoints of [`contact_response`]'s inputs.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ContactAdj {
    pub v: DVec3,
    pub v_body: DVec3,
    pub n: DVec3,
    pub mu: f64,
}

/// Adjoint of [`contact_response`]: `∂L/∂v′` → adjoints of `v`, `v_b`, `n` and `μ`.
///
/// Exact inside each regime. The regime switches are kinks, where the gradient is that of the
/// regime the forward pass took (one-sided): contact on/off (`r_n = 0` under `Separate`, or the
/// contact band edge in the caller), and Coulomb stick/slip (`1 + μ·r_n/‖r_t‖ = 0`, where the
/// `max(0, ·)` clamp gives a zero gradient on the sticking side).
pub fn contact_response_adj(
    v: DVec3,
    v_body: DVec3,
    n: DVec3,
    mode: ContactMode,
    mu: f64,
    g_out: DVec3,
) -> ContactAdj {
    let rel = v - v_body;
    let rn = rel.dot(n);
    let mut adj = ContactAdj::default();
    match mode {
        ContactMode::Sticky => adj.v_body = g_out,
        ContactMode::Separate if rn >= 0.0 => adj.v = g_out,
        ContactMode::Slip | ContactMode::Separate => {
            let vt = rel - rn * n;
            let len = vt.length();
            let active = rn < 0.0 && mu > 0.0 && len > 0.0;
            let raw = if active { 1.0 + mu * rn / len } else { 1.0 };
            let scale = raw.max(0.0);
            // out = v_b + scale·vt
            adj.v_body += g_out;
            let mut g_vt = g_out * scale;
            let mut g_rn = 0.0;
            if active && raw > 0.0 {
                let g_scale = g_out.dot(vt);
                adj.mu += g_scale * rn / len;
                g_rn += g_scale * mu / len;
                let g_len = -g_scale * mu * rn / (len * len);
                g_vt += vt * (g_len / len);
            }
            // vt = rel − rn·n ;  rn = rel·n ;  rel = v − v_b
            let mut g_rel = g_vt;
            g_rn -= g_vt.dot(n);
            adj.n -= g_vt * rn;
            g_rel += n * g_rn;
            adj.n += rel * g_rn;
            adj.v += g_rel;
            adj.v_body -= g_rel;
        }
    }
    adj
}

#[cfg(test)]
mod tests {
    use super::*;

    /// f64 central differences, away from the regime switches.
    const FD_EPS: f64 = 1e-7;
    const ADJ_REL_TOL: f64 = 1e-6;

    /// The domain walls skip empty nodes on the grounds that a resting node (velocity +0, as P2G
    /// leaves an empty node) comes out of every wall response as +0, bit for bit.
    #[test]
    fn a_resting_node_stays_at_positive_zero() {
        for mode in ContactMode::ALL {
            for mu in [0.0, 0.3] {
                for a in 0..3 {
                    for sign in [1.0, -1.0] {
                        let mut n = DVec3::ZERO;
                        n[a] = sign;
                        let r = contact_response(DVec3::ZERO, DVec3::ZERO, n, mode, mu);
                        assert_eq!(
                            r.to_array().map(f64::to_bits),
                            [0u64; 3],
                            "{mode:?} μ {mu} n {n}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn adjoint_matches_central_differences() {
        let mut rng = crate::util::Lcg(17);
        let mut r = || rng.symmetric();
        let mut checked = 0;
        for _ in 0..2000 {
            let v = DVec3::new(r(), r(), r());
            let vb = 0.3 * DVec3::new(r(), r(), r());
            let n = DVec3::new(r(), r(), r()).normalize();
            let mu = 0.5 * (r() + 1.0);
            let w = DVec3::new(r(), r(), r());
            let mode = ContactMode::ALL[checked % 3];
            let rel = v - vb;
            let rn = rel.dot(n);
            let vt = (rel - rn * n).length();
            // Stay 1e-3 away from the switches r_n = 0 and 1 + μ r_n/‖r_t‖ = 0.
            if rn.abs() < 1e-3 || (1.0 + mu * rn / vt).abs() < 1e-3 || vt < 1e-3 {
                continue;
            }
            checked += 1;
            let f = |v: DVec3, vb: DVec3, n: DVec3, mu: f64| {
                contact_response(v, vb, n, mode, mu).dot(w)
            };
            let a = contact_response_adj(v, vb, n, mode, mu, w);
            let close = |fd: f64, ad: f64, what: &str| {
                assert!(
                    (fd - ad).abs() <= ADJ_REL_TOL * fd.abs().max(ad.abs()).max(1e-3),
                    "{mode:?} {what}: fd {fd} ad {ad}"
                );
            };
            for k in 0..3 {
                let mut e = DVec3::ZERO;
                e[k] = FD_EPS;
                close(
                    (f(v + e, vb, n, mu) - f(v - e, vb, n, mu)) / (2.0 * FD_EPS),
                    a.v[k],
                    "v",
                );
                close(
                    (f(v, vb + e, n, mu) - f(v, vb - e, n, mu)) / (2.0 * FD_EPS),
                    a.v_body[k],
                    "v_body",
                );
                close(
                    (f(v, vb, n + e, mu) - f(v, vb, n - e, mu)) / (2.0 * FD_EPS),
                    a.n[k],
                    "n",
                );
            }
            close(
                (f(v, vb, n, mu + FD_EPS) - f(v, vb, n, mu - FD_EPS)) / (2.0 * FD_EPS),
                a.mu,
                "mu",
            );
        }
        assert!(checked > 1000);
    }

    #[test]
    fn modes() {
        let n = DVec3::Y;
        let vb = DVec3::new(0.1, 0.0, 0.0);
        let v = DVec3::new(1.1, -2.0, 0.0);
        assert_eq!(contact_response(v, vb, n, ContactMode::Sticky, 0.3), vb);
        // Frictionless: the normal part goes, the tangential part stays.
        let s = contact_response(v, vb, n, ContactMode::Separate, 0.0);
        assert!((s - DVec3::new(1.1, 0.0, 0.0)).length() < 1e-15);
        // Friction 0.3 removes 0.3·2 = 0.6 of the 1.0 relative slip.
        let f = contact_response(v, vb, n, ContactMode::Separate, 0.3);
        assert!((f - DVec3::new(0.5, 0.0, 0.0)).length() < 1e-15);
        // Large friction sticks tangentially.
        let g = contact_response(v, vb, n, ContactMode::Slip, 5.0);
        assert!((g - vb).length() < 1e-15);
        // Separating: untouched under Separate, normal removed under Slip.
        let up = DVec3::new(0.3, 1.0, 0.0);
        assert_eq!(contact_response(up, vb, n, ContactMode::Separate, 0.3), up);
        assert!(
            (contact_response(up, vb, n, ContactMode::Slip, 0.3) - DVec3::new(0.3, 0.0, 0.0))
                .length()
                < 1e-15
        );
    }
}
