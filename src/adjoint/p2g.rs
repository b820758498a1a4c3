//! Adjoint of stage 5, P2G. Forward: `m_i = Σ_p w_ip·m`, `p_i = Σ_p w_ip·(m·v_p + A_p·d_ip)`
//! with `d_ip = x_i − x_p`, and `v_i = p_i/m_i` on non-empty nodes. Adjoint (a gather, one
//! particle at a time, so deterministic for any thread count):
//!
//! ```text
//! p̄_i = v̄_i/m_i,   m̄_i = −v̄_i·v_i/m_i                       (non-empty nodes; 0 otherwise)
//! v̄_p += Σ_i w_ip·m·p̄_i
//! Ā_p += Σ_i w_ip·p̄_i·d_ipᵀ
//! x̄_p += Σ_i ∇w_ip·[(m·v_p + A_p·d_ip)·p̄_i + m·m̄_i] − w_ip·A_pᵀ·p̄_i
//! ```
//!
//! Exact, except where a positive empty-node threshold is crossed: there the forward jumps (the
//! node's velocity drops from `p/m` to 0), which no adjoint sees. At the default threshold, 0,
//! a node's mass and its weight in every gather vanish together, and nothing jumps. Reads the
//! substep-start `x`, `v`; consumes the grid's `v̄` (zeroes it); accumulates `v̄`, `Ā`, `x̄`.

use crate::adjoint::NonFiniteSeen;
use crate::components::*;
use crate::math::kernel::stencil;
use crate::math::simd::{vectorized, Kernel};
use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3};
use rayon::prelude::*;

pub fn p2g_adjoint(
    params: Res<SimParams>,
    grid: Res<Grid>,
    mut adj: ResMut<GridAdj>,
    seen: Option<Res<NonFiniteSeen>>,
    mut bodies: Query<(
        &Body,
        &SubstepStart,
        &P2gAffine,
        &mut PositionAdj,
        &mut VelocityAdj,
        &mut P2gAffineAdj,
    )>,
) {
    let seen = seen.as_deref();
    let m_min = params.empty_node_mass;
    // Node adjoints of momentum and mass from v = p/m, into the grid adjoint's own buffers (no
    // allocation per substep). Nothing else writes them, so they are set, not accumulated. P2G
    // writes every node's velocity without reading it, so v̄ is consumed here: zeroed, for the
    // previous substep's G2P adjoint to accumulate into.
    let GridAdj {
        mass: g_m,
        momentum: g_p,
        velocity: g_v,
    } = &mut *adj;
    g_p.par_iter_mut()
        .zip(g_m.par_iter_mut())
        .zip(g_v.par_iter_mut())
        .zip(grid.nodes.par_iter())
        .for_each(|(((gp, gm), gv), node)| {
            let Node {
                momentum: p,
                mass: m,
            } = *node;
            (*gp, *gm) = if m > m_min {
                // `−v̄·v/m`, not `−v̄·p/m²`: a node touched only by stencil tails weighs
                // m_p·(δ²/2)³ with δ down to round-off (an estimate, about 1e-90 kg on the
                // default scene), and a mass that small squared underflows.
                (*gv / m, -gv.dot(p / m) / m)
            } else {
                (DVec3::ZERO, 0.0)
            };
            *gv = DVec3::ZERO;
        });
    let (g_p, g_m) = (&*g_p, &*g_m);
    for (body, start, aff, mut gx, mut gv, mut ga) in &mut bodies {
        let m = body.particle_mass;
        gx.0.par_chunks_mut(CHUNK)
            .zip(gv.0.par_chunks_mut(CHUNK).zip(ga.0.par_chunks_mut(CHUNK)))
            .enumerate()
            .for_each(|(chunk, (gx, (gv, ga)))| {
                let first = chunk * CHUNK;
                vectorized(GatherChunk {
                    grid: &grid,
                    x: &start.x[first..first + gx.len()],
                    v: &start.v[first..first + gx.len()],
                    affine: &aff.0[first..first + gx.len()],
                    m,
                    g_p,
                    g_m,
                    seen,
                    gx,
                    gv,
                    ga,
                })
            });
    }
}

/// Particles per parallel task: one call into the vectorised loop per chunk.
const CHUNK: usize = 256;

/// The per-particle gather of the adjoint for a chunk of particles (through [`vectorized`]).
struct GatherChunk<'a> {
    grid: &'a Grid,
    x: &'a [DVec3],
    v: &'a [DVec3],
    affine: &'a [DMat3],
    m: f64,
    g_p: &'a [DVec3],
    g_m: &'a [f64],
    seen: Option<&'a NonFiniteSeen>,
    gx: &'a mut [DVec3],
    gv: &'a mut [DVec3],
    ga: &'a mut [DMat3],
}

impl Kernel for GatherChunk<'_> {
    type Output = ();
    #[inline(always)]
    fn run(self) {
        let Self {
            grid,
            m,
            g_p,
            g_m,
            seen,
            ..
        } = self;
        let dx = grid.dx;
        let inv_dx = 1.0 / dx;
        for (i, (gx, (gv, ga))) in self
            .gx
            .iter_mut()
            .zip(self.gv.iter_mut().zip(self.ga.iter_mut()))
            .enumerate()
        {
            let xp = self.x[i];
            let mv = self.v[i] * m;
            let a = self.affine[i];
            let st = stencil((xp - grid.origin) / dx);
            let [bi, bj, bk] = st.base;
            // `m·v_p + A_p·d_ip` is affine in the node offset; the node sums `Σ w·p̄`,
            // `Σ w·p̄·dᵀ` and `Σ ∇w·[(m·v_p + A_p·d)·p̄ + m·m̄]` are contracted one axis at a
            // time. `Σ w·p̄` serves both v̄_p (times m) and the last term of x̄_p (times −A_pᵀ).
            let t = st.affine(mv, a, dx);
            let sums = st.node_sums(inv_dx, |ia, ib, ic| {
                let node = grid.index(bi + ia, bj + ib, bk) + ic;
                let gp = g_p[node];
                (gp, t.node(t.row(ia, ib), ic).dot(gp) + m * g_m[node])
            });
            *gv += sums.w_g * m;
            *ga += sums.w_g_d(st.fx, dx);
            *gx += sums.grad_s - a.transpose() * sums.w_g;
            NonFiniteSeen::check(seen, gx.is_finite() && gv.is_finite() && ga.is_finite());
        }
    }
}
