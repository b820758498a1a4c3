//! Stage 10, particle collision: the guarantee that thin walls do not leak.
//!
//! A 1–2 mm spoon bowl on a 2.5–5 mm grid is thinner than a grid cell, so grid contact alone
//! lets particles through. After G2P every particle is projected again against the collider
//! SDFs at their end-of-substep pose. With `φ` and `n` the SDF and gradient at `x_p` and `v_b`
//! the collider's velocity there, the advected position `x_p + Δt·v_p` keeps `φ ≥ margin` to
//! first order, both against the surface where it is now (the pose the substep ends with) and,
//! for a surface coming towards the particle, where it will be after the next substep's move,
//! when
//!
//! ```text
//! v_p·n ≥ v_min = (margin − φ)/Δt + max(0, v_b·n)
//! ```
//!
//! (a receding surface does not relax the constraint: the particle must be clear of the surface
//! at the end of this substep too).
//!
//! A particle violating it gets exactly `v_p·n = v_min`; its tangential velocity relative to
//! the collider loses `μ·Δv_n` (Coulomb), or all of it for sticky contact. Particles far from a
//! collider (`φ − margin > Δt·max(‖v_p‖, ‖v_p − v_b‖)`, which implies the inequality) are
//! untouched.
//!
//! **Soft contact** (a collider's `soft_particle_contact`). The projection above is
//! `v_n′ = v_min + max(0, x)` with `x = v_p·n − v_min`: a kink at `x = 0`, exactly where powder
//! resting against a wall or sliding along it sits (its projected `v·n` is `v_min`), so the
//! adjoint there follows one branch while a central difference averages both. The soft
//! projection replaces `max(0, x)` by the C¹ blend `x + (x − τ)²/4τ` on `|x| < τ` (0 below,
//! `x` above), with `τ = margin/Δt` ([`soft_speed`]): the same at `|x| ≥ τ`, never below
//! `v_min` (so no particle comes closer than the hard projection lets it), and differentiable
//! everywhere. A particle in lasting contact settles at `x = τ`, one margin farther out.
//!
//! Reads `Collider`, `ColliderPose`, `Position`; writes `Velocity`.

use crate::components::*;
use bevy_ecs::prelude::*;
use glam::DVec3;
use rayon::prelude::*;

/// Clearance kept between particles and collider surfaces, in grid cells. The projection is
/// first order: a particle moving `d = Δt·‖v‖` along a surface of curvature radius `ρ` can come
/// `d²/2ρ` closer than predicted (6e-5 m was measured at dx = 2.5 mm, on the 15 mm spoon bowl in
/// the pour), and the margin absorbs that.
pub const MARGIN_CELLS: f64 = 0.05;

/// The soft projection's velocity band `τ` for a collider: `margin/Δt` (a normal speed that
/// moves a particle by one clearance in a substep) when `soft`, else 0 (the hard projection).
#[inline(always)]
pub fn soft_speed(soft: bool, margin: f64, dt: f64) -> f64 {
    if soft {
        margin / dt
    } else {
        0.0
    }
}

/// The push above `v_min` for `x = v·n − v_min < τ`, and its derivative: `(x + τ)²/4τ` on
/// `−τ < x < τ`, 0 at or below `−τ` (and for the hard projection, `τ = 0`, at every `x < 0`).
#[inline(always)]
fn soft_push(x: f64, tau: f64) -> (f64, f64) {
    if x <= -tau {
        (0.0, 0.0)
    } else {
        let y = x + tau;
        (y * y / (4.0 * tau), y / (2.0 * tau))
    }
}

/// Where a particle meets a collider: the signed distance `φ`, the outward normal `n` and the
/// surface's velocity `v_b` there (what [`particle_contact`] returns).
pub type Hit = (f64, DVec3, DVec3);

