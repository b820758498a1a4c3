//! Adjoint of stage 7, gravity `v_i += Δt·g` on non-empty nodes: the velocity adjoint passes
//! through unchanged, and `∂L/∂g += Δt·Σ_i v̄_i` over non-empty nodes. Exact.

use crate::components::*;
use bevy_ecs::prelude::*;
use glam::DVec3;

/// `∂L/∂g`, accumulated over the backward pass.
#[derive(Resource, Clone, Copy, Debug, Default)]
pub struct GravityAdj(pub DVec3);

pub fn gravity_adjoint(
    params: Res<SimParams>,
    grid: Res<Grid>,
    adj: Res<GridAdj>,
    mut g: ResMut<GravityAdj>,
) {
    let m_min = params.empty_node_mass;
    // Sequential: a fixed summation order keeps the gradient bitwise reproducible.
    // Only the active spans hold non-empty nodes, visited in index order as the dense loop
    // would: the same sum, bit for bit.
    let mut sum = DVec3::ZERO;
    let spans = grid.active.as_ref().map(|a| a.span.as_slice());
    for_span_ranges(spans, grid.node_count(), grid.n[2], |r| {
        for (v, node) in adj.velocity[r.clone()].iter().zip(&grid.nodes[r]) {
            if node.mass > m_min {
                sum += *v;
            }
        }
    });
    g.0 += sum * params.dt_sub;
}
