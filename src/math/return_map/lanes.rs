//! The Drucker–Prager update of a group of particles at once: [`super::dp_update`] (that is
//! [`super::hencky`], [`super::dp_project_cohesive`], [`super::stretch`] and
//! [`super::kirchhoff_principal`]) written again over [`F64Bits`] lanes, operation for
//! operation, so that each lane's result is the scalar function's to the bit
//! (`lanes_equal_the_scalar_update` checks all three cases, the guards and a cohesive cone). The branches of the return mapping become selects: every lane computes the tip,
//! the elastic and the yield-surface results and keeps its own case's.
//!
//! [`dp_update_group`] runs four particles to an AVX register where the CPU has AVX2, which
//! takes the `ln` and `exp` (`crate::math::elementary`) out of the scalar loop.

use super::{Cone, DpUpdate, DEV_NORM_SQ_MIN, SIGMA_MIN};
use crate::math::elementary::{exp_lanes, ln_lanes};
use crate::math::lanes::{Arr, F64Bits, Vector};
use glam::DVec3;

/// Particles in a group.
pub const LANES: usize = 4;

type V3<V> = [V; 3];

/// [`DpUpdate`] of each lane, by axis.
struct LaneUpdate<V> {
    eps: V3<V>,
    eps_new: V3<V>,
    dq: V,
    sigma_new: V3<V>,
    tau: V3<V>,
}

#[inline(always)]
fn sum<V: Vector>(a: V3<V>) -> V {
    a[0] + a[1] + a[2]
}

