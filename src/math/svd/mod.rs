//! Robust 3×3 singular value decomposition `F = U·diag(σ)·Vᵀ` in f64.
//!
//! Method (after McAdams et al. 2011, with exact instead of approximate rotations):
//! 1. cyclic Jacobi on the symmetric `A = FᵀF` gives `V` and the eigenvalues `σ²`;
//! 2. the columns of `V` are sorted by decreasing eigenvalue, keeping `det V = +1`;
//! 3. a Givens QR of `B = F·V` gives `U = Q` (always orthonormal, even for rank-deficient `F`)
//!    and `σ = diag(R)`.
//!
//! Conventions: `U` and `V` are rotations (`det = +1`), `σ₀ ≥ σ₁ ≥ |σ₂|`, and `σ₂ < 0` exactly
//! when `det F < 0` (an inverted element). Near-equal and tiny singular values are handled:
//! the QR step never divides by a singular value, so `U` stays orthonormal for `F = 0`.

use glam::{DMat3, DVec3};

/// Singular value decomposition of a 3×3 matrix.
#[derive(Clone, Copy, Debug)]
pub struct Svd3 {
    pub u: DMat3,
    pub s: DVec3,
    pub v: DMat3,
}

/// Largest number of Jacobi sweeps; quadratic convergence reaches f64 round-off in 4–6.
const MAX_SWEEPS: usize = 12;
/// An off-diagonal entry below this fraction of its diagonal pair is treated as zero.
const OFF_DIAG_REL: f64 = 1e-18;

/// Whether the Jacobi iteration on `A` (upper off-diagonal `a01, a02, a12`, diagonal
/// `a00, a11, a22`) has converged: the off-diagonal is below 1e-17 of the diagonal, or zero.
#[inline(always)]
fn converged(a01: f64, a02: f64, a12: f64, a00: f64, a11: f64, a22: f64) -> bool {
    let off = a01.abs() + a02.abs() + a12.abs();
    let diag = a00.abs() + a11.abs() + a22.abs();
    off <= 1e-17 * diag || off == 0.0
}

#[inline(always)]
fn jacobi_rotate(a: &mut [[f64; 3]; 3], v: &mut [[f64; 3]; 3], p: usize, q: usize, r: usize) {
    let apq = a[p][q];
    if apq.abs() <= OFF_DIAG_REL * (a[p][p].abs() + a[q][q].abs()) || apq == 0.0 {
        a[p][q] = 0.0;
        a[q][p] = 0.0;
        return;
    }
    // Symmetric Schur decomposition (Numerical Recipes §11.1).
    let theta = (a[q][q] - a[p][p]) / (2.0 * apq);
    let t = if theta.abs() > 1e150 {
        0.5 / theta
    } else {
        theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt())
    };
    let c = 1.0 / (t * t + 1.0).sqrt();
    let s = t * c;
    a[p][p] -= t * apq;
    a[q][q] += t * apq;
    a[p][q] = 0.0;
    a[q][p] = 0.0;
    let (arp, arq) = (a[r][p], a[r][q]);
    a[r][p] = c * arp - s * arq;
    a[p][r] = a[r][p];
    a[r][q] = s * arp + c * arq;
    a[q][r] = a[r][q];
    for row in v.iter_mut() {
        let (vp, vq) = (row[p], row[q]);
        row[p] = c * vp - s * vq;
        row[q] = s * vp + c * vq;
    }
}

/// Givens rotation that zeroes `b[i][j]` against the pivot `b[j][j]`, applied to rows `j`, `i`
/// of `b` and accumulated into the columns `j`, `i` of `q` (so that `q·b` is unchanged).
#[inline(always)]
fn givens(b: &mut [[f64; 3]; 3], q: &mut [[f64; 3]; 3], j: usize, i: usize) {
    let (x, y) = (b[j][j], b[i][j]);
    let (c, s) = if y == 0.0 {
        if x >= 0.0 {
            return;
        }
        // A half turn in the (j, i) plane makes the pivot positive and keeps det Q = +1.
        (-1.0, 0.0)
    } else {
        // x² + y² cannot overflow for deformation gradients (|F| ≪ 1e150); hypot is 10× slower.
        let inv_r = 1.0 / (x * x + y * y).sqrt();
        (x * inv_r, y * inv_r)
    };
    for k in 0..3 {
        let (bj, bi) = (b[j][k], b[i][k]);
        b[j][k] = c * bj + s * bi;
        b[i][k] = -s * bj + c * bi;
        let (qj, qi) = (q[k][j], q[k][i]);
        q[k][j] = c * qj + s * qi;
        q[k][i] = -s * qj + c * qi;
    }
}

