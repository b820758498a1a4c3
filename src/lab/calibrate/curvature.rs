//! The loss's curvature at the optimum, and what it says of each fitted parameter.

use super::{Calibration, Eval};
use serde::{Deserialize, Serialize};

/// The curvature at the optimum and what it says of each parameter.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Identifiability {
    /// Where it was taken, in unit coordinates (the point, moved a step inside the box).
    pub at: Vec<f64>,
    /// The loss there.
    pub loss: f64,
    /// `∂²L/∂u²` by central second differences of the loss.
    pub hessian: Vec<Vec<f64>>,
    /// Its eigenvalues, largest first, and unit eigenvectors (rows).
    pub eigenvalues: Vec<f64>,
    pub eigenvectors: Vec<Vec<f64>>,
    /// Standard error per parameter in its own units (`Cov(u) ≈ (2L*/n) H⁻¹`, mapped by
    /// `dv/du`); infinite where the curvature is not positive definite.
    pub std_error: Vec<f64>,
    /// The standard error as a share of the parameter's search range, or of its value for a
    /// parameter searched in decades.
    pub relative: Vec<f64>,
    /// The unit-coordinate step of the differences.
    pub step: f64,
}

/// The unit-coordinate step of the curvature's second differences: 5 % of each range. The
/// height loss is rough below about 1 % (grains cross pixel edges, contacts switch), so the
/// adjoint gradient's differences at a small step measure the roughness, not the curvature
/// (docs/design.md, calibration); the loss's own differences at 5 % average it out.
pub const CURVATURE_STEP: f64 = 0.05;

/// A parameter is *pinned down* by the observation when its standard error is under this share
/// of its search range (of its value, for one searched in decades).
pub const PINNED_SHARE: f64 = 0.02;

/// The curvature at `u` by central second differences of the forward loss, `1 + 2k²` forward
/// rollouts for `k` parameters (the centre, `±h` along each axis, and the four corners of
/// each pair). `u` is first moved inside the box by a step where it is closer to a face.
pub fn identifiability(
    cal: &Calibration,
    u: &[f64],
    step: f64,
    mut eval: impl FnMut(&[f64]) -> anyhow::Result<Eval>,
) -> anyhow::Result<Identifiability> {
    let d = u.len();
    let c: Vec<f64> = u.iter().map(|x| x.clamp(step, 1.0 - step)).collect();
    let at = |moves: &[(usize, f64)]| {
        let mut p = c.clone();
        for &(i, s) in moves {
            p[i] += s * step;
        }
        p
    };
    let l0 = eval(&c)?.loss;
    let mut plus = vec![0.0; d];
    let mut minus = vec![0.0; d];
    for i in 0..d {
        plus[i] = eval(&at(&[(i, 1.0)]))?.loss;
        minus[i] = eval(&at(&[(i, -1.0)]))?.loss;
    }
    let mut h = vec![vec![0.0; d]; d];
    for (i, row) in h.iter_mut().enumerate() {
        row[i] = (plus[i] - 2.0 * l0 + minus[i]) / (step * step);
    }
    let mut cross = Vec::new();
    for i in 0..d {
        for j in 0..i {
            let pp = eval(&at(&[(i, 1.0), (j, 1.0)]))?.loss;
            let pm = eval(&at(&[(i, 1.0), (j, -1.0)]))?.loss;
            let mp = eval(&at(&[(i, -1.0), (j, 1.0)]))?.loss;
            let mm = eval(&at(&[(i, -1.0), (j, -1.0)]))?.loss;
            cross.push((i, j, (pp - pm - mp + mm) / (4.0 * step * step)));
        }
    }
    for (i, j, v) in cross {
        h[i][j] = v;
        h[j][i] = v;
    }
    let (u, loss) = (c, l0);
    let (eigenvalues, eigenvectors) = symmetric_eigen(&h);
    let scale = 2.0 * loss.max(0.0) / cal.residuals.max(1) as f64;
    let mut std_error = vec![f64::INFINITY; d];
    if eigenvalues.iter().all(|&l| l > 0.0) {
        for i in 0..d {
            // (H⁻¹)_ii = Σ_k v_ki² / λ_k.
            let inv: f64 = eigenvalues
                .iter()
                .zip(&eigenvectors)
                .map(|(l, v)| v[i] * v[i] / l)
                .sum();
            std_error[i] = (scale * inv).sqrt() * cal.params[i].dvalue_du(u[i]).abs();
        }
    }
    // A share of the range for a linear parameter, of the value for one searched in decades
    // (whose range spans them, so that a share of it says little).
    let relative = std_error
        .iter()
        .zip(&cal.params)
        .zip(&u)
        .map(|((s, p), &ui)| {
            if p.log {
                s / p.from_unit(ui)
            } else {
                s / (p.hi - p.lo)
            }
        })
        .collect();
    Ok(Identifiability {
        at: u,
        loss,
        hessian: h,
        eigenvalues,
        eigenvectors,
        std_error,
        relative,
        step,
    })
}

/// Eigenvalues (largest first) and unit eigenvectors (rows) of a small symmetric matrix, by
/// cyclic Jacobi rotations. Hand-written: the project has no linear-algebra crate, and a
/// calibration fits a handful of parameters.
pub fn symmetric_eigen(a: &[Vec<f64>]) -> (Vec<f64>, Vec<Vec<f64>>) {
    let n = a.len();
    let mut a: Vec<Vec<f64>> = a.to_vec();
    let mut v: Vec<Vec<f64>> = (0..n)
        .map(|i| (0..n).map(|j| if i == j { 1.0 } else { 0.0 }).collect())
        .collect();
    for _sweep in 0..100 {
        let off: f64 = (0..n)
            .flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i][j] * a[i][j])
            .sum();
        let diag: f64 = (0..n).map(|i| a[i][i] * a[i][i]).sum();
        if off <= 1e-30 * diag.max(1e-300) {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                if a[p][q] == 0.0 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for row in a.iter_mut() {
                    let (akp, akq) = (row[p], row[q]);
                    row[p] = c * akp - s * akq;
                    row[q] = s * akp + c * akq;
                }
                let (rp, rq) = (a[p].clone(), a[q].clone());
                a[p] = rp.iter().zip(&rq).map(|(x, y)| c * x - s * y).collect();
                a[q] = rp.iter().zip(&rq).map(|(x, y)| s * x + c * y).collect();
                for row in v.iter_mut() {
                    let (vp, vq) = (row[p], row[q]);
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
    }
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&i, &j| a[j][j].total_cmp(&a[i][i]));
    let values = order.iter().map(|&i| a[i][i]).collect();
    // Column i of v is the eigenvector of a[i][i].
    let vectors = order
        .iter()
        .map(|&i| (0..n).map(|k| v[k][i]).collect())
        .collect();
    (values, vectors)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jacobi_eigen_reconstructs_a_symmetric_matrix() {
        let a = vec![
            vec![4.0, 1.0, -2.0],
            vec![1.0, 2.0, 0.5],
            vec![-2.0, 0.5, 3.0],
        ];
        let (l, v) = symmetric_eigen(&a);
        assert!(l[0] >= l[1] && l[1] >= l[2]);
        for i in 0..3 {
            for j in 0..3 {
                let r: f64 = (0..3).map(|k| l[k] * v[k][i] * v[k][j]).sum();
                assert!((r - a[i][j]).abs() < 1e-12, "{i},{j}: {r} vs {}", a[i][j]);
            }
        }
    }
}
