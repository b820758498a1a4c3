//! The loss's curvature at the optimum, and what it says of each fitted parameter.

use super::{Calibration, Eval};
use crate::math::eigen::symmetric_eigen;
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

impl Identifiability {
    /// Whether parameter `i` is pinned down ([`PINNED_SHARE`]), as a page's table says it.
    pub fn pinned_text(&self, i: usize) -> &'static str {
        if self.relative[i] < PINNED_SHARE {
            "yes"
        } else {
            "no"
        }
    }
}

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
