//! The SVD of several matrices at once, one per SIMD lane, by the algorithm of [`svd3_warm`]:
//! [`LANES`] in f64, bitwise equal to [`svd3_warm`] on each, and [`LANES_F32`] in f32, for the
//! scenes that ask for it (`simulation.svd: F32`, `crate::systems::svd`).
//!
//! The kernel is written once over [`Vector`] (`crate::math::lanes`): AVX registers (four f64
//! or eight f32) where the CPU has AVX2, arrays elsewhere, to the same bits. The lanes'
//! independent dependency chains hide the latency of `sqrt` and `/`. A lane whose Jacobi
//! iteration has converged is masked out of the further sweeps of the others, so a lane's result
//! never depends on its neighbours. The kernel has no closures over vectors: a closure is
//! compiled apart from the AVX function that calls it, and its intrinsics become calls.

#[cfg(doc)]
use super::svd3_warm;
use super::{from_rows, to_rows, Svd3, MAX_SWEEPS, OFF_DIAG_REL};
use crate::math::lanes::{Arr, Mask, Real, Vector, MAX_LANES};
#[cfg(target_arch = "x86_64")]
use crate::math::lanes::{F32x8, F64x4};
use glam::{DMat3, DVec3};

/// f64 matrices decomposed together by [`svd3_warm_lanes`].
pub const LANES: usize = 4;
/// f32 matrices decomposed together by [`svd3_warm_lanes_f32`] (one AVX register).
pub const LANES_F32: usize = 8;

/// The iteration's thresholds for a precision.
pub trait SvdReal: Real {
    const HALF: Self;
    const TWO: Self;
    /// A rotation is skipped where `|a_pq|` is below this fraction of `|a_pp| + |a_qq|`.
    const OFF_DIAG_REL: Self;
    /// The iteration stops where the off-diagonal is below this fraction of the diagonal.
    const CONVERGED_REL: Self;
    /// From this `|θ|` on, a rotation's general formula gives exactly `t = 0.5/θ`, `c = 1`.
    const SMALL_ANGLE_THETA: Self;
    /// Above this `|θ|`, `θ²` could overflow: `t = 0.5/θ` is used.
    const HUGE_THETA: Self;
}

impl SvdReal for f64 {
    const HALF: f64 = 0.5;
    const TWO: f64 = 2.0;
    const OFF_DIAG_REL: f64 = OFF_DIAG_REL;
    /// The scalar `converged`'s 1e-17: f64 round-off.
    const CONVERGED_REL: f64 = 1e-17;
    /// 2²⁷: `θ²` is at least 2⁵⁴, so adding 1 is below half its ulp, and `|t| ≤ 2⁻²⁸`, so `t²`
    /// is below half an ulp of 1.
    const SMALL_ANGLE_THETA: f64 = (1u64 << 27) as f64;
    const HUGE_THETA: f64 = 1e150;
}

impl SvdReal for f32 {
    const HALF: f32 = 0.5;
    const TWO: f32 = 2.0;
    /// About ε²/50, as f64's 1e-18 is: far below what a rotation could change.
    const OFF_DIAG_REL: f32 = 3e-16;
    /// f32's ε (2⁻²³): a further rotation would turn `V` by less than f32 resolves.
    const CONVERGED_REL: f32 = f32::EPSILON;
    /// 2¹³: `θ²` is at least 2²⁶, whose half ulp is 4, and `|t| ≤ 2⁻¹⁴`, so `t² ≤ 2⁻²⁸` is
    /// below half an ulp of 1 (2⁻²⁴).
    const SMALL_ANGLE_THETA: f32 = (1u32 << 13) as f32;
    /// `θ²` stays below f32's largest number (3.4e38).
    const HUGE_THETA: f32 = 1e18;
}

/// A 3×3 matrix of lanes, by rows: `m[r][c]` is row `r`, column `c` of every lane's matrix.
type Rows<V> = [[V; 3]; 3];
/// A 3-vector of lanes, by component.
type Col<V> = [V; 3];

