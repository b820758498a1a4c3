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
pub(super) const MAX_SWEEPS: usize = 12;
/// An off-diagonal entry below this fraction of its diagonal pair is treated as zero.
pub(super) const OFF_DIAG_REL: f64 = 1e-18;

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
    // `x² + y²` underflows to 0 where both are below about 1e-162 (1e-23 in f32, where
    // round-off leaves such entries): the column is then zero to the precision, as when `y` is.
    let (c, s) = if y == 0.0 || x * x + y * y == 0.0 {
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
pub(super) fn to_rows(m: DMat3) -> [[f64; 3]; 3] {
    // glam stores columns; rows[r][c] = m.col(c)[r]
    let c = m.to_cols_array_2d();
    [
        [c[0][0], c[1][0], c[2][0]],
        [c[0][1], c[1][1], c[2][1]],
        [c[0][2], c[1][2], c[2][2]],
    ]
}

#[inline(always)]
pub(super) fn from_rows(r: [[f64; 3]; 3]) -> DMat3 {
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

mod lanes;
pub use lanes::{
    svd3_warm_group, svd3_warm_lanes, svd3_warm_lanes_f32, Kernel, SvdReal, LANES, LANES_F32,
};

#[cfg(test)]
mod tests;
