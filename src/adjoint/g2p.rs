//! Adjoint of stage 9, G2P. Forward: `v_p = Σ_i w_ip·v_i`, `C_p = k·Σ_i w_ip·v_i·d_ipᵀ` with
//! `k = 4/dx²` and `d_ip = x_i − x_p`. The adjoint of this gather is a scatter-add into the grid,
//! done with the same race-free slab schedule as P2G (fixed order, any thread count):
//!
//! ```text
//! v̄_i += Σ_p w_ip·(v̄_p + k·C̄_p·d_ip)
//! x̄_p += Σ_i ∇w_ip·(v_i·v̄_p + k·v_iᵀ·C̄_p·d_ip) − k·w_ip·C̄_pᵀ·v_i
//! ```
//!
//! Exact. Reads the substep-start `x` and the final grid velocity; consumes `v̄`, `C̄` (the
//! adjoints of G2P's outputs) and accumulates `x̄` and the grid velocity adjoint.

use crate::adjoint::NonFiniteSeen;
use crate::components::*;
use crate::math::kernel::stencil;
use crate::math::simd::{vectorized, Kernel};
use crate::systems::slab_schedule::SLAB;
use crate::systems::slab_schedule::{Cut, SlabSchedule};
use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3};
use rayon::prelude::*;

#[allow(clippy::type_complexity)]
pub fn g2p_adjoint(
    grid: Res<Grid>,
    mut adj: ResMut<GridAdj>,
    mut scratch: Local<Vec<DVec3>>,
    mut schedule: Local<SlabSchedule>,
    seen: Option<Res<NonFiniteSeen>>,
    mut bodies: Query<(
        &Body,
        &SubstepStart,
        &ScatterOrder,
        &mut PositionAdj,
        &mut VelocityAdj,
        &mut AffineVelocityAdj,
    )>,
) {
    let pl = grid.plane_len();
    let mut bodies: Vec<_> = bodies.iter_mut().collect();
    bodies.sort_by_key(|b| b.0.index);
    for (_, start, order, mut gx, mut gv, mut gc) in bodies {
        // One pass in P2G's slab order does both halves for each particle, from one stencil:
        // the scatter of v̄_i, and the gather of x̄_p over the final grid velocity, whose result
        // goes to `scratch` at the particle's place in that order (each particle has one place,
        // so the slabs write disjoint slices) and is added to x̄ afterwards.
        let gxs = &mut *scratch;
        gxs.clear();
        gxs.resize(order.order.len(), DVec3::ZERO);
        let (gvr, gcr) = (&gv.0, &gc.0);
        // `out` is the slab's planes, from its first one, `SLAB·slab`; `gx_out` its particles.
        let slab = |slab: usize, out: &mut [DVec3], gx_out: &mut [DVec3]| {
            let plane0 = SLAB * slab;
            let (s, e) = (
                order.slab_start[slab] as usize,
                order.slab_start[slab + 1] as usize,
            );
            vectorized(ScatterSlab {
                grid: &grid,
                plane0,
                order: &order.order[s..e],
                x: &start.x,
                g_v: gvr,
                g_c: gcr,
                out,
                gx_out,
            })
        };
        schedule.scatter(
            &order.slab_start,
            pl,
            &mut adj.velocity,
            gxs,
            Cut::Particles,
            slab,
        );
        let mut finite = true;
        for (&p, g) in order.order.iter().zip(scratch.iter()) {
            let gx = &mut gx.0[p as usize];
            *gx += *g;
            finite &= gx.is_finite();
        }
        NonFiniteSeen::check(seen.as_deref(), finite);
        // G2P overwrote v and C: their adjoints are consumed.
        gv.0.par_iter_mut().for_each(|g| *g = DVec3::ZERO);
        gc.0.par_iter_mut().for_each(|g| *g = DMat3::ZERO);
    }
}

/// One slab of the adjoint: the scatter of `v̄_i` into the slab's planes `out` (from x-plane
/// `plane0`) and the gather of `x̄_p` into `gx_out`, for the slab's particles `order` (through
/// [`vectorized`]).
struct ScatterSlab<'a> {
    grid: &'a Grid,
    plane0: usize,
    order: &'a [u32],
    x: &'a [DVec3],
    g_v: &'a [DVec3],
    g_c: &'a [DMat3],
    out: &'a mut [DVec3],
    gx_out: &'a mut [DVec3],
}

impl Kernel for ScatterSlab<'_> {
    type Output = ();
    #[inline(always)]
    fn run(self) {
        let Self {
            grid, plane0, out, ..
        } = self;
        let (dx, n) = (grid.dx, grid.n);
        let inv_dx = 1.0 / dx;
        let k = 4.0 * inv_dx * inv_dx;
        for (&p, gx) in self.order.iter().zip(self.gx_out.iter_mut()) {
            let p = p as usize;
            let st = stencil((self.x[p] - grid.origin) / dx);
            let [bi, bj, bk] = st.base;
            let (g_v, g_c) = (self.g_v[p], self.g_c[p]);
            // `v̄_p + k·C̄_p·d_ip`, what node `i` receives per unit weight, is affine in the
            // node offset. The scatter adds it times the weight; `Σ ∇w·v_i·(v̄_p + k·C̄_p·d)`
            // and `Σ w·v_i` are contracted one axis at a time, and the last term of x̄ is
            // `−k·C̄ᵀ·Σ w·v_i`, one matrix product per particle.
            let t = st.affine(g_v, g_c * k, dx);
            let sums = st.node_sums(inv_dx, |ia, ib, ic| {
                let row = ((bi + ia - plane0) * n[1] + bj + ib) * n[2] + bk;
                let tn = t.node(t.row(ia, ib), ic);
                out[row + ic] += tn * st.weight(ia, ib, ic);
                let vi = grid.velocity[grid.index(bi + ia, bj + ib, bk) + ic];
                (vi, vi.dot(tn))
            });
            *gx = sums.grad_s - g_c.transpose() * sums.w_g * k;
        }
    }
}