#[inline(always)]
fn to_rows(m: DMat3) -> [[f64; 3]; 3] {
    // glam stores columns; rows[r][c] = m.col(c)[r]
    let c = m.to_cols_array_2d();
    [
        [c[0][0], c[1][0], c[2][0]],
        [c[0][1], c[1][1], c[2][1]],
        [c[0][2], c[1][2], c[2][2]],
    ]
}

#[inline(always)]
fn from_rows(r: [[f64; 3]; 3]) -> DMat3 {
    DMat3::from_cols_array_2d(&[
        [r[0][0], r[1][0], r[2][0]],
        [r[0][1], r[1][1], r[2][1]],
        [r[0][2], r[1][2], r[2][2]],
    ])
}

/// SVD of `f`. See the module docs for conventions.
pub fn svd3(f: DMat3) -> Svd3 {
    svd3_warm(f, DMat3::IDENTITY)
}

/// SVD of `f`, with the Jacobi iteration started from the rotation `v0` (for example the `V`
/// of the same particle one substep earlier, when `F` has barely changed): the eigenvectors
/// are then nearly found and one sweep usually suffices. The result is the SVD of `f` whatever
/// `v0` is (any rotation), so a warm start changes the cost, not the answer beyond round-off.
pub fn svd3_warm(f: DMat3, v0: DMat3) -> Svd3 {
    let mut a = to_rows(v0.transpose() * (f.transpose() * f) * v0);
    let mut v = to_rows(v0);
    for _ in 0..MAX_SWEEPS {
        if converged(a[0][1], a[0][2], a[1][2], a[0][0], a[1][1], a[2][2]) {
            break;
        }
        jacobi_rotate(&mut a, &mut v, 0, 1, 2);
        jacobi_rotate(&mut a, &mut v, 0, 2, 1);
        jacobi_rotate(&mut a, &mut v, 1, 2, 0);
    }
    // Sort eigenvalues descending; every column swap is paired with a sign flip so det V = +1.
    let mut ev = [a[0][0], a[1][1], a[2][2]];
    let swap = |v: &mut [[f64; 3]; 3], ev: &mut [f64; 3], i: usize, j: usize| {
        ev.swap(i, j);
        for row in v.iter_mut() {
            row.swap(i, j);
            row[j] = -row[j];
        }
    };
    if ev[0] < ev[1] {
        swap(&mut v, &mut ev, 0, 1);
    }
    if ev[0] < ev[2] {
        swap(&mut v, &mut ev, 0, 2);
    }
    if ev[1] < ev[2] {
        swap(&mut v, &mut ev, 1, 2);
    }
    let vm = from_rows(v);
    let mut b = to_rows(f * vm);
    let mut q = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    givens(&mut b, &mut q, 0, 1);
    givens(&mut b, &mut q, 0, 2);
    givens(&mut b, &mut q, 1, 2);
    // b is now upper triangular with (numerically) zero off-diagonal; its diagonal holds σ.
    Svd3 {
        u: from_rows(q),
        s: DVec3::new(b[0][0], b[1][1], b[2][2]),
        v: vm,
    }
}

/// Particles decomposed together by [`svd3_warm_lanes`].
pub const LANES: usize = 4;

/// One value per lane; every operation acts lane by lane, so the compiler maps it onto SIMD
/// registers, and the lanes' independent dependency chains hide the latency of `sqrt` and `/`.
type Lf = [f64; LANES];
type Lm = [bool; LANES];

#[inline(always)]
fn lanes(f: impl Fn(usize) -> f64) -> Lf {
    std::array::from_fn(f)
}

#[inline(always)]
fn mask(f: impl Fn(usize) -> bool) -> Lm {
    std::array::from_fn(f)
}

#[inline(always)]
fn select(m: Lm, a: Lf, b: Lf) -> Lf {
    lanes(|l| if m[l] { a[l] } else { b[l] })
}

