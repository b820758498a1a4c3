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

use glam::{DMat3, DVec3};

pub mod lanes;

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

    /// `b + M·d_ip` over this stencil's nodes ([`Stencil::offset`]), built as an
    /// [`OffsetAffine`].
    #[inline(always)]
    pub fn affine(&self, b: DVec3, m: DMat3, dx: f64) -> OffsetAffine {
        OffsetAffine {
            first: b - m * (self.fx * dx),
            cols: [m.x_axis * dx, m.y_axis * dx, m.z_axis * dx],
        }
    }
}

/// Sums over a stencil's 27 nodes of a per-node vector `g_i` and scalar `s_i` (what
/// [`Stencil::node_sums`] returns).
#[derive(Clone, Copy, Debug)]
pub struct NodeSums {
    /// `Σ_i w_ip·g_i`.
    pub w_g: DVec3,
    /// `Σ_i w_ip·g_i·o_iᵀ`, with `o_i` the node's integer offset in the stencil (0, 1 or 2 per
    /// axis); [`NodeSums::w_g_d`] turns it into `Σ_i w_ip·g_i·d_ipᵀ`.
    pub w_g_o: DMat3,
    /// `Σ_i ∇w_ip·s_i`, the gradient with respect to the particle position.
    pub grad_s: DVec3,
}

impl NodeSums {
    /// All sums zero (not `Default`: glam's default matrix is the identity).
    pub const ZERO: Self = Self {
        w_g: DVec3::ZERO,
        w_g_o: DMat3::ZERO,
        grad_s: DVec3::ZERO,
    };

    /// `Σ_i w_ip·g_i·d_ipᵀ` with `d_ip = (o_i − fx)·dx`: `dx·(Σ w·g·oᵀ − (Σ w·g)·fxᵀ)`.
    #[inline(always)]
    pub fn w_g_d(&self, fx: DVec3, dx: f64) -> DMat3 {
        let o = &self.w_g_o;
        DMat3::from_cols(
            (o.x_axis - self.w_g * fx.x) * dx,
            (o.y_axis - self.w_g * fx.y) * dx,
            (o.z_axis - self.w_g * fx.z) * dx,
        )
    }
}

impl Stencil {
    /// [`NodeSums`] of `node(a, b, c) = (g_i, s_i)`, contracted one axis at a time (z, then y,
    /// then x): the weight `w = wx·wy·wz`, its gradient `(wx′·wy·wz, wx·wy′·wz, wx·wy·wz′)/dx`
    /// and the offset moments factor along the axes, so a node costs a handful of multiply-adds
    /// instead of forming its own weight, gradient and outer product. Sums a caller does not
    /// read are removed by the optimiser (the function is inlined). Same sums as the direct
    /// 27-term loop up to round-off (test `node_sums_equal_the_direct_sums`).
    #[inline(always)]
    pub fn node_sums(
        &self,
        inv_dx: f64,
        mut node: impl FnMut(usize, usize, usize) -> (DVec3, f64),
    ) -> NodeSums {
        let dw = self.derivs();
        let [wx, wy, wz] = self.w;
        let mut out = NodeSums::ZERO;
        for a in 0..3 {
            let (mut y_g, mut y_gb, mut y_gc) = (DVec3::ZERO, DVec3::ZERO, DVec3::ZERO);
            let (mut y_ww, mut y_dw, mut y_wd) = (0.0, 0.0, 0.0);
            for b in 0..3 {
                let (mut z_g, mut z_gc) = (DVec3::ZERO, DVec3::ZERO);
                let (mut z_w, mut z_d) = (0.0, 0.0);
                for c in 0..3 {
                    let (g, s) = node(a, b, c);
                    z_g += g * wz[c];
                    z_gc += g * (wz[c] * c as f64);
                    z_w += s * wz[c];
                    z_d += s * dw[2][c];
                }
                y_g += z_g * wy[b];
                y_gb += z_g * (wy[b] * b as f64);
                y_gc += z_gc * wy[b];
                y_ww += z_w * wy[b];
                y_dw += z_w * dw[1][b];
                y_wd += z_d * wy[b];
            }
            out.w_g += y_g * wx[a];
            out.w_g_o.x_axis += y_g * (wx[a] * a as f64);
            out.w_g_o.y_axis += y_gb * wx[a];
            out.w_g_o.z_axis += y_gc * wx[a];
            out.grad_s += DVec3::new(y_ww * dw[0][a], y_dw * wx[a], y_wd * wx[a]);
        }
        out.grad_s *= inv_dx;
        out
    }
}

/// Where a grid's node velocities are and how they are laid out (x-major, z fastest).
#[derive(Clone, Copy, Debug)]
pub struct GridView<'a> {
    pub velocity: &'a [DVec3],
    pub origin: DVec3,
    pub dx: f64,
    pub n: [usize; 3],
}

/// G2P's gather for a particle at `x`, `(v_p, C_p)` with `v_p = Σ w·v_i` and
/// `C_p = (4/dx²)·Σ w·v_i·d_ipᵀ`, from the node velocities of `grid`: contracted one axis at a
/// time ([`Stencil::node_sums`]), so a node costs a few multiply-adds instead of its own weight
/// and outer product. [`lanes`] runs it four particles at a time, to the same bits.
#[inline(always)]
pub fn gather_velocity(grid: &GridView, x: DVec3) -> (DVec3, DMat3) {
    let (dx, n) = (grid.dx, grid.n);
    let st = stencil((x - grid.origin) / dx);
    let [bi, bj, bk] = st.base;
    let sums = st.node_sums(1.0 / dx, |a, b, c| {
        (
            grid.velocity[((bi + a) * n[1] + bj + b) * n[2] + bk + c],
            0.0,
        )
    });
    (sums.w_g, sums.w_g_d(st.fx, dx) * (4.0 / (dx * dx)))
}

