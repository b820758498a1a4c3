//! Height maps of a particle cloud: the surface a depth camera looking down the −y axis sees.
//!
//! - [`hard_heights`]: the highest grain top in each pixel's footprint, the observation a
//!   synthetic test makes from a known state (and what a real camera measures).
//! - [`soft_heights`] and its adjoint [`soft_heights_adj`]: a smooth height per pixel for the
//!   calibration loss. Pixel `c` (centre `(X_c, Z_c)`, size `p`) weighs particle `i` by a soft
//!   version of the camera's square footprint, `k_c(x_i) = σ((p/2 − |x_i − X_c|)/w) ·
//!   σ((p/2 − |z_i − Z_c|)/w)` (σ the logistic, `w` the edge's width), and its height is the
//!   soft maximum
//!
//!   `h_c = τ ln( e^{b/τ} + Σ_i k_c(x_i) e^{(y_i + t)/τ} )`
//!
//!   with `b` the base (the floor, which an empty pixel reads), `τ` the temperature and `t`
//!   (`top`) the offset from a grain's centre to its top. As `τ, w → 0` it tends to the hard
//!   height of the same footprint. A grain that drifts sideways out of a pixel fades out of it
//!   through its weight instead of dropping out, so `h` is continuous in every particle's
//!   position and its gradient reaches `x` and `z` as well as `y`. A grain `δ` outside the
//!   footprint counts about `δ·τ/w` lower than it is; with `w` a quarter of `τ` a higher grain
//!   just across the edge, on a pile's slope, does not lift this pixel's height (with a bilinear
//!   tent over the neighbouring pixels it did, by up to a layer). The soft maximum reads high by
//!   at most `τ ln(Σ k)`, the grains near the top of a pixel all counting; `calibrate` takes `τ`
//!   a tenth of a spacing (docs/design.md, calibration).
//!
//! Each particle touches the pixels within [`REACH`] widths of it, so a pass is
//! `O(N + pixels)`, and the shift by each pixel's largest term keeps every exponent ≤ 0.

use crate::math::geometry::logistic;
use glam::DVec3;

/// A regular grid of pixels over the x–z plane: pixel `(i, j)` is centred at
/// `(origin[0] + i·pixel, origin[1] + j·pixel)` and stored at index `j·nx + i` (rows along z).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeightGrid {
    /// x and z of pixel (0, 0)'s centre (m).
    pub origin: [f64; 2],
    /// Pixel size (m), > 0.
    pub pixel: f64,
    pub nx: usize,
    pub nz: usize,
}