/// From this `|θ|` on (2²⁷), a Jacobi rotation's general formula reduces exactly to
/// `t = 0.5/θ`, `c = 1`: `θ²` is at least 2⁵⁴, so adding 1 is below half its ulp, and
/// `|t| ≤ 2⁻²⁸`, so `t²` is below half an ulp of 1.
const SMALL_ANGLE_THETA: f64 = (1u64 << 27) as f64;

/// [`jacobi_rotate`] on every lane where `active` holds; the other lanes are left untouched.
/// Each lane computes exactly the operations of the scalar function, so the results are
/// bitwise equal to it.
#[inline(always)]
fn jacobi_rotate_lanes(
    a: &mut [[Lf; 3]; 3],
    v: &mut [[Lf; 3]; 3],
    active: Lm,
    p: usize,
    q: usize,
    r: usize,
) {
    let (apq, app, aqq) = (a[p][q], a[p][p], a[q][q]);
    let tiny =
        mask(|l| apq[l].abs() <= OFF_DIAG_REL * (app[l].abs() + aqq[l].abs()) || apq[l] == 0.0);
    let rot = mask(|l| active[l] && !tiny[l]);
    let theta = lanes(|l| (aqq[l] - app[l]) / (2.0 * apq[l]));
    let (t, c, s) = if (0..LANES).all(|l| !rot[l] || theta[l].abs() >= SMALL_ANGLE_THETA) {
        // Every rotating lane turns by a small angle (as in the last sweep of nearly every
        // decomposition): there the general formula below gives exactly `t = 0.5/θ`, `c = 1`,
        // `s = t`, since `θ² + 1` rounds to `θ²`, `√(θ²)` is `|θ|` in IEEE arithmetic, and
        // `t² + 1` rounds to 1. One division instead of three and two square roots on the
        // rotation's dependency chain, for the same bits (`small_angle_rotation_is_exact`).
        let t = lanes(|l| 0.5 / theta[l]);
        (t, [1.0; LANES], t)
    } else {
        let huge = mask(|l| theta[l].abs() > 1e150);
        let t_huge = lanes(|l| 0.5 / theta[l]);
        let root = lanes(|l| (theta[l] * theta[l] + 1.0).sqrt());
        let t = select(
            huge,
            t_huge,
            lanes(|l| theta[l].signum() / (theta[l].abs() + root[l])),
        );
        let c = lanes(|l| 1.0 / (t[l] * t[l] + 1.0).sqrt());
        (t, c, lanes(|l| t[l] * c[l]))
    };
    a[p][p] = select(rot, lanes(|l| app[l] - t[l] * apq[l]), app);
    a[q][q] = select(rot, lanes(|l| aqq[l] + t[l] * apq[l]), aqq);
    let off = select(active, [0.0; LANES], apq);
    a[p][q] = off;
    a[q][p] = off;
    // `A` is symmetric only up to round-off on entry: a lane that does not rotate keeps both
    // triangles as they are, as the scalar function's early return does.
    let (arp, arq) = (a[r][p], a[r][q]);
    let rp = lanes(|l| c[l] * arp[l] - s[l] * arq[l]);
    let rq = lanes(|l| s[l] * arp[l] + c[l] * arq[l]);
    a[p][r] = select(rot, rp, a[p][r]);
    a[q][r] = select(rot, rq, a[q][r]);
    a[r][p] = select(rot, rp, arp);
    a[r][q] = select(rot, rq, arq);
    for row in v.iter_mut() {
        let (vp, vq) = (row[p], row[q]);
        row[p] = select(rot, lanes(|l| c[l] * vp[l] - s[l] * vq[l]), vp);
        row[q] = select(rot, lanes(|l| s[l] * vp[l] + c[l] * vq[l]), vq);
    }
}

/// [`givens`] on every lane, bitwise equal to it.
#[inline(always)]
fn givens_lanes(b: &mut [[Lf; 3]; 3], q: &mut [[Lf; 3]; 3], j: usize, i: usize) {
    let (x, y) = (b[j][j], b[i][j]);
    let keep = mask(|l| y[l] == 0.0 && x[l] >= 0.0);
    let inv_r = lanes(|l| 1.0 / (x[l] * x[l] + y[l] * y[l]).sqrt());
    let c = lanes(|l| if y[l] == 0.0 { -1.0 } else { x[l] * inv_r[l] });
    let s = lanes(|l| if y[l] == 0.0 { 0.0 } else { y[l] * inv_r[l] });
    for k in 0..3 {
        let (bj, bi) = (b[j][k], b[i][k]);
        b[j][k] = select(keep, bj, lanes(|l| c[l] * bj[l] + s[l] * bi[l]));
        b[i][k] = select(keep, bi, lanes(|l| -s[l] * bj[l] + c[l] * bi[l]));
        let (qj, qi) = (q[k][j], q[k][i]);
        q[k][j] = select(keep, qj, lanes(|l| c[l] * qj[l] + s[l] * qi[l]));
        q[k][i] = select(keep, qi, lanes(|l| -s[l] * qj[l] + c[l] * qi[l]));
    }
}

