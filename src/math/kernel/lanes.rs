//! G2P's gather ([`super::gather_velocity`]) four particles at a time, one particle to a lane of
//! a [`Vector`]: AVX registers where the CPU has AVX2, arrays elsewhere.
//!
//! Each lane performs the scalar gather's operations in the scalar gather's order (the stencil
//! itself is computed per particle by the scalar [`super::stencil`]), so every lane is the
//! scalar result to the bit (`lanes_equal_the_scalar_gather`). What the lanes save is the
//! arithmetic: the contraction's ~500 multiplies and adds per particle run four to an
//! instruction. The 27 node velocities of each particle are read one by one and inserted into
//! the registers ([`Vector::from_fn`]); loading each row of three nodes as two 4-wide loads and
//! transposing them in registers was measured at 0.95–1.00× the stage's time, within the noise,
//! and left out.

use super::{gather_velocity, stencil, GridView, Stencil};
use crate::math::lanes::{Arr, Vector};
use glam::{DMat3, DVec3};

/// Particles per group.
pub const LANES: usize = 4;

type V3<V> = [V; 3];

#[inline(always)]
fn axpy<V: Vector<Scalar = f64>>(acc: &mut V3<V>, g: &V3<V>, w: V) {
    for k in 0..3 {
        acc[k] = acc[k] + g[k] * w;
    }
}

/// The gather of `LANES` particles whose stencils are `st`, lane by lane the operations of
/// [`super::Stencil::node_sums`] (the sums `Σ w·g` and `Σ w·g·oᵀ` only) and
/// [`super::NodeSums::w_g_d`].
// The loops index by node offset, as the scalar `node_sums` they mirror does.
#[allow(clippy::needless_range_loop)]
#[inline(always)]
fn gather_packed<V: Vector<Scalar = f64>>(
    grid: &GridView,
    st: &[Stencil; LANES],
) -> [(DVec3, DMat3); LANES] {
    let [n1, n2] = [grid.n[1], grid.n[2]];
    // No closure here returns a vector (`docs/design.md` §11): the ones below give scalars.
    let mut w = [[V::splat(0.0); 3]; 3];
    for (axis, w) in w.iter_mut().enumerate() {
        for (i, w) in w.iter_mut().enumerate() {
            *w = V::from_fn(|l| st[l].w[axis][i]);
        }
    }
    let [wx, wy, wz] = w;
    let zero = V::splat(0.0);
    let idx: [V; 3] = [V::splat(0.0), V::splat(1.0), V::splat(2.0)];
    let mut w_g = [zero; 3];
    let mut w_g_o = [[zero; 3]; 3];
    for a in 0..3 {
        let (mut y_g, mut y_gb, mut y_gc) = ([zero; 3], [zero; 3], [zero; 3]);
        for b in 0..3 {
            // The three nodes along z of row (a, b), for each lane.
            let rows: [&[DVec3]; LANES] = std::array::from_fn(|l| {
                let [bi, bj, bk] = st[l].base;
                let start = ((bi + a) * n1 + bj + b) * n2 + bk;
                &grid.velocity[start..start + 3]
            });
            let (mut z_g, mut z_gc) = ([zero; 3], [zero; 3]);
            for c in 0..3 {
                let g: V3<V> = [
                    V::from_fn(|l| rows[l][c].x),
                    V::from_fn(|l| rows[l][c].y),
                    V::from_fn(|l| rows[l][c].z),
                ];
                axpy(&mut z_g, &g, wz[c]);
                axpy(&mut z_gc, &g, wz[c] * idx[c]);
            }
            axpy(&mut y_g, &z_g, wy[b]);
            axpy(&mut y_gb, &z_g, wy[b] * idx[b]);
            axpy(&mut y_gc, &z_gc, wy[b]);
        }
        axpy(&mut w_g, &y_g, wx[a]);
        axpy(&mut w_g_o[0], &y_g, wx[a] * idx[a]);
        axpy(&mut w_g_o[1], &y_gb, wx[a]);
        axpy(&mut w_g_o[2], &y_gc, wx[a]);
    }
    // `w_g_d`: column j is (Σ w·g·o_j − (Σ w·g)·fx_j)·dx, then the whole matrix times 4/dx².
    let dx = V::splat(grid.dx);
    let scale = V::splat(4.0 / (grid.dx * grid.dx));
    let mut cols = [[zero; 3]; 3];
    for (j, col) in cols.iter_mut().enumerate() {
        let fx = V::from_fn(|l| st[l].fx[j]);
        for (k, e) in col.iter_mut().enumerate() {
            *e = (w_g_o[j][k] - w_g[k] * fx) * dx * scale;
        }
    }
    let mut v = [[0.0; LANES]; 3];
    let mut c = [[[0.0; LANES]; 3]; 3];
    for k in 0..3 {
        w_g[k].store(&mut v[k]);
        for j in 0..3 {
            cols[j][k].store(&mut c[j][k]);
        }
    }
    std::array::from_fn(|l| {
        let col = |j: usize| DVec3::new(c[j][0][l], c[j][1][l], c[j][2][l]);
        (
            DVec3::new(v[0][l], v[1][l], v[2][l]),
            DMat3::from_cols(col(0), col(1), col(2)),
        )
    })
}

