//! The region of a plate that powder is pushed or pulled into (seed B's four classes), its hard
//! and soft indicators, and the push loss: how far the powder still outside lies from it.
//!
//! The region is the part of a plate's top, a box of centre `c` and half extents `h`, beyond an
//! edge `x = b` on the side `s` (−1: toward −x, +1: toward +x). A grain at `x` is *short of* it
//! by `a₁ = s·(b − x)`, *off the plate* along x by `a₂ = |x − c_x| − h_x` and along z by
//! `a₃ = |z − c_z| − h_z`; it is inside when all three are negative (and it is above the
//! plate's bottom).
//!
//! **The push loss** ([`PlateRegion::distance`]) is the mean over grains of
//! `d = sp(a₁) + sp(a₂) + sp(a₃)`, with the softplus `sp(a) = w·ln(1 + e^(a/w))`: about the
//! distance a grain still has to travel into the region (within `w·ln 2` per face for a grain
//! on a face, and `≈ 0` deep inside). Unlike the soft count, whose logistic edge gives a
//! gradient only to the grains within a few `w` of the boundary, every grain outside pulls the
//! loss's gradient toward the region with a weight near 1, however far it is: a stroke that
//! stops short is told which way to reach further. The grains share one material in the push
//! task, so the mean over grains is the mass-weighted mean.

use glam::DVec3;

use super::geometry::logistic;

/// The region of a plate beyond an edge.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlateRegion {
    /// The plate's centre (m).
    pub centre: DVec3,
    /// The plate's half extents (m).
    pub half: DVec3,
    /// The region's edge along x (m).
    pub boundary: f64,
    /// The side: −1 for the part at smaller x, +1 for larger x.
    pub side: f64,
}

/// `sp(a) = w·ln(1 + e^(a/w))` and its derivative `σ(a/w)`, without overflow.
#[inline]
pub fn softplus(a: f64, w: f64) -> (f64, f64) {
    let z = a / w;
    let v = if z > 0.0 {
        a + w * (-z).exp().ln_1p()
    } else {
        w * z.exp().ln_1p()
    };
    (v, logistic(z))
}

impl PlateRegion {
    /// The three signed distances `(a₁, a₂, a₃)` (negative inside) and their gradients in x.
    fn faces(&self, x: DVec3) -> [(f64, DVec3); 3] {
        let dx = x.x - self.centre.x;
        let dz = x.z - self.centre.z;
        [
            (
                self.side * (self.boundary - x.x),
                DVec3::new(-self.side, 0.0, 0.0),
            ),
            (
                dx.abs() - self.half.x,
                DVec3::new(dx.signum() * f64::from(dx != 0.0), 0.0, 0.0),
            ),
            (
                dz.abs() - self.half.z,
                DVec3::new(0.0, 0.0, dz.signum() * f64::from(dz != 0.0)),
            ),
        ]
    }

    /// Whether `x` lies in the region (and above the plate's bottom).
    pub fn inside(&self, x: DVec3) -> bool {
        self.faces(x).iter().all(|(a, _)| *a < 0.0) && x.y > self.centre.y - self.half.y
    }

