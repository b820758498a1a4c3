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

#[cfg(test)]
mod tests {
    use super::*;

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
