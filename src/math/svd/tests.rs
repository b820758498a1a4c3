//! The SVD against reconstruction, orthogonality and its four-lane twin, and its adjoint
//! against central differences.

use super::lanes::{svd3_warm_lanes_body, svd3_warm_lanes_f32_body};
use super::*;

/// Reconstruction and orthogonality error allowed, relative to ‖F‖, in f64.
const RECON_TOL: f64 = 1e-12;

fn check(f: DMat3) {
    let d = svd3(f);
    let recon = d.u * DMat3::from_diagonal(d.s) * d.v.transpose();
    let scale = f
        .to_cols_array()
        .iter()
        .map(|x| x.abs())
        .fold(1e-300, f64::max);
    let err = (recon - f)
        .to_cols_array()
        .iter()
        .map(|x| x.abs())
        .fold(0.0, f64::max);
    assert!(err <= RECON_TOL * scale, "recon err {err} for {f:?}");
    for m in [d.u, d.v] {
        let e = (m.transpose() * m - DMat3::IDENTITY)
            .to_cols_array()
            .iter()
            .map(|x| x.abs())
            .fold(0.0, f64::max);
        assert!(e < RECON_TOL, "orthogonality {e}");
        assert!((m.determinant() - 1.0).abs() < RECON_TOL);
    }
    assert!(
        d.s.x >= d.s.y && d.s.y >= d.s.z.abs() - RECON_TOL * scale,
        "{:?}",
        d.s
    );
    assert!(d.s.x >= 0.0 && d.s.y >= 0.0);
    if d.s.z.abs() > RECON_TOL * scale {
        assert_eq!(d.s.z < 0.0, f.determinant() < 0.0);
    }
}

/// The tests' fixed stream in [−1, 1) ([`crate::util::Lcg`]).
use crate::util::lcg_symmetric as lcg;

#[test]
fn random_matrices() {
    let mut s = 7;
    for _ in 0..2000 {
        let f = DMat3::from_cols_array(&std::array::from_fn(|_| lcg(&mut s)));
        check(f);
        check(DMat3::IDENTITY + 0.01 * f);
    }
}

#[test]
fn warm_start_gives_the_same_decomposition() {
    let mut s = 9;
    for _ in 0..500 {
        let f =
            DMat3::IDENTITY + 0.3 * DMat3::from_cols_array(&std::array::from_fn(|_| lcg(&mut s)));
        let cold = svd3(f);
        let g = f + 1e-3 * DMat3::from_cols_array(&std::array::from_fn(|_| lcg(&mut s)));
        let warm = svd3_warm(g, cold.v);
        let again = svd3(g);
        assert!(
            (warm.s - again.s).abs().max_element() < 1e-13,
            "{:?} vs {:?}",
            warm.s,
            again.s
        );
        let recon = warm.u * DMat3::from_diagonal(warm.s) * warm.v.transpose();
        assert!((recon - g).to_cols_array().iter().all(|x| x.abs() < 1e-13));
    }
}

/// Central differences in f64 with step 1e-6 resolve a smooth function to ~1e-9 relative;
/// the adjoint must agree to 1e-6 relative.
const ADJ_REL_TOL: f64 = 1e-6;
const FD_EPS: f64 = 1e-6;

fn weighted(d: &Svd3, wu: DMat3, ws: DVec3, wv: DMat3) -> f64 {
    let dot = |a: DMat3, b: DMat3| {
        a.to_cols_array()
            .iter()
            .zip(b.to_cols_array())
            .map(|(x, y)| x * y)
            .sum::<f64>()
    };
    dot(d.u, wu) + d.s.dot(ws) + dot(d.v, wv)
}