impl HeightGrid {
    pub fn len(&self) -> usize {
        self.nx * self.nz
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The pixels whose soft footprint reaches `(x, z)`, with the footprint's weight `k` and
    /// its x and z derivatives. Per axis the weight is `σ((p/2 − |d|)/w)`, `d` the offset from
    /// the pixel's centre: 1 well inside the pixel's square, ½ on its edge, and `e^{−a}` at `a`
    /// widths outside. Pixels more than [`REACH`] widths outside are skipped (weight < 2e-9).
    fn footprints(&self, x: f64, z: f64, w: f64, mut f: impl FnMut(usize, f64, f64, f64)) {
        let half = 0.5 * self.pixel;
        let reach = half + REACH * w;
        let range = |v: f64, o: f64, n: usize| -> Option<(usize, usize)> {
            let lo = ((v - reach - o) / self.pixel).ceil().max(0.0);
            let hi = ((v + reach - o) / self.pixel).floor().min(n as f64 - 1.0);
            (lo.is_finite() && hi.is_finite() && lo <= hi).then_some((lo as usize, hi as usize))
        };
        let (Some((i0, i1)), Some((j0, j1))) = (
            range(x, self.origin[0], self.nx),
            range(z, self.origin[1], self.nz),
        ) else {
            return;
        };
        let axis = |d: f64| -> (f64, f64) {
            let k = logistic((half - d.abs()) / w);
            // dk/dd = σ'·(−sign d)/w; the subgradient 0 on the centre line.
            let s = if d > 0.0 {
                1.0
            } else if d < 0.0 {
                -1.0
            } else {
                0.0
            };
            (k, -k * (1.0 - k) * s / w)
        };
        for j in j0..=j1 {
            let (kz, dkz) = axis(z - (self.origin[1] + j as f64 * self.pixel));
            for i in i0..=i1 {
                let (kx, dkx) = axis(x - (self.origin[0] + i as f64 * self.pixel));
                f(j * self.nx + i, kx * kz, dkx * kz, kx * dkz);
            }
        }
    }
}

/// How far outside a pixel, in footprint widths, a grain still counts.
pub const REACH: f64 = 20.0;

/// The highest grain top `y + top` among the particles whose x–z position lies in each pixel's
/// square footprint, or `base` where none does (or where all are below it).
pub fn hard_heights(grid: &HeightGrid, xs: &[DVec3], base: f64, top: f64) -> Vec<f64> {
    let mut h = vec![base; grid.len()];
    for p in xs {
        let i = ((p.x - grid.origin[0]) / grid.pixel + 0.5).floor();
        let j = ((p.z - grid.origin[1]) / grid.pixel + 0.5).floor();
        if i >= 0.0 && j >= 0.0 && i < grid.nx as f64 && j < grid.nz as f64 {
            let c = j as usize * grid.nx + i as usize;
            h[c] = h[c].max(p.y + top);
        }
    }
    h
}

/// The soft height's settings: the height an empty pixel reads (m, the floor), from a grain's
/// centre to its top (m), the soft maximum's temperature `τ` (m, > 0) and the width of the soft
/// footprint's edge (m, > 0).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SoftHeight {
    pub base: f64,
    pub top: f64,
    pub tau: f64,
    pub edge: f64,
}

/// Per pixel: the largest exponent (the shift) and the sum `S` of the shifted terms.
fn soft_sums(grid: &HeightGrid, xs: &[DVec3], sh: &SoftHeight) -> (Vec<f64>, Vec<f64>) {
    let SoftHeight {
        base,
        top,
        tau,
        edge,
    } = *sh;
    // Shift each pixel's exponents by its largest term, so that S ≥ 1 and nothing overflows.
    let mut m = vec![base; grid.len()];
    for p in xs {
        grid.footprints(p.x, p.z, edge, |c, k, _, _| {
            m[c] = m[c].max(p.y + top + tau * k.ln())
        });
    }
    let mut s: Vec<f64> = m.iter().map(|&mc| ((base - mc) / tau).exp()).collect();
    for p in xs {
        grid.footprints(p.x, p.z, edge, |c, k, _, _| {
            s[c] += k * ((p.y + top - m[c]) / tau).exp()
        });
    }
    (m, s)
}

/// The soft height of every pixel (see the module docs), for a temperature `tau` > 0.
pub fn soft_heights(grid: &HeightGrid, xs: &[DVec3], sh: &SoftHeight) -> Vec<f64> {
    let (m, s) = soft_sums(grid, xs, sh);
    m.iter()
        .zip(&s)
        .map(|(mc, sc)| mc + sh.tau * sc.ln())
        .collect()
}

/// The adjoint of [`soft_heights`]: `∂/∂x_i` of `Σ_c g_c·h_c` for every particle, given
/// `g_h[c] = ∂L/∂h_c`.
///
/// `∂h_c/∂y_i = k_c e^{(y_i + t − m_c)/τ} / S_c` (the softmax weight) and
/// `∂h_c/∂(x_i, z_i) = τ ∇k_c e^{(y_i + t − m_c)/τ} / S_c`.
pub fn soft_heights_adj(
    grid: &HeightGrid,
    xs: &[DVec3],
    sh: &SoftHeight,
    g_h: &[f64],
) -> Vec<DVec3> {
    let (m, s) = soft_sums(grid, xs, sh);
    let SoftHeight { top, tau, edge, .. } = *sh;
    xs.iter()
        .map(|p| {
            let mut g = DVec3::ZERO;
            grid.footprints(p.x, p.z, edge, |c, k, dkx, dkz| {
                let e = ((p.y + top - m[c]) / tau).exp() / s[c] * g_h[c];
                g += DVec3::new(tau * dkx * e, k * e, tau * dkz * e);
            });
            g
        })
        .collect()
}