#[inline(always)]
fn pack(m: [[[f64; 3]; 3]; LANES]) -> [[Lf; 3]; 3] {
    std::array::from_fn(|r| std::array::from_fn(|c| lanes(|l| m[l][r][c])))
}

#[inline(always)]
fn unpack(m: &[[Lf; 3]; 3], l: usize) -> [[f64; 3]; 3] {
    std::array::from_fn(|r| std::array::from_fn(|c| m[r][c][l]))
}

/// [`svd3_warm`] of [`LANES`] matrices at once, lane `l` from `f[l]` and `v0[l]`. Bitwise equal
/// to calling `svd3_warm` on each: every lane runs the scalar algorithm's operations, and a lane
/// whose Jacobi iteration has converged is masked out of the further sweeps of the others.
/// The forward SVD stage runs on this: on `sand_box` (2 threads, AVX2) the stage took 1.48 s
/// instead of 3.27 s one matrix at a time, since the latency of the rotations' square roots and
/// divisions overlaps across lanes (`powderlab bench scenes/sand_box.ron --stages`).
pub fn svd3_warm_lanes(f: &[DMat3; LANES], v0: &[DMat3; LANES]) -> [Svd3; LANES] {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, which is all the function's target features ask for.
        return unsafe { svd3_warm_lanes_avx2(f, v0) };
    }
    svd3_warm_lanes_body(f, v0)
}

/// [`svd3_warm`] of each of up to [`LANES`] matrices, `f[i]` warm-started from `v0[i]`, handed to
/// `out(i, svd)`: a full group goes through [`svd3_warm_lanes`], a shorter one (the end of a
/// particle array) one matrix at a time; the results are bitwise the same either way.
#[inline(always)]
pub fn svd3_warm_group(f: &[DMat3], v0: &[DMat3], mut out: impl FnMut(usize, Svd3)) {
    match (
        <&[DMat3; LANES]>::try_from(f),
        <&[DMat3; LANES]>::try_from(v0),
    ) {
        (Ok(f), Ok(v0)) => {
            for (l, d) in svd3_warm_lanes(f, v0).into_iter().enumerate() {
                out(l, d);
            }
        }
        _ => {
            for (i, (&f, &v0)) in f.iter().zip(v0).enumerate() {
                out(i, svd3_warm(f, v0));
            }
        }
    }
}

/// [`svd3_warm_lanes_body`] compiled for AVX2 (four f64 lanes per register). Rust never fuses a
/// multiply and an add on its own, so the results are the same bits as the baseline build's.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn svd3_warm_lanes_avx2(f: &[DMat3; LANES], v0: &[DMat3; LANES]) -> [Svd3; LANES] {
    svd3_warm_lanes_body(f, v0)
}