#[test]
fn adjoint_matches_central_differences() {
    let mut seed = 21;
    let mut rnd =
        |scale: f64| DMat3::from_cols_array(&std::array::from_fn(|_| scale * lcg(&mut seed)));
    for case in 0..200 {
        let f = DMat3::IDENTITY + rnd(0.4);
        let (wu, wv) = (rnd(1.0), rnd(1.0));
        let ws = DVec3::new(0.3, -0.7, 1.1);
        let d = svd3(f);
        // Well separated singular values only: the FD check needs a smooth neighbourhood.
        let gap = (d.s.x - d.s.y).min(d.s.y - d.s.z);
        if gap < 0.05 {
            continue;
        }
        let g = svd3_adj(&d, wu, ws, wv);
        for c in 0..9 {
            let mut e = [0.0; 9];
            e[c] = FD_EPS;
            let de = DMat3::from_cols_array(&e);
            let fd = (weighted(&svd3(f + de), wu, ws, wv) - weighted(&svd3(f - de), wu, ws, wv))
                / (2.0 * FD_EPS);
            let ad = g.to_cols_array()[c];
            let scale = fd.abs().max(ad.abs()).max(1e-3);
            assert!(
                (fd - ad).abs() <= ADJ_REL_TOL * scale,
                "case {case} entry {c}: fd {fd} ad {ad}"
            );
        }
    }
}

/// Near-degenerate singular values: the guarded adjoint stays finite, and for a loss that is
/// a symmetric function of σ (here the Hencky energy) it matches finite differences.
#[test]
fn adjoint_near_equal_singular_values() {
    // Tolerance: the guard changes the rotational terms by O(gap/SVD_ADJ_GAP) where they
    // are O(gap) already; FD at eps 1e-6 resolves 1e-9 of this loss.
    const NEAR_TOL: f64 = 1e-6;
    let r = crate::math::pose::quat_from_rotation_vector(DVec3::new(0.2, 0.5, -0.3));
    for sig in [
        DVec3::new(1.0, 1.0, 1.0),
        DVec3::new(1.0 + 1e-9, 1.0, 1.0 - 1e-9),
        DVec3::new(1.1, 1.1, 0.9),
    ] {
        let f = DMat3::from_quat(r) * DMat3::from_diagonal(sig);
        let energy = |f: DMat3| {
            let s = svd3(f).s;
            let e = DVec3::new(s.x.ln(), s.y.ln(), s.z.ln());
            e.length_squared() + 0.5 * (e.x + e.y + e.z).powi(2)
        };
        let d = svd3(f);
        let e = DVec3::new(d.s.x.ln(), d.s.y.ln(), d.s.z.ln());
        let tr = e.x + e.y + e.z;
        let g_s = DVec3::new(
            (2.0 * e.x + tr) / d.s.x,
            (2.0 * e.y + tr) / d.s.y,
            (2.0 * e.z + tr) / d.s.z,
        );
        let g = svd3_adj(&d, DMat3::ZERO, g_s, DMat3::ZERO);
        assert!(g.is_finite());
        for c in 0..9 {
            let mut v = [0.0; 9];
            v[c] = FD_EPS;
            let de = DMat3::from_cols_array(&v);
            let fd = (energy(f + de) - energy(f - de)) / (2.0 * FD_EPS);
            let ad = g.to_cols_array()[c];
            assert!(
                (fd - ad).abs() <= NEAR_TOL * fd.abs().max(ad.abs()).max(1e-3),
                "σ {sig:?} entry {c}: fd {fd} ad {ad}"
            );
        }
    }
}

#[test]
fn degenerate_cases() {
    check(DMat3::IDENTITY);
    check(DMat3::ZERO);
    check(DMat3::from_diagonal(DVec3::new(1.0, 1.0, 1e-9)));
    check(DMat3::from_diagonal(DVec3::new(2.0, 2.0, 2.0 + 1e-13)));
    check(DMat3::from_diagonal(DVec3::new(1.0, -1.0, 1.0)));
    check(DMat3::from_diagonal(DVec3::new(1e-8, 1e-8, 1e-8)));
    // rank one
    let a = DVec3::new(1.0, 2.0, 3.0);
    check(DMat3::from_cols(a, 2.0 * a, -a));
    // rotation times near-equal stretch
    let r = crate::math::pose::quat_from_rotation_vector(DVec3::new(0.3, -1.1, 0.4));
    check(DMat3::from_quat(r) * DMat3::from_diagonal(DVec3::new(1.0, 1.0 + 1e-10, 1.0 - 1e-10)));
}

