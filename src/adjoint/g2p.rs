//! Adjoint of stage 9, G2P. Forward: `v_p = Σ_i w_ip·v_i`, `C_p = k·Σ_i w_ip·v_i·d_ipᵀ` with
//! `k = 4/dx²` and `d_ip = x_i − x_p`. The adjoint of this gather is a scatter-add into the grid,
//! done with the same race-free slab colouring as P2G (fixed order, any thread count):
//!
//! ```text
//! v̄_i += Σ_p w_ip·(v̄_p + k·C̄_p·d_ip)
//! x̄_p += Σ_i ∇w_ip·(v_i·v̄_p + k·v_iᵀ·C̄_p·d_ip) − k·w_ip·C̄_pᵀ·v_i
//! ```
//!
//! Exact. Reads the substep-start `x` and the final grid velocity; consumes `v̄`, `C̄` (the
//! adjoints of G2P's outputs) and accumulates `x̄` and the grid velocity adjoint.

use crate::components::*;
use crate::math::kernel::stencil;
use crate::systems::p2g::SLAB;
use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3};
use rayon::prelude::*;

#[allow(clippy::type_complexity)]
pub fn g2p_adjoint(
    grid: Res<Grid>,
    mut adj: ResMut<GridAdj>,
    mut bodies: Query<(
        &Body,
        &SubstepStart,
        &ScatterOrder,
        &mut PositionAdj,
        &mut VelocityAdj,
        &mut AffineVelocityAdj,
    )>,
) {
    let dx = grid.dx;
    let inv_dx = 1.0 / dx;
    let k = 4.0 * inv_dx * inv_dx;
    let n = grid.n;
    let pl = grid.plane_len();
    let mut bodies: Vec<_> = bodies.iter_mut().collect();
    bodies.sort_by_key(|b| b.0.index);
    for (_, start, order, mut gx, mut gv, mut gc) in bodies {
        // x̄: a gather over the final grid velocity.
        gx.0.par_iter_mut().enumerate().for_each(|(i, gx)| {
            let xp = start.x[i];
            let st = stencil((xp - grid.origin) / dx);
            let [bi, bj, bk] = st.base;
            let (g_v, g_c) = (gv.0[i], gc.0[i]);
            // `v̄_p + k·C̄_p·d_ip`, what node `i` receives per unit weight, is affine in the node
            // offset; `Σ ∇w·v_i·(v̄_p + k·C̄_p·d)` and `Σ w·v_i` are contracted one axis at a
            // time, and the last term is `−k·C̄ᵀ·Σ w·v_i`, one matrix product per particle.
            let t = st.affine(g_v, g_c * k, dx);
            let sums = st.node_sums(inv_dx, |ia, ib, ic| {
                let vi = grid.velocity[grid.index(bi + ia, bj + ib, bk) + ic];
                (vi, vi.dot(t.node(t.row(ia, ib), ic)))
            });
            *gx += sums.grad_s - g_c.transpose() * sums.w_g * k;
        });
        // v̄_i: a scatter, slab-coloured exactly like P2G.
        let scatter_slab = |slab: usize, plane0: usize, out: &mut [DVec3]| {
            if slab + 1 >= order.slab_start.len() {
                return;
            }
            let (s, e) = (
                order.slab_start[slab] as usize,
                order.slab_start[slab + 1] as usize,
            );
            for &p in &order.order[s..e] {
                let p = p as usize;
                let st = stencil((start.x[p] - grid.origin) / dx);
                let [bi, bj, bk] = st.base;
                let t = st.affine(gv.0[p], gc.0[p] * k, dx);
                for ia in 0..3 {
                    for ib in 0..3 {
                        let row = ((bi + ia - plane0) * n[1] + bj + ib) * n[2] + bk;
                        let t_row = t.row(ia, ib);
                        for ic in 0..3 {
                            let w = st.weight(ia, ib, ic);
                            out[row + ic] += t.node(t_row, ic) * w;
                        }
                    }
                }
            }
        };
        let chunk = 2 * SLAB * pl;
        adj.velocity
            .par_chunks_mut(chunk)
            .enumerate()
            .for_each(|(c, out)| scatter_slab(2 * c, 2 * SLAB * c, out));
        let off = (SLAB * pl).min(adj.velocity.len());
        adj.velocity[off..]
            .par_chunks_mut(chunk)
            .enumerate()
            .for_each(|(c, out)| scatter_slab(2 * c + 1, 2 * SLAB * c + SLAB, out));
        // G2P overwrote v and C: their adjoints are consumed.
        gv.0.par_iter_mut().for_each(|g| *g = DVec3::ZERO);
        gc.0.par_iter_mut().for_each(|g| *g = DMat3::ZERO);
    }
}
