//! Stage 5, P2G: MLS-MPM/APIC scatter with quadratic B-splines (Hu et al. 2018):
//!
//! ```text
//! m_i    += Σ_p w_ip·m_p
//! (mv)_i += Σ_p w_ip·(m_p·v_p + A_p·(x_i − x_p)),   A_p = m_p·C_p − Δt·V_p·(4/dx²)·τ_p
//! v_i     = (mv)_i / m_i   where m_i > m_min, else 0
//! ```
//!
//! **Race-free, fixed-order scatter.** Particles are bucketed by the x-slab of their stencil
//! base (slabs of [`SLAB`] = 2 x-planes; a stencil spans 3 planes, so slab `s` writes planes
//! `[2s, 2s + 4)`). A slab shares nodes only with its two neighbours; every node sums its even
//! slab's particles, then its odd slab's, each slab sequentially in particle order, and
//! [`SlabSchedule`] runs the slabs in parallel under that constraint (an odd slab once its two
//! even neighbours are done). The grid is x-major, so a slab's nodes are one contiguous range.
//! The summation order of every node is fixed by the scene, not by the thread count: results
//! are bitwise identical for any number of threads.
//!
//! **Active-block grid.** While it bins, P2G marks the rows of nodes that the stencils reach
//! ([`ActiveRows`]); the velocity pass and the later grid stages sweep those spans only.
//!
//! Reads `Body`, `Position`, `Velocity`, `P2gAffine`; writes `Grid` and `ScatterOrder`.

use crate::components::*;
use crate::math::kernel::stencil;
use crate::math::simd::{vectorized, Kernel};
use crate::systems::slab_schedule::{Cut, SlabSchedule, SLAB};
use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3};
use rayon::prelude::*;

/// Particles per chunk of [`bin_by_slab`]'s parallel pass. Fixed, so the chunks (and so the
/// order) do not depend on the thread count.
const BIN_CHUNK: usize = 4096;

/// Buckets particles by slab: a stable counting sort, so the order is deterministic (particle
/// index order within each slab). The slab of every particle and the per-chunk counts are
/// computed in parallel over fixed chunks; only the placement, an integer pass, is sequential.
pub fn bin_by_slab(grid: &Grid, x: &[DVec3], out: &mut ScatterOrder) {
    let n_slabs = grid.n[0].div_ceil(SLAB);
    let n_chunks = x.len().div_ceil(BIN_CHUNK);
    // The slab of a particle is that of its stencil's base node, computed exactly as `stencil`
    // does ((x − origin)/dx − ½, floored): multiplying by 1/dx instead can round a particle
    // sitting on a half-cell boundary to the other side, and the scatter would then index the
    // plane before its slab's chunk.
    let slab_of =
        |p: &DVec3| -> u32 { (stencil((*p - grid.origin) / grid.dx).base[0] / SLAB) as u32 };
    out.slab.resize(x.len(), 0);
    out.counts.clear();
    out.counts.resize(n_chunks * n_slabs, 0);
    out.slab
        .par_chunks_mut(BIN_CHUNK)
        .zip(x.par_chunks(BIN_CHUNK))
        .zip(out.counts.par_chunks_mut(n_slabs))
        .for_each(|((slabs, xs), counts)| {
            for (s, p) in slabs.iter_mut().zip(xs) {
                *s = slab_of(p);
                counts[*s as usize] += 1;
            }
        });
    // Cursors: slab by slab, chunk by chunk, so each slab holds its particles in index order.
    out.slab_start.clear();
    out.slab_start.resize(n_slabs + 1, 0);
    let mut acc = 0u32;
    for s in 0..n_slabs {
        out.slab_start[s] = acc;
        for c in 0..n_chunks {
            let k = c * n_slabs + s;
            let count = out.counts[k];
            out.counts[k] = acc;
            acc += count;
        }
    }
    out.slab_start[n_slabs] = acc;
    out.order.resize(x.len(), 0);
    for (c, slabs) in out.slab.chunks(BIN_CHUNK).enumerate() {
        let cursor = &mut out.counts[c * n_slabs..(c + 1) * n_slabs];
        for (k, &s) in slabs.iter().enumerate() {
            out.order[cursor[s as usize] as usize] = (c * BIN_CHUNK + k) as u32;
            cursor[s as usize] += 1;
        }
    }
}

/// Marks the base rows of a binned body's particles in `rows` (see [`ActiveRows`]): slab `s`
/// owns base x-planes `[SLAB·s, SLAB·s + SLAB)`, so the slabs mark disjoint rows in parallel,
/// and a minimum and a maximum do not depend on the order.
pub fn mark_active(
    rows: &mut ActiveRows,
    order: &ScatterOrder,
    x: &[DVec3],
    origin: DVec3,
    dx: f64,
    n: [usize; 3],
) {
    let ny = n[1];
    rows.base_mut()
        .par_chunks_mut(SLAB * ny)
        .enumerate()
        .for_each(|(slab, base)| {
            let Some(&e) = order.slab_start.get(slab + 1) else {
                return;
            };
            let s = order.slab_start[slab] as usize;
            for &p in &order.order[s..e as usize] {
                let [bi, bj, bk] = stencil((x[p as usize] - origin) / dx).base;
                ActiveRows::mark(&mut base[(bi - SLAB * slab) * ny + bj], bk);
            }
        });
}