/// How a collider projects the particles that meet it: the substep, the contact margin, the
/// contact mode, the friction coefficient and the soft projection's band [`soft_speed`] (0:
/// the hard projection).
#[derive(Clone, Copy, Debug)]
pub struct ContactRule {
    pub dt: f64,
    pub margin: f64,
    pub mode: ContactMode,
    pub mu: f64,
    pub soft: f64,
}

impl ContactRule {
    pub fn new(dt: f64, margin: f64, mode: ContactMode, mu: f64, soft: f64) -> Self {
        Self {
            dt,
            margin,
            mode,
            mu,
            soft,
        }
    }

    /// Collider `c`'s rule at contact margin `margin` and substep `dt`, its soft band from
    /// its `soft_particle_contact`.
    pub fn of(c: &Collider, margin: f64, dt: f64) -> Self {
        let soft = soft_speed(c.soft_particle_contact, margin, dt);
        Self::new(dt, margin, c.contact, c.friction, soft)
    }

    /// How far from the surface a particle is looked at: the margin plus the soft band's
    /// reach over a substep.
    pub fn reach(&self) -> f64 {
        self.margin + self.soft * self.dt
    }
}

/// Velocity of a particle after the non-penetration projection (see the module docs).
#[inline(always)]
pub fn project_particle(v: DVec3, (phi, n, v_body): Hit, rule: &ContactRule) -> DVec3 {
    let (dt, margin, mode, mu, soft) = (rule.dt, rule.margin, rule.mode, rule.mu, rule.soft);
    let v_min = v_body.dot(n).max(0.0) + (margin - phi) / dt;
    let vn = v.dot(n);
    if vn >= v_min + soft {
        return v;
    }
    // The target normal speed: v_min itself for the hard projection.
    let v_target = v_min + soft_push(vn - v_min, soft).0;
    let rel = v - v_body;
    let rel_t = rel - rel.dot(n) * n;
    let dvn = v_target - vn;
    let t_len = rel_t.length();
    let rel_t = match mode {
        ContactMode::Sticky => DVec3::ZERO,
        _ if mu > 0.0 && t_len > 0.0 => rel_t * (1.0 - mu * dvn / t_len).max(0.0),
        _ => rel_t,
    };
    v_body + rel_t + n * (v_target - v_body.dot(n))
}

/// Adjoints of [`project_particle`]'s inputs.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ProjectAdj {
    pub v: DVec3,
    pub phi: f64,
    pub n: DVec3,
    pub v_body: DVec3,
    pub mu: f64,
}