#[inline(always)]
fn dot<V: Vector>(a: V3<V>, b: V3<V>) -> V {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The update of each lane: `σ` (three vectors of lanes, by axis), each lane's cone coefficient
/// `α`, and the cone (at `tr_c = 0` [`super::dp_project`], at any other
/// [`super::dp_project_cohesive`]). Loops, not closures: a closure that LLVM
/// declines to inline is compiled without the caller's AVX, and its intrinsics become calls.
#[inline(always)]
fn dp_update_body<V: F64Bits>(sigma: V3<V>, alpha: V, cone: Cone) -> LaneUpdate<V> {
    let Cone { mu, lambda, tr_c } = cone;
    let zero = V::splat(0.0);
    // hencky: glam's max keeps the bound where σ is not above it (NaN included).
    let lo = V::splat(SIGMA_MIN);
    let mut eps = sigma;
    for a in 0..3 {
        eps[a] = ln_lanes(V::select(lo.lt(sigma[a]), sigma[a], lo));
    }
    // dp_project_cohesive: the cohesionless projection of `ε − tr_c/3`, moved back (at
    // `tr_c = 0`, dp_project itself: no shift at all, as in the scalar code).
    let cohesive = tr_c != 0.0;
    let shift = V::splat(tr_c / 3.0);
    let mut e = eps;
    if cohesive {
        for a in 0..3 {
            e[a] = eps[a] - shift;
        }
    }
    let tr = sum(e);
    let tip = zero.le(tr);
    let third = tr / V::splat(3.0);
    let mut dev = e;
    for a in 0..3 {
        dev[a] = e[a] - third;
    }
    let dn2 = dot(dev, dev);
    let floor = V::splat(DEV_NORM_SQ_MIN);
    let dev_norm = V::select(floor.lt(dn2), dn2, floor).sqrt();
    let k = (3.0 * lambda + 2.0 * mu) / (2.0 * mu);
    let dgamma = dev_norm + V::splat(k) * alpha * tr;
    let elastic = dgamma.le(zero);
    let scale = dgamma / dev_norm;
    let mut eps_new = e;
    for a in 0..3 {
        let yielded = e[a] - dev[a] * scale;
        eps_new[a] = V::select(tip, zero, V::select(elastic, e[a], yielded));
        if cohesive {
            eps_new[a] = eps_new[a] + shift;
        }
    }
    let dq = V::select(tip, dot(e, e).sqrt(), V::select(elastic, zero, dgamma));
    // stretch and kirchhoff_principal
    let (two_mu, volumetric) = (V::splat(2.0 * mu), V::splat(lambda) * sum(eps_new));
    let (mut sigma_new, mut tau) = (eps_new, eps_new);
    for a in 0..3 {
        sigma_new[a] = exp_lanes(eps_new[a]);
        tau[a] = two_mu * eps_new[a] + volumetric;
    }
    LaneUpdate {
        eps,
        eps_new,
        dq,
        sigma_new,
        tau,
    }
}

/// [`dp_update_body`] on `LANES` particles given as vectors and scalars.
#[inline(always)]
fn dp_update_packed<V: F64Bits>(
    sigma: &[DVec3; LANES],
    alpha: &[f64; LANES],
    cone: Cone,
) -> [DpUpdate; LANES] {
    let mut by_axis = [[0.0; LANES]; 3];
    for (l, s) in sigma.iter().enumerate() {
        for a in 0..3 {
            by_axis[a][l] = s[a];
        }
    }
    let sv = [
        V::load(&by_axis[0]),
        V::load(&by_axis[1]),
        V::load(&by_axis[2]),
    ];
    let r = dp_update_body(sv, V::load(alpha), cone);
    let mut out = [[[0.0; LANES]; 3]; 4];
    let by_field = [&r.eps, &r.eps_new, &r.sigma_new, &r.tau];
    for q in 0..4 {
        for a in 0..3 {
            by_field[q][a].store(&mut out[q][a]);
        }
    }
    let mut dq = [0.0; LANES];
    r.dq.store(&mut dq);
    let vec = |q: usize, l: usize| DVec3::new(out[q][0][l], out[q][1][l], out[q][2][l]);
    std::array::from_fn(|l| DpUpdate {
        eps: vec(0, l),
        eps_new: vec(1, l),
        dq: dq[l],
        sigma_new: vec(2, l),
        tau: vec(3, l),
    })
}

/// The Drucker–Prager update (`ε = ln σ`, the return mapping of the cone with apex trace
/// `tr_c`, `exp ε′`, `τ_p`) of `LANES` particles, lane `l` at `sigma[l]` with cone coefficient
/// `alpha[l]`: each the scalar functions' result to the bit, in AVX registers where the CPU has
/// AVX2.
pub fn dp_update_group(
    sigma: &[DVec3; LANES],
    alpha: &[f64; LANES],
    cone: Cone,
) -> [DpUpdate; LANES] {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, which is all the function's target features ask for.
        return unsafe { dp_update_avx2(sigma, alpha, cone) };
    }
    dp_update_packed::<Arr<f64, LANES>>(sigma, alpha, cone)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn dp_update_avx2(sigma: &[DVec3; LANES], alpha: &[f64; LANES], cone: Cone) -> [DpUpdate; LANES] {
    dp_update_packed::<crate::math::lanes::F64x4>(sigma, alpha, cone)
}

#[cfg(test)]
mod tests {
    use super::super::{cohesion_trace, dp_alpha, dp_project_cohesive, dp_update, hencky, lame};
    use super::*;

    fn bits(u: &DpUpdate) -> Vec<u64> {
        [u.eps, u.eps_new, u.sigma_new, u.tau]
            .iter()
            .flat_map(|v| v.to_array())
            .chain([u.dq])
            .map(f64::to_bits)
            .collect()
    }

    /// Every lane is the scalar update's to the bit, in the portable lanes and in AVX
    /// registers, on stretches that take each case (expansion to the tip, inside the cone,
    /// onto the yield surface), the guards (`σ` at and below `SIGMA_MIN`, inverted, `σ = 1`
    /// where `ε̂ = 0`) and non-finite input, for cohesionless and cohesive cones.
    #[test]
    fn lanes_equal_the_scalar_update() {
        let (mu, lambda) = lame(3.5e5, 0.3);
        let mut cases = Vec::new();
        for i in 0..4000 {
            let t = i as f64;
            let s = |k: f64| 1.0 + 0.08 * (t * k).sin() + 0.02 * (t * k * 3.1).cos();
            let sigma = DVec3::new(s(0.37), s(0.71), s(1.13));
            cases.push((sigma, dp_alpha(20.0 + (t * 0.19).sin().abs() * 30.0)));
        }
        for sigma in [
            DVec3::ONE,
            DVec3::new(1e-7, 1.0, 1.0),
            DVec3::new(-0.5, 1.0, 1.0),
            DVec3::new(1e-6, 1e-6, 2.0),
            DVec3::new(f64::NAN, 1.0, 1.0),
            DVec3::new(f64::INFINITY, 1.0, 0.9),
            DVec3::new(0.0, -0.0, 1e300),
        ] {
            cases.push((sigma, dp_alpha(30.0)));
        }
        while cases.len() % LANES != 0 {
            cases.push((DVec3::ONE, 0.1));
        }
        // A cohesion of 20 Pa puts the apex at a strain trace of about 1e-4, within the spread
        // of the stretches above, so the shifted cone takes all three cases too.
        for tr_c in [0.0, cohesion_trace(20.0, 30.0, mu, lambda)] {
            let mut seen = [false; 3];
            for (sigma, alpha) in &cases {
                let (_, _, case) = dp_project_cohesive(hencky(*sigma), mu, lambda, *alpha, tr_c);
                seen[case as usize] = true;
            }
            assert_eq!(
                seen, [true; 3],
                "every return-mapping case at tr_c = {tr_c:e}"
            );
            for group in cases.chunks_exact(LANES) {
                let sigma: [DVec3; LANES] = std::array::from_fn(|l| group[l].0);
                let alpha: [f64; LANES] = std::array::from_fn(|l| group[l].1);
                let cone = Cone { mu, lambda, tr_c };
                let portable = dp_update_packed::<Arr<f64, LANES>>(&sigma, &alpha, cone);
                let dispatched = dp_update_group(&sigma, &alpha, cone);
                for l in 0..LANES {
                    let want = bits(&dp_update(sigma[l], alpha[l], cone));
                    assert_eq!(bits(&portable[l]), want, "portable lane at {:?}", sigma[l]);
                    assert_eq!(bits(&dispatched[l]), want, "AVX lane at {:?}", sigma[l]);
                }
            }
        }
    }
}