/// Which lanes' iteration has converged (the scalar `converged`, over [`Vector`]).
#[inline(always)]
fn converged<V: Vector>(a: &Rows<V>) -> V::Mask
where
    V::Scalar: SvdReal,
{
    let off = a[0][1].abs() + a[0][2].abs() + a[1][2].abs();
    let diag = a[0][0].abs() + a[1][1].abs() + a[2][2].abs();
    off.le(V::splat(V::Scalar::CONVERGED_REL) * diag) | off.eq(V::splat(V::Scalar::ZERO))
}

/// The scalar `jacobi_rotate` on every lane where `active` holds; the other lanes are left
/// untouched. Each lane computes exactly the operations of the scalar function, so in f64 the
/// results are bitwise equal to it.
#[inline(always)]
fn jacobi_rotate_lanes<V: Vector>(
    a: &mut Rows<V>,
    v: &mut Rows<V>,
    active: V::Mask,
    p: usize,
    q: usize,
    r: usize,
) where
    V::Scalar: SvdReal,
{
    let (apq, app, aqq) = (a[p][q], a[p][p], a[q][q]);
    let zero = V::splat(V::Scalar::ZERO);
    let one = V::splat(V::Scalar::ONE);
    let tiny = apq
        .abs()
        .le(V::splat(V::Scalar::OFF_DIAG_REL) * (app.abs() + aqq.abs()))
        | apq.eq(zero);
    let rot = active & !tiny;
    let theta = (aqq - app) / (V::splat(V::Scalar::TWO) * apq);
    let (t, c, sn) = if (!rot | V::splat(V::Scalar::SMALL_ANGLE_THETA).le(theta.abs())).all() {
        // Every rotating lane turns by a small angle (as in the last sweep of nearly every
        // decomposition): there the general formula below gives exactly `t = 0.5/θ`, `c = 1`,
        // `s = t`, since `θ² + 1` rounds to `θ²`, `√(θ²)` is `|θ|` in IEEE arithmetic, and
        // `t² + 1` rounds to 1. One division instead of three and two square roots on the
        // rotation's dependency chain, for the same bits (`small_angle_rotation_is_exact`).
        let t = V::splat(V::Scalar::HALF) / theta;
        (t, one, t)
    } else {
        let huge = V::splat(V::Scalar::HUGE_THETA).lt(theta.abs());
        let root = (theta * theta + one).sqrt();
        let t = V::select(
            huge,
            V::splat(V::Scalar::HALF) / theta,
            theta.signum() / (theta.abs() + root),
        );
        let c = one / (t * t + one).sqrt();
        (t, c, t * c)
    };
    a[p][p] = V::select(rot, app - t * apq, app);
    a[q][q] = V::select(rot, aqq + t * apq, aqq);
    let off = V::select(active, zero, apq);
    a[p][q] = off;
    a[q][p] = off;
    // `A` is symmetric only up to round-off on entry: a lane that does not rotate keeps both
    // triangles as they are, as the scalar function's early return does.
    let (arp, arq) = (a[r][p], a[r][q]);
    let rp = c * arp - sn * arq;
    let rq = sn * arp + c * arq;
    a[p][r] = V::select(rot, rp, a[p][r]);
    a[q][r] = V::select(rot, rq, a[q][r]);
    a[r][p] = V::select(rot, rp, arp);
    a[r][q] = V::select(rot, rq, arq);
    for row in v.iter_mut() {
        let (vp, vq) = (row[p], row[q]);
        row[p] = V::select(rot, c * vp - sn * vq, vp);
        row[q] = V::select(rot, sn * vp + c * vq, vq);
    }
}

/// The scalar `givens` on every lane (in f64 bitwise equal to it).
#[inline(always)]
fn givens_lanes<V: Vector>(b: &mut Rows<V>, q: &mut Rows<V>, j: usize, i: usize) {
    let (x, y) = (b[j][j], b[i][j]);
    let (zero, one) = (V::splat(V::Scalar::ZERO), V::splat(V::Scalar::ONE));
    let r2 = x * x + y * y;
    let nil = y.eq(zero) | r2.eq(zero);
    let keep = nil & zero.le(x);
    let inv_r = one / r2.sqrt();
    let c = V::select(nil, -one, x * inv_r);
    let s = V::select(nil, zero, y * inv_r);
    for k in 0..3 {
        let (bj, bi) = (b[j][k], b[i][k]);
        b[j][k] = V::select(keep, bj, c * bj + s * bi);
        b[i][k] = V::select(keep, bi, -s * bj + c * bi);
        let (qj, qi) = (q[k][j], q[k][i]);
        q[k][j] = V::select(keep, qj, c * qj + s * qi);
        q[k][i] = V::select(keep, qi, -s * qj + c * qi);
    }
}