/// Scatters one particle into the nodes of the slab that start at x-plane `plane0`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn scatter_particle(
    grid_origin: DVec3,
    dx: f64,
    n: [usize; 3],
    plane0: usize,
    nodes: &mut [Node],
    x: DVec3,
    mv: DVec3,
    affine: DMat3,
    m: f64,
) {
    let st = stencil((x - grid_origin) / dx);
    let [bi, bj, bk] = st.base;
    // `m·v_p + A_p·d_ip` is affine in the node's offset: a row's start plus whole multiples of
    // `A_p`'s columns, three additions per node instead of a matrix product. The node's mass
    // rides in the fourth lane, so a node takes one 4-wide multiply and add (`Node`).
    let t = st.affine(mv, affine, dx);
    for a in 0..3 {
        let wa = st.w[0][a];
        let row = (bi + a - plane0) * n[1];
        for b in 0..3 {
            let wab = wa * st.w[1][b];
            let start = t.row(a, b);
            let col = (row + bj + b) * n[2] + bk;
            for c in 0..3 {
                let w = wab * st.w[2][c];
                let p = t.node(start, c);
                let node = &mut nodes[col + c];
                node.momentum.x += w * p.x;
                node.momentum.y += w * p.y;
                node.momentum.z += w * p.z;
                node.mass += w * m;
            }
        }
    }
}

/// One slab's particles, `order`, scattered into its nodes, `nodes`, which start at x-plane
/// `plane0` (through [`vectorized`]).
struct ScatterSlab<'a> {
    origin: DVec3,
    dx: f64,
    n: [usize; 3],
    plane0: usize,
    nodes: &'a mut [Node],
    order: &'a [u32],
    x: &'a [DVec3],
    v: &'a [DVec3],
    affine: &'a [DMat3],
    m: f64,
}

impl Kernel for ScatterSlab<'_> {
    type Output = ();
    #[inline(always)]
    fn run(self) {
        for &p in self.order {
            let p = p as usize;
            scatter_particle(
                self.origin,
                self.dx,
                self.n,
                self.plane0,
                self.nodes,
                self.x[p],
                self.v[p] * self.m,
                self.affine[p],
                self.m,
            );
        }
    }
}

