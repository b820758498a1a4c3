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
    let mut sum = DVec3::ZERO;
    for (v, &m) in adj.velocity.iter().zip(&grid.mass) {
        if m > m_min {
            sum += *v;
        }
    }
    g.0 += sum * params.dt_sub;
}