/// The height-field loss `L = (1/n) Σ_c (h_c − o_c)²` over the `n` pixels whose observed height
/// `o_c` is finite (a NaN marks a pixel the camera did not see), and `∂L/∂h`.
pub fn squared_error(h: &[f64], observed: &[f64]) -> (f64, Vec<f64>) {
    let n = observed.iter().filter(|o| o.is_finite()).count().max(1) as f64;
    let mut l = 0.0;
    let g = h
        .iter()
        .zip(observed)
        .map(|(hc, oc)| {
            if oc.is_finite() {
                let r = hc - oc;
                l += r * r / n;
                2.0 * r / n
            } else {
                0.0
            }
        })
        .collect();
    (l, g)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Central differences in f64 at a step of 1e-7 m on heights of order 1e-2 m: truncation
    /// error ~ h² |h'''| ≲ 1e-12 for τ ≥ 1e-4, rounding ~ 1e-16/1e-7 = 1e-9 relative.
    const FD_TOL: f64 = 1e-6;

    fn cloud() -> Vec<DVec3> {
        // A deterministic scatter of 60 grains over a 4 × 3 grid of 1 cm pixels.
        (0..60)
            .map(|k| {
                let t = k as f64;
                DVec3::new(
                    0.0123 + 0.031 * ((t * 0.618).fract()),
                    0.01 + 0.02 * ((t * 0.377).fract()),
                    0.0071 + 0.019 * ((t * 0.853).fract()),
                )
            })
            .collect()
    }

    #[test]
    fn soft_height_adjoint_matches_central_differences() {
        let grid = HeightGrid {
            origin: [0.01, 0.005],
            pixel: 0.01,
            nx: 4,
            nz: 3,
        };
        let xs = cloud();
        let sh = SoftHeight {
            base: 0.0,
            top: 0.001,
            tau: 0.002,
            edge: 0.001,
        };
        let obs: Vec<f64> = (0..grid.len()).map(|c| 0.02 + 0.001 * c as f64).collect();
        let loss = |xs: &[DVec3]| squared_error(&soft_heights(&grid, xs, &sh), &obs).0;
        let (_, g_h) = squared_error(&soft_heights(&grid, &xs, &sh), &obs);
        let g = soft_heights_adj(&grid, &xs, &sh, &g_h);
        let eps = 1e-7;
        let mut worst: f64 = 0.0;
        for i in 0..xs.len() {
            for d in 0..3 {
                let mut p = xs.clone();
                p[i][d] += eps;
                let mut q = xs.clone();
                q[i][d] -= eps;
                let fd = (loss(&p) - loss(&q)) / (2.0 * eps);
                let scale = fd.abs().max(g[i][d].abs()).max(1e-6);
                worst = worst.max((fd - g[i][d]).abs() / scale);
            }
        }
        assert!(worst < FD_TOL, "worst relative error {worst:e}");
    }

    #[test]
    fn soft_height_tends_to_the_highest_grain_and_empty_pixels_read_the_base() {
        let grid = HeightGrid {
            origin: [0.0, 0.0],
            pixel: 0.01,
            nx: 3,
            nz: 1,
        };
        // Two grains at pixel 0's centre; nothing reaches pixel 2.
        let xs = [DVec3::new(0.0, 0.03, 0.0), DVec3::new(0.0, 0.02, 0.0)];
        let sh = SoftHeight {
            base: 0.0,
            top: 0.001,
            tau: 1e-5,
            edge: 1e-6,
        };
        let h = soft_heights(&grid, &xs, &sh);
        assert!((h[0] - 0.031).abs() < 1e-6, "{h:?}");
        assert!(h[2].abs() < 1e-12, "{h:?}");
        let hard = hard_heights(&grid, &xs, 0.0, 0.001);
        assert!((hard[0] - 0.031).abs() < 1e-15 && hard[1] == 0.0 && hard[2] == 0.0);
    }
}