/// `b + M·d_ip` at the nodes of a stencil, with `d_ip = (o − fx)·dx` and `o` the node's integer
/// offset: affine in `o`, so it is the value at the first node plus whole multiples of `M`'s
/// columns times dx, a few additions per node instead of a matrix product. The adjoint
/// transfers use it for `m·v_p + A_p·d_ip` (P2G) and `v̄_p + k·C̄_p·d_ip` (G2P).
#[derive(Clone, Copy, Debug)]
pub struct OffsetAffine {
    first: DVec3,
    cols: [DVec3; 3],
}

impl OffsetAffine {
    /// The value at node `(a, b, 0)`, the start of a row along z.
    #[inline(always)]
    pub fn row(&self, a: usize, b: usize) -> DVec3 {
        self.first + self.cols[0] * a as f64 + self.cols[1] * b as f64
    }

    /// The value at node `(a, b, c)` from its row's [`OffsetAffine::row`].
    #[inline(always)]
    pub fn node(&self, row: DVec3, c: usize) -> DVec3 {
        row + self.cols[2] * c as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Round-off bound of `b + M·d` built from columns, against the matrix product, for O(1)
    /// entries: a few ulps of the largest term.
    const AFFINE_TOL: f64 = 1e-14;

    #[test]
    fn offset_affine_equals_the_matrix_product_at_every_node() {
        let st = stencil(DVec3::new(3.7, 5.2, 4.95));
        let b = DVec3::new(0.3, -1.2, 0.8);
        let m = DMat3::from_cols_array(&[0.9, -0.4, 0.2, 1.1, 0.5, -0.7, 0.3, 0.6, -1.3]);
        let dx = 0.5;
        let t = st.affine(b, m, dx);
        for a in 0..3 {
            for bb in 0..3 {
                let row = t.row(a, bb);
                for c in 0..3 {
                    let want = b + m * st.offset(a, bb, c, dx);
                    let got = t.node(row, c);
                    assert!(
                        (got - want).abs().max_element() < AFFINE_TOL,
                        "{got} vs {want}"
                    );
                }
            }
        }
    }

    /// Round-off bound of the separable sums against the direct 27-term loop, for O(1) node
    /// values, weights ≤ 1 and gradients ≤ 1.5/dx: a few ulps of 27 terms.
    const NODE_SUMS_TOL: f64 = 1e-13;

    #[test]
    fn node_sums_equal_the_direct_sums() {
        let dx = 0.25;
        for (k, x) in [
            DVec3::new(3.7, 5.2, 4.95),
            DVec3::new(2.5, 2.5000001, 7.4999),
            DVec3::new(10.01, 3.33, 6.66),
        ]
        .into_iter()
        .enumerate()
        {
            let st = stencil(x);
            // Arbitrary O(1) node values, different at every node.
            let g = |a: usize, b: usize, c: usize| {
                let i = (9 * a + 3 * b + c + k) as f64;
                DVec3::new(
                    (1.3 * i).sin(),
                    (0.7 * i + 0.2).cos(),
                    (0.37 * i).sin() - 0.3,
                )
            };
            let s = |a: usize, b: usize, c: usize| (2.1 * (9 * a + 3 * b + c) as f64).cos();
            let got = st.node_sums(1.0 / dx, |a, b, c| (g(a, b, c), s(a, b, c)));
            let dw = st.derivs();
            let mut want = NodeSums::ZERO;
            let mut w_g_d = DMat3::ZERO;
            for a in 0..3 {
                for b in 0..3 {
                    for c in 0..3 {
                        let w = st.weight(a, b, c);
                        let gi = g(a, b, c);
                        let o = DVec3::new(a as f64, b as f64, c as f64);
                        let d = st.offset(a, b, c, dx);
                        want.w_g += gi * w;
                        want.w_g_o +=
                            DMat3::from_cols(gi * (w * o.x), gi * (w * o.y), gi * (w * o.z));
                        w_g_d += DMat3::from_cols(gi * (w * d.x), gi * (w * d.y), gi * (w * d.z));
                        want.grad_s += st.weight_grad(&dw, a, b, c, 1.0 / dx) * s(a, b, c);
                    }
                }
            }
            let close = |p: &[f64], q: &[f64], what: &str| {
                for (u, v) in p.iter().zip(q) {
                    assert!((u - v).abs() < NODE_SUMS_TOL, "{what}: {u} vs {v}");
                }
            };
            close(&got.w_g.to_array(), &want.w_g.to_array(), "Σ w·g");
            close(
                &got.w_g_o.to_cols_array(),
                &want.w_g_o.to_cols_array(),
                "Σ w·g·oᵀ",
            );
            close(
                &got.w_g_d(st.fx, dx).to_cols_array(),
                &w_g_d.to_cols_array(),
                "Σ w·g·dᵀ",
            );
            close(
                &(got.grad_s * dx).to_array(),
                &(want.grad_s * dx).to_array(),
                "Σ ∇w·s (times dx)",
            );
        }
    }

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