fn bits(d: &Svd3) -> Vec<u64> {
    [d.u.to_cols_array(), d.v.to_cols_array()]
        .concat()
        .into_iter()
        .chain(d.s.to_array())
        .map(f64::to_bits)
        .collect()
}

/// The lane version must equal the scalar one bit for bit, whatever its lane neighbours:
/// lanes mix warm-started, cold, degenerate, inverted and already decomposed matrices, which
/// need 0 to 6 sweeps.
#[test]
fn lanes_are_bitwise_equal_to_scalar() {
    let mut s = 11;
    let r = DMat3::from_quat(crate::math::pose::quat_from_rotation_vector(DVec3::new(
        0.3, -1.1, 0.4,
    )));
    let special = [
        DMat3::IDENTITY,
        DMat3::ZERO,
        DMat3::from_diagonal(DVec3::new(1.0, 1.0, 1e-9)),
        DMat3::from_diagonal(DVec3::new(2.0, 2.0, 2.0 + 1e-13)),
        DMat3::from_diagonal(DVec3::new(1.0, -1.0, 1.0)),
        DMat3::from_diagonal(DVec3::new(1e-8, 1e-8, 1e-8)),
        DMat3::from_cols(DVec3::X, 2.0 * DVec3::X, -DVec3::X),
        r * DMat3::from_diagonal(DVec3::new(1.0, 1.0 + 1e-10, 1.0 - 1e-10)),
    ];
    for k in 0..3000 {
        let mut rnd = || DMat3::from_cols_array(&std::array::from_fn(|_| lcg(&mut s)));
        let (f, v0): (Vec<DMat3>, Vec<DMat3>) = (0..LANES)
            .map(|l| match (k + 3 * l) % 7 {
                0 => (special[(k + l) % special.len()], DMat3::IDENTITY),
                1 => (rnd(), DMat3::IDENTITY),
                2 => (rnd(), svd3(rnd()).v),
                3 => {
                    let f = DMat3::IDENTITY + 0.3 * rnd();
                    let v0 = svd3(f).v;
                    (f + 1e-4 * rnd(), v0)
                }
                4 => (-(DMat3::IDENTITY + 0.01 * rnd()), r),
                // Nearly converged warm starts: `VᵀFᵀFV` is symmetric only to round-off and
                // some rotations are skipped as tiny while others are not.
                5 => {
                    let f = DMat3::IDENTITY + 0.01 * rnd();
                    (f, svd3(f).v)
                }
                _ => {
                    let f = DMat3::IDENTITY + 0.01 * rnd();
                    let v0 = svd3(f).v;
                    (f + 1e-9 * rnd(), v0)
                }
            })
            .unzip();
        let (f, v0): ([DMat3; LANES], [DMat3; LANES]) =
            (f.try_into().unwrap(), v0.try_into().unwrap());
        // The dispatched path (AVX2 where the CPU has it) and the baseline build.
        for together in [
            svd3_warm_lanes(&f, &v0),
            svd3_warm_lanes_body::<crate::math::lanes::Arr<f64, LANES>>(&f, &v0),
        ] {
            for l in 0..LANES {
                assert_eq!(
                    bits(&together[l]),
                    bits(&svd3_warm(f[l], v0[l])),
                    "lane {l} of case {k}: {:?}",
                    f[l]
                );
            }
        }
    }
}

/// The rotation of `θ` by the general formula is the small-angle shortcut's, `t = 0.5/θ` and
/// `c = 1`, to the bit.
fn assert_small_angle_exact<T>(theta: T, bits: fn(T) -> u64)
where
    T: SvdReal + crate::math::lanes::Real + std::fmt::LowerExp,
{
    assert!(theta.abs() >= T::SMALL_ANGLE_THETA && theta.abs() <= T::HUGE_THETA);
    let root = (theta * theta + T::ONE).sqrt();
    let t = theta.signum() / (theta.abs() + root);
    let c = T::ONE / (t * t + T::ONE).sqrt();
    assert_eq!(bits(t), bits(T::HALF / theta), "θ = {theta:e}");
    assert!(c == T::ONE, "θ = {theta:e}");
}