/// Adjoint of [`project_particle`]: `∂L/∂v′` → adjoints of `v`, `φ`, `n`, `v_b`, `μ`. Exact in
/// each regime; the switches (constraint active or not, `v·n = v_min`; Coulomb stick or slip)
/// are kinks where the gradient is that of the regime the forward pass took (one-sided).
pub fn project_particle_adj(
    v: DVec3,
    (phi, n, v_body): Hit,
    rule: &ContactRule,
    g_out: DVec3,
) -> ProjectAdj {
    let (dt, margin, mode, mu, soft) = (rule.dt, rule.margin, rule.mode, rule.mu, rule.soft);
    let vbn_plus = v_body.dot(n);
    let approaching = vbn_plus > 0.0;
    let v_min = vbn_plus.max(0.0) + (margin - phi) / dt;
    let vn = v.dot(n);
    let mut a = ProjectAdj::default();
    if vn >= v_min + soft {
        a.v = g_out;
        return a;
    }
    let (push, d_push) = soft_push(vn - v_min, soft);
    let v_target = v_min + push;
    let rel = v - v_body;
    let rn = rel.dot(n);
    let rel_t = rel - rn * n;
    let dvn = v_target - vn;
    let t_len = rel_t.length();
    // out = v_b + rel_t′ + n·(v_target − v_b·n)
    let vbn = v_body.dot(n);
    let gn_out = g_out.dot(n);
    a.v_body += g_out - n * gn_out;
    a.n += g_out * (v_target - vbn) - v_body * gn_out;
    let mut g_target = gn_out;
    let mut g_dvn = 0.0;
    let g_rel_t = match mode {
        ContactMode::Sticky => DVec3::ZERO,
        _ if mu > 0.0 && t_len > 0.0 => {
            let raw = 1.0 - mu * dvn / t_len;
            if raw > 0.0 {
                let g_s = g_out.dot(rel_t);
                a.mu += -g_s * dvn / t_len;
                g_dvn += -g_s * mu / t_len;
                let g_len = g_s * mu * dvn / (t_len * t_len);
                g_out * raw + rel_t * (g_len / t_len)
            } else {
                DVec3::ZERO
            }
        }
        _ => g_out,
    };
    // dvn = v_target − v·n; v_target = v_min + push(v·n − v_min)
    g_target += g_dvn;
    let g_vmin = g_target * (1.0 - d_push);
    let g_vn = g_target * d_push - g_dvn;
    a.v += n * g_vn;
    a.n += v * g_vn;
    // rel_t = rel − (rel·n)·n
    let nt = n.dot(g_rel_t);
    let g_rel = g_rel_t - n * nt;
    a.n -= g_rel_t * rn + rel * nt;
    // rel = v − v_b
    a.v += g_rel;
    a.v_body -= g_rel;
    // v_min = max(0, v_b·n) + (margin − φ)/dt (the max is a kink: one-sided at v_b·n = 0)
    if approaching {
        a.v_body += n * g_vmin;
        a.n += v_body * g_vmin;
    }
    a.phi = -g_vmin / dt;
    a
}

/// `max(‖v‖, ‖v − v_b‖)`, the speed [`clear_of`] allows for over a substep.
#[inline(always)]
fn clearance_speed(v: DVec3, v_body: DVec3) -> f64 {
    v.length_squared().max((v - v_body).length_squared()).sqrt()
}

/// Whether a particle is so far from a collider that the projection cannot change it:
/// `φ − margin > Δt·max(‖v‖, ‖v − v_b‖)` implies `v·n ≥ v_min` for every unit `n` (the `‖v‖`
/// term covers a receding surface, the relative speed an approaching one), so skipping is exact.
#[inline(always)]
pub fn clear_of(phi: f64, margin: f64, dt: f64, v: DVec3, v_body: DVec3) -> bool {
    phi - margin > dt * clearance_speed(v, v_body)
}

/// The contact of a particle at `x` moving at `v` with collider `c` in this substep:
/// `(φ, world normal, the collider's velocity at x)`, or `None` where the projection cannot
/// change the particle: out of the collider's reach ([`Reach`]), clear by the shape's cheap
/// test ([`Shape::surely_clear`](crate::math::sdf::Shape::surely_clear), at the same threshold
/// as [`clear_of`], so skipping on it is exact) or by `φ` itself. The stage and its adjoint both
/// ask this, so they skip the same particles. `margin` is the clearance plus, for a soft
/// contact, `τ·Δt`: `φ − margin − τΔt > Δt·max(‖v‖, ‖v − v_b‖)` implies `v·n ≥ v_min + τ`.
#[inline(always)]
pub fn particle_contact(
    c: &Collider,
    pose: &ColliderPose,
    reach: &Reach,
    x: DVec3,
    v: DVec3,
    dt: f64,
    margin: f64,
) -> Option<(f64, DVec3, DVec3)> {
    if !reach.may_reach(x, v, dt, margin) {
        return None;
    }
    let vb = pose.velocity_at(x);
    let local = pose.pose.to_local(x);
    if c.shape
        .surely_clear(local, margin + dt * clearance_speed(v, vb))
    {
        return None;
    }
    let (phi, n) = pose.sdf_at_local(&c.shape, local);
    (!clear_of(phi, margin, dt, v, vb)).then_some((phi, n, vb))
}