/// The gather of every particle of `x` into `v` and `c`, groups of [`LANES`] in lanes and the
/// rest one at a time; lane by lane the scalar result to the bit.
#[inline(always)]
fn gather_all<V: Vector<Scalar = f64>>(
    grid: &GridView,
    x: &[DVec3],
    v: &mut [DVec3],
    c: &mut [DMat3],
) {
    let mut xs = x.chunks_exact(LANES);
    let mut vs = v.chunks_exact_mut(LANES);
    let mut cs = c.chunks_exact_mut(LANES);
    for ((x, v), c) in (&mut xs).zip(&mut vs).zip(&mut cs) {
        let st: [Stencil; LANES] = std::array::from_fn(|l| stencil((x[l] - grid.origin) / grid.dx));
        for (l, (vp, cp)) in gather_packed::<V>(grid, &st).into_iter().enumerate() {
            v[l] = vp;
            c[l] = cp;
        }
    }
    let tail = xs.remainder().iter();
    for ((x, v), c) in tail.zip(vs.into_remainder()).zip(cs.into_remainder()) {
        (*v, *c) = gather_velocity(grid, *x);
    }
}

/// [`super::gather_velocity`] for every particle of `x`, into `v` (velocity) and `c` (affine
/// velocity), in AVX registers where the CPU has AVX2; the scalar gather's bits either way.
pub fn gather_many(grid: &GridView, x: &[DVec3], v: &mut [DVec3], c: &mut [DMat3]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, which is all the function's target features ask for.
        return unsafe { gather_avx2(grid, x, v, c) };
    }
    gather_all::<Arr<f64, LANES>>(grid, x, v, c)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn gather_avx2(grid: &GridView, x: &[DVec3], v: &mut [DVec3], c: &mut [DMat3]) {
    gather_all::<crate::math::lanes::F64x4>(grid, x, v, c)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bits_of(v: &[DVec3], c: &[DMat3]) -> Vec<u64> {
        v.iter()
            .flat_map(|v| v.to_array())
            .chain(c.iter().flat_map(|c| c.to_cols_array()))
            .map(f64::to_bits)
            .collect()
    }

    /// A grid of arbitrary O(1) velocities (with a signed zero, a subnormal and a large value
    /// among them), and particles spread over it including ones on cell faces and half-cells.
    fn scene() -> (Vec<DVec3>, [usize; 3], Vec<DVec3>) {
        let n = [9, 8, 10];
        let velocity: Vec<DVec3> = (0..n[0] * n[1] * n[2])
            .map(|i| {
                let t = i as f64;
                match i % 97 {
                    5 => DVec3::new(-0.0, 0.0, 1e-310),
                    6 => DVec3::new(3e200, -2.5, 0.125),
                    _ => DVec3::new((1.3 * t).sin(), (0.7 * t).cos() - 0.2, (0.37 * t).sin()),
                }
            })
            .collect();
        let mut x = vec![
            DVec3::new(0.02, 0.02, 0.02),
            DVec3::new(0.025, 0.03, 0.035),
            DVec3::new(0.05, 0.045, 0.07),
        ];
        for k in 0..41 {
            let t = k as f64;
            x.push(DVec3::new(
                0.02 + 0.015 * (0.9 * t).sin().abs() * 3.0,
                0.02 + 0.01 * (1.7 * t).cos().abs() * 3.0,
                0.02 + 0.012 * (0.3 * t).sin().abs() * 4.0,
            ));
        }
        (velocity, n, x)
    }

    /// Every lane of the portable arrays and of the AVX registers is the scalar gather's
    /// result to the bit, the tail (44 particles: 11 groups, then none; and 43: a tail of 3)
    /// included.
    #[test]
    fn lanes_equal_the_scalar_gather() {
        let (velocity, n, x) = scene();
        let grid = GridView {
            velocity: &velocity,
            origin: DVec3::new(0.001, -0.002, 0.0),
            dx: 0.01,
            n,
        };
        for count in [x.len(), x.len() - 1] {
            let x = &x[..count];
            let (mut v, mut c) = (vec![DVec3::ZERO; count], vec![DMat3::ZERO; count]);
            for (p, (v, c)) in x.iter().zip(v.iter_mut().zip(c.iter_mut())) {
                (*v, *c) = gather_velocity(&grid, *p);
            }
            let want = bits_of(&v, &c);
            let (mut v, mut c) = (vec![DVec3::ZERO; count], vec![DMat3::ZERO; count]);
            gather_all::<Arr<f64, LANES>>(&grid, x, &mut v, &mut c);
            assert_eq!(bits_of(&v, &c), want, "portable lanes");
            let (mut v, mut c) = (vec![DVec3::ZERO; count], vec![DMat3::ZERO; count]);
            gather_many(&grid, x, &mut v, &mut c);
            assert_eq!(bits_of(&v, &c), want, "dispatched lanes");
        }
    }
}