/// `count` values `±m·2^e` for each binade `e` of `binades`: `m = 1` first, then random
/// mantissas of `digits` bits (exact in the type tested), the signs alternating.
fn binade_samples(
    binades: std::ops::RangeInclusive<i32>,
    count: usize,
    digits: u32,
    seed: u64,
) -> impl Iterator<Item = f64> {
    let mut rng = crate::util::Lcg(seed);
    binades.flat_map(move |e| {
        (0..count)
            .map(|k| {
                let bits = rng.next_u64();
                let m = if k == 0 {
                    1.0
                } else {
                    1.0 + (bits >> (64 - digits)) as f64 / (1u64 << digits) as f64
                };
                let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
                sign * m * 2f64.powi(e)
            })
            .collect::<Vec<_>>()
    })
}

/// The small-angle shortcut of the lane rotation is the general formula's result to the bit:
/// for every `|θ| ≥ 2²⁷` (below the 1e150 branch), `sign(θ)/(|θ| + √(θ² + 1))` is `0.5/θ` and
/// `1/√(t² + 1)` is 1. Checked over every binade from 2²⁷ up, with random mantissas and both
/// signs, and at the bound itself.
#[test]
fn small_angle_rotation_is_exact() {
    let thetas = binade_samples(27..=497, 2000, 52, 5);
    assert_eq!(
        thetas
            .map(|t| assert_small_angle_exact(t, f64::to_bits))
            .count(),
        942_000
    );
}

/// f32's shortcut likewise: every `|θ|` from 2¹³ up to the `HUGE_THETA` branch (1e18).
#[test]
fn small_angle_rotation_is_exact_in_f32() {
    let thetas = binade_samples(13..=58, 20_000, 23, 9);
    let bits = |x: f32| u64::from(x.to_bits());
    assert_eq!(
        thetas
            .map(|t| assert_small_angle_exact(t as f32, bits))
            .count(),
        920_000
    );
}

/// What f32 can hold: a decomposition good to a few ulps of f32 (ε = 1.2e-7) relative to
/// `‖F‖`, for the matrices a simulation meets and for the degenerate ones.
const F32_TOL: f64 = 2e-6;