/// Cyclic Jacobi on the symmetric `a` (each lane's `V₀ᵀ·FᵀF·V₀`), accumulated into `v` (each
/// lane's `V₀`), then `v`'s columns sorted by decreasing eigenvalue, each swap exchanging two
/// columns and negating the second so that `det V` stays +1.
#[inline(always)]
fn jacobi_sorted<V: Vector>(mut a: Rows<V>, mut v: Rows<V>) -> Rows<V>
where
    V::Scalar: SvdReal,
{
    let mut active = <V::Mask as Mask>::splat(true);
    for _ in 0..MAX_SWEEPS {
        active = active & !converged(&a);
        if !active.any() {
            break;
        }
        jacobi_rotate_lanes(&mut a, &mut v, active, 0, 1, 2);
        jacobi_rotate_lanes(&mut a, &mut v, active, 0, 2, 1);
        jacobi_rotate_lanes(&mut a, &mut v, active, 1, 2, 0);
    }
    let mut ev = [a[0][0], a[1][1], a[2][2]];
    for (i, j) in [(0, 1), (0, 2), (1, 2)] {
        let sw = ev[i].lt(ev[j]);
        let (ei, ej) = (ev[i], ev[j]);
        ev[i] = V::select(sw, ej, ei);
        ev[j] = V::select(sw, ei, ej);
        for row in v.iter_mut() {
            let (vi, vj) = (row[i], row[j]);
            row[i] = V::select(sw, vj, vi);
            row[j] = V::select(sw, -vi, vj);
        }
    }
    v
}

/// Givens QR of each lane's `B = F·V`: returns `(Q, R)`, `R`'s diagonal holding σ.
#[inline(always)]
fn qr<V: Vector>(mut b: Rows<V>) -> (Rows<V>, Rows<V>) {
    let (one, zero) = (V::splat(V::Scalar::ONE), V::splat(V::Scalar::ZERO));
    let mut q = [[one, zero, zero], [zero, one, zero], [zero, zero, one]];
    givens_lanes(&mut b, &mut q, 0, 1);
    givens_lanes(&mut b, &mut q, 0, 2);
    givens_lanes(&mut b, &mut q, 1, 2);
    (q, b)
}

/// `x·y` lane by lane, summed in glam's order (`((x₀y₀ + x₁y₁) + x₂y₂)` for each entry).
#[inline(always)]
fn mul<V: Vector>(x: &Rows<V>, y: &Rows<V>) -> Rows<V> {
    // Loops, not closures: a closure is compiled apart from the AVX function that calls it.
    let mut m = *x;
    for (r, row) in m.iter_mut().enumerate() {
        for (c, e) in row.iter_mut().enumerate() {
            *e = x[r][0] * y[0][c] + x[r][1] * y[1][c] + x[r][2] * y[2][c];
        }
    }
    m
}

#[inline(always)]
fn transpose<V: Vector>(x: &Rows<V>) -> Rows<V> {
    let mut m = *x;
    for (r, row) in m.iter_mut().enumerate() {
        for (c, e) in row.iter_mut().enumerate() {
            *e = x[c][r];
        }
    }
    m
}

/// Makes each lane's `V` a rotation again (Gram–Schmidt on its first two columns, the third
/// their cross product). An f32 rotation is orthonormal only to round-off, and each substep's
/// `V` starts from the last one's: without this the error would accumulate over the run.
#[inline(always)]
fn orthonormalize<V: Vector>(v: &mut Rows<V>) {
    let c0 = unit([v[0][0], v[1][0], v[2][0]]);
    let c1 = [v[0][1], v[1][1], v[2][1]];
    let d = dot(&c0, &c1);
    let c1 = unit([c1[0] - d * c0[0], c1[1] - d * c0[1], c1[2] - d * c0[2]]);
    let c2 = [
        c0[1] * c1[2] - c0[2] * c1[1],
        c0[2] * c1[0] - c0[0] * c1[2],
        c0[0] * c1[1] - c0[1] * c1[0],
    ];
    for r in 0..3 {
        (v[r][0], v[r][1], v[r][2]) = (c0[r], c1[r], c2[r]);
    }
}

