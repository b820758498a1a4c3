//! Quadratic B-spline weights for MLS-MPM (Hu et al. 2018).
//!
//! For a particle at grid coordinate `X = x/dx`, the stencil base node is
//! `base = floor(X - 0.5)` and `fx = X - base ∈ [0.5, 1.5)`. Along one axis the three weights are
//!
//! ```text
//! w0 = ½(1.5 − fx)²,  w1 = ¾ − (fx − 1)²,  w2 = ½(fx − 0.5)²
//! ```
//!
//! and their derivatives with respect to `fx` are `fx − 1.5`, `−2(fx − 1)` and `fx − 0.5`.
//! The weights sum to 1 and their derivatives sum to 0 for every `fx` (partition of unity).

use glam::DVec3;

/// Stencil of one particle: base node, fractional offset and per-axis weights.
#[derive(Clone, Copy, Debug)]
pub struct Stencil {
    /// Index of the first stencil node along each axis.
    pub base: [usize; 3],
    /// `X - base` along each axis, in cells.
    pub fx: DVec3,
    /// `w[a][i]`: weight of node `base[a] + i` along axis `a`.
    pub w: [[f64; 3]; 3],
}

/// The three quadratic B-spline weights along one axis.
#[inline(always)]
pub fn weights_1d(fx: f64) -> [f64; 3] {
    let a = 1.5 - fx;
    let b = fx - 1.0;
    let c = fx - 0.5;
    [0.5 * a * a, 0.75 - b * b, 0.5 * c * c]
}

/// Derivatives of [`weights_1d`] with respect to `fx`.
#[inline(always)]
pub fn weights_1d_deriv(fx: f64) -> [f64; 3] {
    [fx - 1.5, -2.0 * (fx - 1.0), fx - 0.5]
}

/// Adjoint of [`weights_1d`]: `∂L/∂w` → `∂L/∂fx`. Exact (the weights are polynomials).
#[inline(always)]
pub fn weights_1d_adj(fx: f64, g_w: [f64; 3]) -> f64 {
    let d = weights_1d_deriv(fx);
    g_w[0] * d[0] + g_w[1] * d[1] + g_w[2] * d[2]
}

/// `floor` by truncation and a one-step correction, exact for `|x| < 2⁶³` (grid coordinates
/// always are): a conversion instruction instead of a libm call on targets without SSE4.1's
/// `roundsd` (the x86-64 baseline).
#[inline(always)]
fn floor_fast(v: DVec3) -> DVec3 {
    let f = |x: f64| {
        let t = x as i64 as f64;
        if t > x {
            t - 1.0
        } else {
            t
        }
    };
    DVec3::new(f(v.x), f(v.y), f(v.z))
}

/// Stencil of a particle at `x` on a grid with node `i` at `origin + i·dx`.
///
/// The caller guarantees that the base lies inside the grid (the advect stage keeps particles in
/// the safe region); `grid_x` is `(x - origin)/dx`.
#[inline(always)]
pub fn stencil(grid_x: DVec3) -> Stencil {
    let b = floor_fast(grid_x - DVec3::splat(0.5));
    let fx = grid_x - b;
    Stencil {
        base: [b.x as usize, b.y as usize, b.z as usize],
        fx,
        w: [weights_1d(fx.x), weights_1d(fx.y), weights_1d(fx.z)],
    }
}

impl Stencil {
    /// Weight of node `(a, b, c)` of the stencil.
    #[inline(always)]
    pub fn weight(&self, a: usize, b: usize, c: usize) -> f64 {
        self.w[0][a] * self.w[1][b] * self.w[2][c]
    }

    /// `x_i − x_p` for node `(a, b, c)`, in metres.
    #[inline(always)]
    pub fn offset(&self, a: usize, b: usize, c: usize, dx: f64) -> DVec3 {
        DVec3::new(
            a as f64 - self.fx.x,
            b as f64 - self.fx.y,
            c as f64 - self.fx.z,
        ) * dx
    }

    /// Per-axis weight derivatives with respect to `fx` (for [`Stencil::weight_grad`]).
    #[inline(always)]
    pub fn derivs(&self) -> [[f64; 3]; 3] {
        [
            weights_1d_deriv(self.fx.x),
            weights_1d_deriv(self.fx.y),
            weights_1d_deriv(self.fx.z),
        ]
    }

    /// `∂w/∂x_p` of node `(a, b, c)`, given [`Stencil::derivs`].
    #[inline(always)]
    pub fn weight_grad(
        &self,
        dw: &[[f64; 3]; 3],
        a: usize,
        b: usize,
        c: usize,
        inv_dx: f64,
    ) -> DVec3 {
        let w = &self.w;
        DVec3::new(
            dw[0][a] * w[1][b] * w[2][c],
            w[0][a] * dw[1][b] * w[2][c],
            w[0][a] * w[1][b] * dw[2][c],
        ) * inv_dx
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Round-off bound for sums of three O(1) terms in f64.
    const SUM_TOL: f64 = 1e-15;

    #[test]
    fn floor_fast_is_floor() {
        for k in -4000..4000 {
            let x = k as f64 * 0.0625 + [0.0, 1e-12, -1e-12][(k as usize) % 3];
            let v = DVec3::new(x, -x, x + 0.5);
            assert_eq!(floor_fast(v), v.floor(), "{x}");
        }
    }

    #[test]
    fn partition_of_unity_and_zero_gradient_sum() {
        for k in 0..=1000 {
            let fx = 0.5 + k as f64 / 1000.0 * (1.0 - 1e-12);
            let w = weights_1d(fx);
            let dw = weights_1d_deriv(fx);
            assert!((w.iter().sum::<f64>() - 1.0).abs() < SUM_TOL);
            assert!(dw.iter().sum::<f64>().abs() < SUM_TOL);
            assert!(w.iter().all(|&x| x >= 0.0));
            // First moment: sum w_i (i - fx) = 0, which makes the APIC transfer affine-exact.
            let m1: f64 = (0..3).map(|i| w[i] * (i as f64 - fx)).sum();
            assert!(m1.abs() < SUM_TOL);
        }
    }

    #[test]
    fn derivative_matches_central_difference() {
        const H: f64 = 1e-6;
        // Central difference of a quadratic is exact up to round-off ~ eps/H.
        const TOL: f64 = 1e-9;
        for k in 1..100 {
            let fx = 0.5 + k as f64 / 100.0;
            let d = weights_1d_deriv(fx);
            let (p, m) = (weights_1d(fx + H), weights_1d(fx - H));
            for i in 0..3 {
                assert!(((p[i] - m[i]) / (2.0 * H) - d[i]).abs() < TOL);
            }
        }
    }

    #[test]
    fn weights_adjoint_matches_central_difference() {
        const H: f64 = 1e-6;
        const TOL: f64 = 1e-9;
        let g = [0.3, -1.2, 0.8];
        for k in 1..100 {
            let fx = 0.5 + k as f64 / 100.0;
            let f = |x: f64| weights_1d(x).iter().zip(g).map(|(w, g)| w * g).sum::<f64>();
            assert!(((f(fx + H) - f(fx - H)) / (2.0 * H) - weights_1d_adj(fx, g)).abs() < TOL);
        }
    }

    #[test]
    fn stencil_base_and_offset() {
        let s = stencil(DVec3::new(3.2, 7.9, 0.5));
        assert_eq!(s.base, [2, 7, 0]);
        assert!((s.fx - DVec3::new(1.2, 0.9, 0.5)).abs().max_element() < 1e-12);
    }
}