/// The f32 lanes give the SVD of `F` to f32's precision (reconstruction, orthonormal factors
/// with det +1, σ sorted and equal to the f64 SVD's), the same bits dispatched (AVX2) and in
/// the baseline build, and a lane's result does not depend on its neighbours.
#[test]
fn f32_lanes_decompose_to_f32_precision() {
    let mut s = 23;
    let r = DMat3::from_quat(crate::math::pose::quat_from_rotation_vector(DVec3::new(
        -0.7, 0.2, 1.3,
    )));
    let special = [
        DMat3::IDENTITY,
        DMat3::ZERO,
        DMat3::from_diagonal(DVec3::new(1.0, 1.0, 1e-5)),
        DMat3::from_diagonal(DVec3::new(1.0, -1.0, 1.0)),
        r * DMat3::from_diagonal(DVec3::new(1.0, 1.0 + 1e-6, 1.0 - 1e-6)),
        DMat3::from_cols(DVec3::X, 2.0 * DVec3::X, -DVec3::X),
        // Met on `sand_box`: entries whose squares underflow f32, under a permuting warm start.
        DMat3::from_cols(
            DVec3::new(1.0, 1.2e-19, -4.1e-23),
            DVec3::new(-4.7e-20, 0.9997, -3.2e-8),
            DVec3::new(-7.4e-24, 8.7e-24, 1.0000003),
        ),
    ];
    let max_abs = |m: DMat3| m.to_cols_array().iter().fold(0.0f64, |a, x| a.max(x.abs()));
    for k in 0..2000 {
        let mut rnd = || DMat3::from_cols_array(&std::array::from_fn(|_| lcg(&mut s)));
        let (f, v0): (Vec<DMat3>, Vec<DMat3>) = (0..LANES_F32)
            .map(|l| match (k + 3 * l) % 5 {
                0 => (special[(k + l) % special.len()], DMat3::IDENTITY),
                1 if l % 2 == 0 => (rnd(), DMat3::IDENTITY),
                1 => (
                    special[(k + l) % special.len()],
                    DMat3::from_cols(DVec3::X, DVec3::Z, -DVec3::Y),
                ),
                2 => {
                    let f = DMat3::IDENTITY + 0.3 * rnd();
                    let v0 = svd3(f).v;
                    (f + 1e-4 * rnd(), v0)
                }
                3 => (-(DMat3::IDENTITY + 0.01 * rnd()), r),
                _ => (r * (DMat3::IDENTITY + 0.02 * rnd()), svd3(rnd()).v),
            })
            .unzip();
        let (f, v0): ([DMat3; LANES_F32], [DMat3; LANES_F32]) =
            (f.try_into().unwrap(), v0.try_into().unwrap());
        let got = svd3_warm_lanes_f32(&f, &v0);
        let base = svd3_warm_lanes_f32_body::<crate::math::lanes::Arr<f32, LANES_F32>>(&f, &v0);
        // Lanes rotated by one place: each matrix meets other neighbours.
        let rot = |m: &[DMat3; LANES_F32]| -> [DMat3; LANES_F32] {
            std::array::from_fn(|l| m[(l + 1) % LANES_F32])
        };
        let shifted = svd3_warm_lanes_f32(&rot(&f), &rot(&v0));
        for l in 0..LANES_F32 {
            let d = &got[l];
            assert_eq!(bits(d), bits(&base[l]), "AVX2 against baseline, lane {l}");
            assert_eq!(bits(&shifted[(l + LANES_F32 - 1) % LANES_F32]), bits(d));
            let scale = max_abs(f[l]).max(1e-30);
            let recon = d.u * DMat3::from_diagonal(d.s) * d.v.transpose();
            assert!(
                max_abs(recon - f[l]) <= F32_TOL * scale,
                "reconstruction {:e} for {:?}",
                max_abs(recon - f[l]),
                f[l]
            );
            for m in [d.u, d.v] {
                assert!(max_abs(m.transpose() * m - DMat3::IDENTITY) < F32_TOL);
                assert!((m.determinant() - 1.0).abs() < F32_TOL);
            }
            let exact = svd3(f[l]).s;
            assert!(
                max_abs(DMat3::from_diagonal(d.s - exact)) <= F32_TOL * scale,
                "σ {:?} against {:?}",
                d.s,
                exact
            );
        }
    }
}

/// A short group (the end of a particle array) is padded with identities, and a full one goes
/// to the kernel in place: either way each of its matrices gets `svd3_warm`'s bits, in f64,
/// and the f32 kernel's own bits.
#[test]
fn short_groups_give_each_matrix_its_own_decomposition() {
    let mut s = 31;
    for len in 1..=LANES_F32 {
        let f: Vec<DMat3> = (0..len)
            .map(|_| {
                DMat3::IDENTITY
                    + 0.2 * DMat3::from_cols_array(&std::array::from_fn(|_| lcg(&mut s)))
            })
            .collect();
        let v0: Vec<DMat3> = f
            .iter()
            .map(|m| svd3(*m + 0.01 * DMat3::IDENTITY).v)
            .collect();
        if len <= LANES {
            let group = svd3_warm_group(svd3_warm_lanes, &f, &v0);
            assert_eq!(group.len(), len, "f64: one result a matrix");
            for (i, d) in group.enumerate() {
                assert_eq!(
                    bits(&d),
                    bits(&svd3_warm(f[i], v0[i])),
                    "f64, {len} matrices"
                );
            }
        }
        let mut full: [DMat3; LANES_F32] =
            std::array::from_fn(|l| DMat3::from_diagonal(DVec3::splat(1.0 + l as f64)));
        let mut full_v0 = [DMat3::IDENTITY; LANES_F32];
        full[..len].copy_from_slice(&f);
        full_v0[..len].copy_from_slice(&v0);
        let alone = svd3_warm_lanes_f32(&full, &full_v0);
        let group = svd3_warm_group(svd3_warm_lanes_f32, &f, &v0);
        assert_eq!(group.len(), len, "f32: one result a matrix");
        for (i, d) in group.enumerate() {
            assert_eq!(bits(&d), bits(&alone[i]), "f32, {len} matrices");
        }
    }
}