    /// The share of `xs` in the region.
    pub fn share<'a>(&self, xs: impl Iterator<Item = &'a DVec3>) -> f64 {
        let (mut k, mut n) = (0usize, 0usize);
        for x in xs {
            k += usize::from(self.inside(*x));
            n += 1;
        }
        k as f64 / n.max(1) as f64
    }

    /// The soft share outside: `1 − mean σ(−a₁/w)·σ(−a₂/w)·σ(−a₃/w)·σ((y − bottom)/w)`. At
    /// `w` half a 5 mm cell, the bottom's ramp counts a grain resting on a 5 mm plate about 8 %
    /// outside wherever it lies: an offset common to every stroke, which moves no optimiser's
    /// choice, and the reason the hard share is what the pages report.
    pub fn soft_outside<'a>(&self, xs: impl Iterator<Item = &'a DVec3>, w: f64) -> f64 {
        let (mut sum, mut n) = (0.0, 0.0);
        for x in xs {
            let [a1, a2, a3] = self.faces(*x);
            sum += logistic(-a1.0 / w)
                * logistic(-a2.0 / w)
                * logistic(-a3.0 / w)
                * logistic((x.y - (self.centre.y - self.half.y)) / w);
            n += 1.0;
        }
        1.0 - sum / f64::max(n, 1.0)
    }

    /// The push loss of one grain, `d = Σ sp(aᵢ)` (m), and `∂d/∂x`.
    pub fn distance(&self, x: DVec3, w: f64) -> (f64, DVec3) {
        let mut d = 0.0;
        let mut g = DVec3::ZERO;
        for (a, da) in self.faces(x) {
            let (v, dv) = softplus(a, w);
            d += v;
            g += dv * da;
        }
        (d, g)
    }

    /// The push loss `L = mean_p d(x_p)` (m) over every body's grains, and `∂L/∂x` per body.
    pub fn push_loss(&self, xs: &[Vec<DVec3>], w: f64) -> (f64, Vec<Vec<DVec3>>) {
        let n: usize = xs.iter().map(Vec::len).sum();
        let inv = 1.0 / n.max(1) as f64;
        let mut l = 0.0;
        let g = xs
            .iter()
            .map(|body| {
                body.iter()
                    .map(|x| {
                        let (d, g) = self.distance(*x, w);
                        l += d;
                        g * inv
                    })
                    .collect()
            })
            .collect();
        (l * inv, g)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn region() -> PlateRegion {
        PlateRegion {
            centre: DVec3::new(0.1, 0.0175, 0.06),
            half: DVec3::new(0.075, 0.0025, 0.04),
            boundary: 0.06,
            side: -1.0,
        }
    }

    /// Central differences in f64 with a step of 1e-7 m: the loss is smooth on the scale of
    /// `w` = 2.5 mm, so the truncation error is about (1e-7/w)² of the gradient, and round-off
    /// about 1e-16·d/1e-7; 1e-7 relative covers both.
    const FD_TOLERANCE: f64 = 1e-7;

    #[test]
    fn the_push_loss_gradient_matches_central_differences() {
        let r = region();
        let w = 0.0025;
        let xs = vec![
            vec![
                DVec3::new(0.09, 0.021, 0.05),
                DVec3::new(0.061, 0.02, 0.03),
                DVec3::new(0.04, 0.02, 0.099),
            ],
            vec![DVec3::new(0.18, 0.021, 0.101), DVec3::new(0.02, 0.0, 0.06)],
        ];
        let (_, g) = r.push_loss(&xs, w);
        let h = 1e-7;
        for b in 0..xs.len() {
            for i in 0..xs[b].len() {
                for k in 0..3 {
                    let mut p = xs.clone();
                    let mut m = xs.clone();
                    p[b][i][k] += h;
                    m[b][i][k] -= h;
                    let fd = (r.push_loss(&p, w).0 - r.push_loss(&m, w).0) / (2.0 * h);
                    let an = g[b][i][k];
                    assert!(
                        (fd - an).abs() <= FD_TOLERANCE * (1.0 + an.abs()),
                        "body {b} grain {i} axis {k}: {an} against {fd}"
                    );
                }
            }
        }
    }

    /// A grain short of the region by 30 mm pays about 30 mm and is pulled toward it with a
    /// weight of 1; one deep inside pays nearly nothing; the hard indicator agrees.
    #[test]
    fn the_distance_is_the_way_still_to_go() {
        let r = region();
        let w = 0.0025;
        let far = DVec3::new(0.09, 0.021, 0.06);
        let (d, g) = r.distance(far, w);
        assert!((d - 0.03).abs() < 1e-4, "{d}");
        assert!((g.x - 1.0).abs() < 1e-5 && g.z.abs() < 1e-5, "{g}");
        let deep = DVec3::new(0.04, 0.021, 0.06);
        assert!(r.distance(deep, w).0 < 1e-3 && r.inside(deep) && !r.inside(far));
        let mirrored = PlateRegion {
            boundary: 0.14,
            side: 1.0,
            ..r
        };
        let (dm, gm) = mirrored.distance(DVec3::new(0.2 - far.x, far.y, far.z), w);
        assert!((dm - d).abs() < 1e-12 && (gm.x + g.x).abs() < 1e-12);
        assert!((r.share([far, deep].iter()) - 0.5).abs() < 1e-12);
        // The bottom's ramp counts a grain on the plate's top, 6 mm above its bottom, 8 %
        // outside; the edges' ramps count it by their distance.
        assert!(r.soft_outside([deep].iter(), w) < 0.09);
        assert!(r.soft_outside([far].iter(), w) > 0.99);
    }

    #[test]
    fn softplus_does_not_overflow() {
        assert_eq!(softplus(1.0, 1e-6).0, 1.0);
        assert_eq!(softplus(-1.0, 1e-6), (0.0, 0.0));
        let (v, d) = softplus(0.0, 0.5);
        assert!((v - 0.5 * 2f64.ln()).abs() < 1e-15 && d == 0.5);
    }
}
