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
        let off = a[0][1].abs() + a[0][2].abs() + a[1][2].abs();
        let diag = a[0][0].abs() + a[1][1].abs() + a[2][2].abs();
        if off <= 1e-17 * diag || off == 0.0 {
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

#[cfg(test)]
mod tests {
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

    fn lcg(seed: &mut u64) -> f64 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*seed >> 11) as f64) / ((1u64 << 53) as f64) * 2.0 - 1.0
    }

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
            let f = DMat3::IDENTITY
                + 0.3 * DMat3::from_cols_array(&std::array::from_fn(|_| lcg(&mut s)));
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
        check(
            DMat3::from_quat(r) * DMat3::from_diagonal(DVec3::new(1.0, 1.0 + 1e-10, 1.0 - 1e-10)),
        );
    }
}