#[inline(always)]
fn dot<V: Vector>(x: &Col<V>, y: &Col<V>) -> V {
    x[0] * y[0] + x[1] * y[1] + x[2] * y[2]
}

#[inline(always)]
fn unit<V: Vector>(x: Col<V>) -> Col<V> {
    let k = V::splat(V::Scalar::ONE) / dot(&x, &x).sqrt();
    [x[0] * k, x[1] * k, x[2] * k]
}

/// Lane `l` of the result is `m[l]`, a matrix by rows.
#[inline(always)]
fn pack<V: Vector>(m: &[[[V::Scalar; 3]; 3]]) -> Rows<V> {
    let mut out = [[V::splat(V::Scalar::ZERO); 3]; 3];
    let mut lanes = [V::Scalar::ZERO; MAX_LANES];
    for (r, row) in out.iter_mut().enumerate() {
        for (c, e) in row.iter_mut().enumerate() {
            for (x, ml) in lanes.iter_mut().zip(m) {
                *x = ml[r][c];
            }
            *e = V::load(&lanes);
        }
    }
    out
}

/// Every lane's matrix: `out[l]` is lane `l`'s, by rows.
#[inline(always)]
fn unpack<V: Vector>(m: &Rows<V>) -> [[[V::Scalar; 3]; 3]; MAX_LANES] {
    let mut out = [[[V::Scalar::ZERO; 3]; 3]; MAX_LANES];
    let mut lanes = [V::Scalar::ZERO; MAX_LANES];
    for r in 0..3 {
        for c in 0..3 {
            m[r][c].store(&mut lanes);
            for (o, x) in out.iter_mut().zip(lanes) {
                o[r][c] = x;
            }
        }
    }
    out
}

/// [`svd3_warm`] of [`LANES`] matrices at once, lane `l` from `f[l]` and `v0[l]`. Bitwise equal
/// to calling `svd3_warm` on each. The forward SVD stage runs on this: on `sand_box` (2 threads,
/// AVX2) the stage takes 0.90 s (`powderlab bench scenes/sand_box.ron --stages`), against 3.27 s
/// one matrix at a time, since the latency of the rotations' square roots and divisions overlaps
/// across lanes.
pub fn svd3_warm_lanes(f: &[DMat3; LANES], v0: &[DMat3; LANES]) -> [Svd3; LANES] {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, which is all the function's target features ask for.
        return unsafe { svd3_warm_lanes_avx2(f, v0) };
    }
    svd3_warm_lanes_body::<Arr<f64, LANES>>(f, v0)
}

/// A lane kernel ([`svd3_warm_lanes`] or [`svd3_warm_lanes_f32`]).
pub type Kernel<const N: usize> = fn(&[DMat3; N], &[DMat3; N]) -> [Svd3; N];

/// `kernel` on up to `N` matrices, `f[i]` warm-started from `v0[i]`: the decompositions of the
/// `f.len()` matrices, in order. A full group goes to the kernel where it lies (a copy of
/// dynamic length would be a `memcpy` call per group); a shorter one (the end of a particle
/// array) is padded with identities whose lanes are dropped: a lane's result does not depend on
/// its neighbours, so the padding changes no bit (in f64 the results are [`svd3_warm`]'s on
/// each matrix). The results are owned, so the caller may overwrite the warm starts with them.
#[inline(always)]
pub fn svd3_warm_group<const N: usize>(
    kernel: Kernel<N>,
    f: &[DMat3],
    v0: &[DMat3],
) -> std::iter::Take<std::array::IntoIter<Svd3, N>> {
    let out = match (<&[DMat3; N]>::try_from(f), <&[DMat3; N]>::try_from(v0)) {
        (Ok(f), Ok(v0)) => kernel(f, v0),
        _ => {
            let mut fl = [DMat3::IDENTITY; N];
            let mut vl = [DMat3::IDENTITY; N];
            fl[..f.len()].copy_from_slice(f);
            vl[..v0.len()].copy_from_slice(v0);
            kernel(&fl, &vl)
        }
    };
    out.into_iter().take(f.len())
}

