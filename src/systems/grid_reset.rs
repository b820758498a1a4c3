//! Stage 1, grid reset: `m_i = 0`, `(mv)_i = 0` and, on the active-block grid, `v_i = 0`, for
//! every node that may be non-zero.
//!
//! With the active-block grid ([`Grid::active`]), only the previous substep's active spans can
//! hold non-zero values, so only they are zeroed: the cost follows the nodes the powder reaches,
//! not the domain's size. Without it (the first substep, or a dense grid), every node is.
//!
//! Reads nothing; writes `Grid`.

use crate::components::{for_active_nodes, ActiveRows, Grid, Node};
use bevy_ecs::prelude::*;
use glam::DVec3;

pub fn grid_reset(mut grid: ResMut<Grid>) {
    let g = &mut *grid;
    let (n, active) = (g.n, g.active.as_ref());
    for_active_nodes(&mut g.nodes, n, active, |_, p| *p = Node::ZERO);
    if g.sparse {
        // A dense P2G writes every node's velocity; a sparse one only the active spans.
        for_active_nodes(&mut g.velocity, n, active, |_, v| *v = DVec3::ZERO);
    }
    if g.active.is_none() && g.sparse {
        // Every node is zero now: from here on P2G tracks the active part.
        g.active = Some(ActiveRows::empty(n));
    } else if !g.sparse {
        g.active = None;
    }
}