/// A collider's bounding sphere and the speed of its fastest point, computed once per substep:
/// the cheap test before the SDF.
#[derive(Clone, Copy, Debug)]
pub struct Reach {
    centre: DVec3,
    radius: f64,
    body_speed: f64,
}

impl Reach {
    pub fn of(c: &Collider, pose: &ColliderPose) -> Reach {
        Reach {
            centre: pose.pose.translation,
            radius: c.bounding_radius,
            body_speed: pose.linear.length() + pose.angular.length() * c.bounding_radius,
        }
    }

    /// Whether a particle at `x` with velocity `v` can reach the collider within a substep:
    /// the bounding sphere grown by the margin and by the substep's relative motion (the
    /// particle's and the collider's fastest point's). Outside it `φ` exceeds what
    /// [`clear_of`] needs, so skipping is exact.
    #[inline(always)]
    pub fn may_reach(&self, x: DVec3, v: DVec3, dt: f64, margin: f64) -> bool {
        let reach = self.radius + margin + dt * (v.length() + self.body_speed);
        (x - self.centre).length_squared() <= reach * reach
    }
}

pub fn particle_collision(
    params: Res<SimParams>,
    grid: Res<Grid>,
    colliders: Query<(&Collider, &ColliderPose)>,
    mut bodies: Query<(&Position, &mut Velocity)>,
) {
    let dt = params.dt_sub;
    let margin = MARGIN_CELLS * grid.dx;
    // Per collider: its reach and its projection's rule.
    let mut cs: Vec<_> = colliders
        .iter()
        .filter(|c| c.0.particle_contact)
        .map(|(c, pose)| (c, pose, Reach::of(c, pose), ContactRule::of(c, margin, dt)))
        .collect();
    cs.sort_by_key(|c| c.0.index);
    for (x, mut v) in &mut bodies {
        v.0.par_iter_mut().zip(x.0.par_iter()).for_each(|(v, &x)| {
            for (c, pose, reach, rule) in &cs {
                if let Some(hit) = particle_contact(c, pose, reach, x, *v, dt, rule.reach()) {
                    *v = project_particle(*v, hit, rule);
                }
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn adjoint_matches_central_differences() {
        // f64 central differences, away from the regime switches. The outputs are O(1) (v_min is
        // a clearance over Δt), so the round-off of a difference at ε = 1e-7 is ~1e-9 absolute:
        // gradients are compared relative to at least FLOOR.
        const EPS: f64 = 1e-7;
        const TOL: f64 = 1e-6;
        const FLOOR: f64 = 1e-2;
        let mut rng = crate::util::Lcg(3);
        let mut r = || rng.symmetric();
        let (dt, margin) = (1e-3, 1e-5);
        let (mut checked, mut in_band) = (0, 0);
        for k in 0..6000 {
            // Every other sample with the soft projection, its band wide enough (0.3 m/s) for
            // random velocities to fall in it often.
            let soft = if k % 2 == 0 { 0.0 } else { 0.3 };
            let v = DVec3::new(r(), r(), r());
            let n = DVec3::new(r(), r(), r()).normalize();
            let vb = 0.2 * DVec3::new(r(), r(), r());
            let phi = 1e-3 * r();
            let mu = 0.5 * (r() + 1.0);
            let w = DVec3::new(r(), r(), r());
            let mode = ContactMode::ALL[k % 3];
            let v_min = vb.dot(n).max(0.0) + (margin - phi) / dt;
            let rel = v - vb;
            let rel_t = rel - rel.dot(n) * n;
            let x = v.dot(n) - v_min;
            let v_target = v_min + if x < soft { soft_push(x, soft).0 } else { x };
            let raw = 1.0 - mu * (v_target - v.dot(n)) / rel_t.length();
            // Away from the switches: the hard kink at x = 0, the soft band's edges at ±τ
            // (where the blend is C¹ but its curvature jumps), stick/slip and v_b·n = 0.
            let near = |a: f64| (x - a).abs() < 1e-3;
            if near(0.0) && soft == 0.0
                || soft > 0.0 && (near(soft) || near(-soft))
                || raw.abs() < 1e-3
                || vb.dot(n).abs() < 1e-3
            {
                continue;
            }
            checked += 1;
            in_band += usize::from(x.abs() < soft);
            let f = |v: DVec3, phi: f64, n: DVec3, vb: DVec3, mu: f64| {
                project_particle(
                    v,
                    (phi, n, vb),
                    &ContactRule::new(dt, margin, mode, mu, soft),
                )
                .dot(w)
            };
            let a = project_particle_adj(
                v,
                (phi, n, vb),
                &ContactRule::new(dt, margin, mode, mu, soft),
                w,
            );
            let close = |fd: f64, ad: f64, what: &str| {
                assert!(
                    (fd - ad).abs() <= TOL * fd.abs().max(ad.abs()).max(FLOOR),
                    "{mode:?} {what}: fd {fd} ad {ad}"
                );
            };
            for c in 0..3 {
                let mut e = DVec3::ZERO;
                e[c] = EPS;
                close(
                    (f(v + e, phi, n, vb, mu) - f(v - e, phi, n, vb, mu)) / (2.0 * EPS),
                    a.v[c],
                    "v",
                );
                close(
                    (f(v, phi, n + e, vb, mu) - f(v, phi, n - e, vb, mu)) / (2.0 * EPS),
                    a.n[c],
                    "n",
                );
                close(
                    (f(v, phi, n, vb + e, mu) - f(v, phi, n, vb - e, mu)) / (2.0 * EPS),
                    a.v_body[c],
                    "v_body",
                );
            }
            // φ moves v_min by h/Δt: 1e-5 m/s, well inside the switches skipped above.
            let h = 1e-8;
            close(
                (f(v, phi + h, n, vb, mu) - f(v, phi - h, n, vb, mu)) / (2.0 * h),
                a.phi,
                "phi",
            );
            close(
                (f(v, phi, n, vb, mu + EPS) - f(v, phi, n, vb, mu - EPS)) / (2.0 * EPS),
                a.mu,
                "mu",
            );
        }
        assert!(
            checked > 2000 && in_band > 100,
            "{checked}, {in_band} in the soft band"
        );
    }

    /// Powder resting against a wall sits exactly at `v·n = v_min`. There the hard projection's
    /// adjoint takes one branch while the central difference averages the two; the soft one is
    /// differentiable, and its adjoint is the central difference.
    #[test]
    fn at_rest_against_a_wall_only_the_soft_projection_is_differentiable() {
        let (dt, margin, n) = (1e-3, 1e-5, DVec3::Y);
        // At the clearance, at rest: v_min = 0 = v·n.
        let (v, phi, w) = (
            DVec3::new(0.01, 0.0, 0.0),
            margin,
            DVec3::new(0.3, 1.0, 0.2),
        );
        let eps = 1e-7;
        for (soft, differentiable) in [(0.0, false), (soft_speed(true, margin, dt), true)] {
            let f = |v: DVec3| {
                project_particle(
                    v,
                    (phi, n, DVec3::ZERO),
                    &ContactRule::new(dt, margin, ContactMode::Slip, 0.3, soft),
                )
                .dot(w)
            };
            let fd = (f(v + n * eps) - f(v - n * eps)) / (2.0 * eps);
            let a = project_particle_adj(
                v,
                (phi, n, DVec3::ZERO),
                &ContactRule::new(dt, margin, ContactMode::Slip, 0.3, soft),
                w,
            );
            let agrees = (fd - a.v.y).abs() <= 1e-6 * fd.abs().max(1.0);
            assert_eq!(
                agrees, differentiable,
                "soft {soft}: fd {fd}, adjoint {}",
                a.v.y
            );
        }
    }

    /// The soft projection never lets a particle closer than the hard one does: its normal
    /// speed is at least `v_min`, and it leaves every particle with `v·n ≥ v_min + τ` alone.
    #[test]
    fn the_soft_projection_keeps_the_clearance() {
        let mut rng = crate::util::SplitMix64(5);
        let mut r = || rng.uniform_in(-1.0, 1.0);
        let (dt, margin) = (1e-3, 1e-5);
        let soft = 0.2;
        for _ in 0..20000 {
            let v = DVec3::new(r(), r(), r());
            let n = DVec3::new(r(), r(), r()).normalize();
            let vb = 0.3 * DVec3::new(r(), r(), r());
            let phi = 1e-3 * r();
            let v_min = vb.dot(n).max(0.0) + (margin - phi) / dt;
            let out = project_particle(
                v,
                (phi, n, vb),
                &ContactRule::new(dt, margin, ContactMode::Slip, 0.4, soft),
            );
            assert!(out.dot(n) >= v_min - 1e-12, "{out} below {v_min}");
            if v.dot(n) >= v_min + soft {
                assert_eq!(out, v);
            }
        }
    }

    #[test]
    fn projection_keeps_the_particle_outside_to_first_order() {
        let n = DVec3::Y;
        let dt = 1e-3;
        // 0.1 mm above the surface, moving down at 1 m/s: would end 0.9 mm inside.
        let v = project_particle(
            DVec3::new(0.2, -1.0, 0.0),
            (1e-4, n, DVec3::ZERO),
            &ContactRule::new(dt, 1e-5, ContactMode::Separate, 0.0, 0.0),
        );
        assert!((1e-4 + dt * v.y - 1e-5).abs() < 1e-15);
        assert_eq!(v.x, 0.2);
        // Friction takes μ·Δv_n off the tangential speed.
        let vf = project_particle(
            DVec3::new(0.2, -1.0, 0.0),
            (1e-4, n, DVec3::ZERO),
            &ContactRule::new(dt, 1e-5, ContactMode::Separate, 0.1, 0.0),
        );
        assert!((vf.x - (0.2 - 0.1 * 0.91)).abs() < 1e-12);
        // A particle that cannot reach the wall is untouched.
        let w = DVec3::new(0.0, -0.01, 0.0);
        assert_eq!(
            project_particle(
                w,
                (1e-3, n, DVec3::ZERO),
                &ContactRule::new(dt, 1e-5, ContactMode::Separate, 0.5, 0.0)
            ),
            w
        );
    }

    #[test]
    fn skipping_a_clear_particle_is_exact() {
        // Whenever `clear_of` lets a particle skip the projection, the projection would have
        // returned it unchanged, for approaching and receding surfaces alike.
        let mut rng = crate::util::SplitMix64(11);
        let mut r = || rng.uniform_in(-1.0, 1.0);
        let (dt, margin) = (1e-3, 1e-5);
        let mut skipped = 0;
        for k in 0..20000 {
            let v = DVec3::new(r(), r(), r());
            let n = DVec3::new(r(), r(), r()).normalize();
            let vb = DVec3::new(r(), r(), r());
            let phi = 3e-3 * r();
            let mode = ContactMode::ALL[k % 3];
            if clear_of(phi, margin, dt, v, vb) {
                skipped += 1;
                assert_eq!(
                    project_particle(
                        v,
                        (phi, n, vb),
                        &ContactRule::new(dt, margin, mode, 0.4, 0.0)
                    ),
                    v
                );
            }
            // The soft projection's skip test adds τ·Δt to the clearance.
            let soft = 0.2;
            if clear_of(phi, margin + soft * dt, dt, v, vb) {
                assert_eq!(
                    project_particle(
                        v,
                        (phi, n, vb),
                        &ContactRule::new(dt, margin, mode, 0.4, soft)
                    ),
                    v
                );
            }
        }
        assert!(skipped > 1000, "{skipped}");
    }
}