/// [`svd3_warm_lanes_body`] in AVX registers (four f64 lanes each). Rust never fuses a multiply
/// and an add on its own, so the results are the same bits as the portable build's.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn svd3_warm_lanes_avx2(f: &[DMat3; LANES], v0: &[DMat3; LANES]) -> [Svd3; LANES] {
    svd3_warm_lanes_body::<F64x4>(f, v0)
}

#[inline(always)]
pub(super) fn svd3_warm_lanes_body<V: Vector<Scalar = f64>>(
    f: &[DMat3; LANES],
    v0: &[DMat3; LANES],
) -> [Svd3; LANES] {
    let mut a = [[[0.0; 3]; 3]; LANES];
    for (al, (f, v0)) in a.iter_mut().zip(f.iter().zip(v0)) {
        *al = to_rows(v0.transpose() * (f.transpose() * *f) * *v0);
    }
    let v = unpack(&jacobi_sorted(pack::<V>(&a), pack::<V>(&v0.map(to_rows))));
    let vm: [DMat3; LANES] = std::array::from_fn(|l| from_rows(v[l]));
    let mut b = [[[0.0; 3]; 3]; LANES];
    for (bl, (f, v)) in b.iter_mut().zip(f.iter().zip(&vm)) {
        *bl = to_rows(*f * *v);
    }
    let (q, b) = qr(pack::<V>(&b));
    let (q, b) = (unpack(&q), unpack(&b));
    std::array::from_fn(|l| Svd3 {
        u: from_rows(q[l]),
        s: DVec3::new(b[l][0][0], b[l][1][1], b[l][2][2]),
        v: vm[l],
    })
}

/// The SVD of [`LANES_F32`] matrices at once in f32, lane `l` from `f[l]` warm-started from
/// `v0[l]`, by the algorithm of [`svd3_warm`] with f32's thresholds ([`SvdReal`]), its `V` made
/// a rotation again at the end. The factors are those of `f` to f32's precision (about 1e-7 of
/// `‖F‖`: `f32_lanes_decompose_to_f32_precision`); a lane's result depends on its own inputs
/// only, so it is the same for any grouping of the particles.
pub fn svd3_warm_lanes_f32(f: &[DMat3; LANES_F32], v0: &[DMat3; LANES_F32]) -> [Svd3; LANES_F32] {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, which is all the function's target features ask for.
        return unsafe { svd3_warm_lanes_f32_avx2(f, v0) };
    }
    svd3_warm_lanes_f32_body::<Arr<f32, LANES_F32>>(f, v0)
}

/// [`svd3_warm_lanes_f32_body`] in AVX registers (eight f32 lanes each), to the same bits as the
/// portable build's.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn svd3_warm_lanes_f32_avx2(f: &[DMat3; LANES_F32], v0: &[DMat3; LANES_F32]) -> [Svd3; LANES_F32] {
    svd3_warm_lanes_f32_body::<F32x8>(f, v0)
}

#[inline(always)]
pub(super) fn svd3_warm_lanes_f32_body<V: Vector<Scalar = f32>>(
    f: &[DMat3; LANES_F32],
    v0: &[DMat3; LANES_F32],
) -> [Svd3; LANES_F32] {
    let (fr, v0r) = (pack::<V>(&f.map(narrow)), pack::<V>(&v0.map(narrow)));
    let a = mul(&mul(&transpose(&v0r), &mul(&transpose(&fr), &fr)), &v0r);
    let mut v = jacobi_sorted(a, v0r);
    orthonormalize(&mut v);
    let (q, b) = qr(mul(&fr, &v));
    let (q, b, v) = (unpack(&q), unpack(&b), unpack(&v));
    std::array::from_fn(|l| Svd3 {
        u: widen(q[l]),
        s: DVec3::new(b[l][0][0].into(), b[l][1][1].into(), b[l][2][2].into()),
        v: widen(v[l]),
    })
}

/// A matrix by rows in f32.
#[inline(always)]
fn narrow(m: DMat3) -> [[f32; 3]; 3] {
    to_rows(m).map(|row| row.map(|x| x as f32))
}

/// A matrix by rows from f32.
#[inline(always)]
fn widen(m: [[f32; 3]; 3]) -> DMat3 {
    from_rows(m.map(|row| row.map(f64::from)))
}