#[inline(always)]
fn svd3_warm_lanes_body(f: &[DMat3; LANES], v0: &[DMat3; LANES]) -> [Svd3; LANES] {
    let mut a = pack(std::array::from_fn(|l| {
        to_rows(v0[l].transpose() * (f[l].transpose() * f[l]) * v0[l])
    }));
    let mut v = pack(std::array::from_fn(|l| to_rows(v0[l])));
    let mut active = [true; LANES];
    for _ in 0..MAX_SWEEPS {
        for (l, on) in active.iter_mut().enumerate() {
            *on = *on
                && !converged(
                    a[0][1][l], a[0][2][l], a[1][2][l], a[0][0][l], a[1][1][l], a[2][2][l],
                );
        }
        if !active.iter().any(|&on| on) {
            break;
        }
        jacobi_rotate_lanes(&mut a, &mut v, active, 0, 1, 2);
        jacobi_rotate_lanes(&mut a, &mut v, active, 0, 2, 1);
        jacobi_rotate_lanes(&mut a, &mut v, active, 1, 2, 0);
    }
    // Sort as `svd3_warm` does: each swap exchanges two columns and negates the second.
    let mut ev = [a[0][0], a[1][1], a[2][2]];
    for (i, j) in [(0, 1), (0, 2), (1, 2)] {
        let sw = mask(|l| ev[i][l] < ev[j][l]);
        let (ei, ej) = (ev[i], ev[j]);
        ev[i] = select(sw, ej, ei);
        ev[j] = select(sw, ei, ej);
        for row in v.iter_mut() {
            let (vi, vj) = (row[i], row[j]);
            row[i] = select(sw, vj, vi);
            row[j] = select(sw, lanes(|l| -vi[l]), vj);
        }
    }
    let vm: [DMat3; LANES] = std::array::from_fn(|l| from_rows(unpack(&v, l)));
    let mut b = pack(std::array::from_fn(|l| to_rows(f[l] * vm[l])));
    let one = [1.0; LANES];
    let zero = [0.0; LANES];
    let mut q = [[one, zero, zero], [zero, one, zero], [zero, zero, one]];
    givens_lanes(&mut b, &mut q, 0, 1);
    givens_lanes(&mut b, &mut q, 0, 2);
    givens_lanes(&mut b, &mut q, 1, 2);
    std::array::from_fn(|l| Svd3 {
        u: from_rows(unpack(&q, l)),
        s: DVec3::new(b[0][0][l], b[1][1][l], b[2][2][l]),
        v: vm[l],
    })
}

/// Smallest `|σ_j² − σ_i²|` the adjoint divides by. Closer singular values (including exactly
/// equal ones, e.g. `F = I` at rest) use this value with the sign of the difference.
///
/// **Bias.** For `|σ_j² − σ_i²| < SVD_ADJ_GAP` the rotational terms of the adjoint are damped by
/// the factor `|σ_j² − σ_i²|/SVD_ADJ_GAP`. Losses that depend on `F` only through functions of
/// the singular values that are symmetric in them (every isotropic energy, Hencky stress and the
/// Drucker–Prager map) have `J_ij`, `K_ij` terms that vanish as the gap closes, so the damping
/// changes their gradient by O(gap); a loss on `U` or `V` alone is ill-defined at equal `σ` and
/// gets a bounded surrogate there.
pub const SVD_ADJ_GAP: f64 = 1e-12;

/// Adjoint of [`svd3`]: given `∂L/∂U`, `∂L/∂σ` and `∂L/∂V`, returns `∂L/∂F` (Townsend 2016,
/// square case):
///
/// ```text
/// ∂L/∂F = U·[ (Fm ∘ (J − Jᵀ))·Σ + diag(∂L/∂σ) + Σ·(Fm ∘ (K − Kᵀ)) ]·Vᵀ,
/// J = Uᵀ·∂L/∂U,  K = Vᵀ·∂L/∂V,  Fm_ij = 1/(σ_j² − σ_i²)  (i ≠ j, guarded by SVD_ADJ_GAP)
/// ```
pub fn svd3_adj(d: &Svd3, g_u: DMat3, g_s: DVec3, g_v: DMat3) -> DMat3 {
    let j = to_rows(d.u.transpose() * g_u);
    let k = to_rows(d.v.transpose() * g_v);
    let s = [d.s.x, d.s.y, d.s.z];
    let mut m = [[0.0; 3]; 3];
    for (i, row) in m.iter_mut().enumerate() {
        for (jj, e) in row.iter_mut().enumerate() {
            if i == jj {
                *e = s_adj_diag(g_s, i);
            } else {
                let den = s[jj] * s[jj] - s[i] * s[i];
                let den = if den.abs() < SVD_ADJ_GAP {
                    if den < 0.0 {
                        -SVD_ADJ_GAP
                    } else {
                        SVD_ADJ_GAP
                    }
                } else {
                    den
                };
                *e = ((j[i][jj] - j[jj][i]) * s[jj] + s[i] * (k[i][jj] - k[jj][i])) / den;
            }
        }
    }
    d.u * from_rows(m) * d.v.transpose()
}

#[inline(always)]
fn s_adj_diag(g_s: DVec3, i: usize) -> f64 {
    [g_s.x, g_s.y, g_s.z][i]
}

#[cfg(test)]
mod tests;