pub fn p2g(
    params: Res<SimParams>,
    mut grid: ResMut<Grid>,
    mut health: ResMut<Health>,
    mut schedule: Local<SlabSchedule>,
    mut bodies: Query<(&Body, &Position, &Velocity, &P2gAffine, &mut ScatterOrder)>,
) {
    let mut bodies: Vec<_> = bodies.iter_mut().collect();
    bodies.sort_by_key(|b| b.0.index);
    let g = &mut *grid;
    let (origin, dx, n) = (g.origin, g.dx, g.n);
    let pl = g.plane_len();
    // The active-block grid: the spans that this substep's stencils reach, marked body by body
    // from the slab binning (see `ActiveRows`). A grid without tracking stays dense.
    let mut active = g.active.take().filter(|_| g.sparse);
    if let Some(rows) = active.as_mut() {
        rows.clear(n);
    }
    for (body, x, v, aff, mut order) in bodies {
        bin_by_slab(g, &x.0, &mut order);
        if let Some(rows) = active.as_mut() {
            mark_active(rows, &order, &x.0, origin, dx, n);
        }
        let m = body.particle_mass;
        let order = &*order;
        let scatter_slab = |slab: usize, nodes: &mut [Node], _: &mut [()]| {
            let (s, e) = (
                order.slab_start[slab] as usize,
                order.slab_start[slab + 1] as usize,
            );
            vectorized(ScatterSlab {
                origin,
                dx,
                n,
                plane0: SLAB * slab,
                nodes,
                order: &order.order[s..e],
                x: &x.0,
                v: &v.0,
                affine: &aff.0,
                m,
            })
        };
        schedule.scatter(
            &order.slab_start,
            pl,
            &mut g.nodes,
            &mut [],
            Cut::None,
            scatter_slab,
        );
    }
    if let Some(rows) = active.as_mut() {
        rows.finish(n);
    }
    g.active = active;
    let m_min = params.empty_node_mass;
    let watch = crate::systems::FiniteWatch::default();
    let nodes = &g.nodes;
    for_active_nodes(&mut g.velocity, n, g.active.as_ref(), |idx, v| {
        let Node { momentum, mass: m } = nodes[idx];
        *v = if m > m_min { momentum / m } else { DVec3::ZERO };
        watch.check(v.is_finite());
    });
    if let Some(i) = watch.first_nonfinite_vec(&g.velocity) {
        health.report(Fault {
            stage: "p2g",
            field: "grid velocity",
            owner: "grid node".into(),
            index: i,
            value: format!("{:?}", g.velocity[i]),
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Particles on a half-cell boundary, where `x·(1/dx)` and `x/dx` round apart: each is binned
    /// into the slab of its own stencil base (a mismatch made the scatter index out of bounds).
    #[test]
    fn binning_agrees_with_the_stencil_on_half_cell_boundaries() {
        let dx = 0.0025;
        let grid = Grid::new(DVec3::ZERO, dx, [64, 8, 8]);
        let mut disagreements = 0;
        for k in 2..60 {
            let mut x = (k as f64 + 0.5) * dx;
            for _ in 0..64 {
                x = f64::from_bits(x.to_bits() - 1);
                let mul = (x * (1.0 / dx) - 0.5).floor() as usize;
                let base = stencil(DVec3::new(x, 0.01, 0.01) / dx).base[0];
                disagreements += usize::from(mul != base);
                let mut order = ScatterOrder::default();
                bin_by_slab(&grid, &[DVec3::new(x, 0.01, 0.01)], &mut order);
                let slab = base / SLAB;
                assert_eq!(
                    order.slab_start[slab + 1] - order.slab_start[slab],
                    1,
                    "x = {x:e}"
                );
            }
        }
        // The test exercises the case it is about.
        assert!(disagreements > 0);
    }

    /// The scatter compiled for AVX2 (where the CPU has it) adds the same bits as the baseline
    /// build: the node layout and the wider registers change no operation and no order.
    #[test]
    fn vectorized_scatter_equals_the_baseline_bit_for_bit() {
        use crate::math::simd::baseline;
        let dx = 0.01;
        let n = [12, 10, 9];
        let mut rng = crate::util::Lcg(11);
        let mut u = || rng.uniform();
        let count = 500;
        let x: Vec<DVec3> = (0..count)
            .map(|_| DVec3::new(2.0 + 7.0 * u(), 2.0 + 5.0 * u(), 2.0 + 4.0 * u()) * dx)
            .collect();
        let v: Vec<DVec3> = (0..count)
            .map(|_| DVec3::new(u() - 0.5, u() - 0.5, u() - 0.5))
            .collect();
        let affine: Vec<DMat3> = (0..count)
            .map(|_| DMat3::from_cols_array(&std::array::from_fn(|_| u() - 0.5)))
            .collect();
        let order: Vec<u32> = (0..count as u32).collect();
        let run = |vector: bool| {
            let mut nodes = vec![Node::ZERO; n[0] * n[1] * n[2]];
            let k = ScatterSlab {
                origin: DVec3::ZERO,
                dx,
                n,
                plane0: 0,
                nodes: &mut nodes,
                order: &order,
                x: &x,
                v: &v,
                affine: &affine,
                m: 0.3,
            };
            if vector {
                vectorized(k)
            } else {
                baseline(k)
            }
            nodes
        };
        let (a, b) = (run(true), run(false));
        let bits = |n: &Node| [n.momentum.x, n.momentum.y, n.momentum.z, n.mass].map(f64::to_bits);
        assert!(a.iter().any(|n| n.mass > 0.0));
        assert!(a.iter().zip(&b).all(|(a, b)| bits(a) == bits(b)));
    }

    /// Over several chunks of the parallel pass, the order is the stable sort of the particle
    /// indices by slab, and the slab starts bound each slab's particles.
    #[test]
    fn binning_is_the_stable_sort_by_slab() {
        let dx = 0.01;
        let grid = Grid::new(DVec3::ZERO, dx, [40, 6, 6]);
        let mut rng = crate::util::Lcg(7);
        let x: Vec<DVec3> = (0..3 * BIN_CHUNK + 123)
            .map(|_| {
                let u = rng.uniform();
                DVec3::new((2.0 + 35.0 * u) * dx, 0.03, 0.03)
            })
            .collect();
        let slab = |p: &DVec3| stencil(*p / dx).base[0] / SLAB;
        let mut expected: Vec<u32> = (0..x.len() as u32).collect();
        expected.sort_by_key(|&i| slab(&x[i as usize]));
        let mut order = ScatterOrder::default();
        bin_by_slab(&grid, &x, &mut order);
        assert_eq!(order.order, expected);
        for s in 0..order.slab_start.len() - 1 {
            let (a, b) = (
                order.slab_start[s] as usize,
                order.slab_start[s + 1] as usize,
            );
            assert!(order.order[a..b].iter().all(|&i| slab(&x[i as usize]) == s));
        }
    }
}
