//! Stage 8, grid collision: rigid colliders (tools, containers), then the domain walls.
//!
//! For a node at `x_i` with `φ(x_i) < band` against a collider, the velocity gets the contact
//! response of `crate::math::contact` with the SDF gradient as the normal and the collider's
//! rigid velocity at `x_i` (so friction acts on the velocity relative to the tool), in full or,
//! for a soft band, blended in by `1 − φ/band` (`crate::math::contact::band_weight`). Domain walls
//! act on the outer `cells` node layers of each face with the axis as the normal.
//!
//! Reads `Collider`, `ColliderPose`, `DomainWalls`, `SimParams`; writes `Grid::velocity`.

use crate::components::*;
use crate::math::contact::{band_weight, contact_response};
use bevy_ecs::prelude::*;
use glam::DVec3;
use rayon::prelude::*;

pub fn collider_contact(
    params: Res<SimParams>,
    mut grid: ResMut<Grid>,
    colliders: Query<(&Collider, &ColliderPose, Option<&NodeContacts>)>,
    mut save: Option<ResMut<ColliderInputVelocity>>,
) {
    let mut cs: Vec<_> = colliders
        .iter()
        .map(|(c, p, t)| (c, p, t.filter(|t| t.fits(p, &grid))))
        .collect();
    cs.sort_by_key(|c| c.0.index);
    let m_min = params.empty_node_mass;
    let g = &mut *grid;
    let (origin, dx, n) = (g.origin, g.dx, g.n);
    let node = |idx: usize, v: &mut DVec3, m: f64| {
        if m <= m_min {
            return;
        }
        let k = idx % n[2];
        let j = (idx / n[2]) % n[1];
        let i = idx / (n[1] * n[2]);
        let x = origin + DVec3::new(i as f64, j as f64, k as f64) * dx;
        for &(c, pose, table) in &cs {
            if let Some((phi, normal)) = node_contact(c, pose, table, idx, x) {
                let r = contact_response(*v, pose.velocity_at(x), normal, c.contact, c.friction);
                let (w, _) = band_weight(phi, c.band, c.soft_band);
                *v = if w == 1.0 { r } else { *v + (r - *v) * w };
            }
        }
    };
    let (nodes, active) = (&g.nodes, g.active.as_ref());
    if let Some(s) = save.as_deref_mut() {
        // The backward driver's recomputation: the input of every node acted on is saved.
        let v = &g.velocity;
        for_active_nodes(&mut s.0, n, active, |idx, s| {
            if nodes[idx].mass > m_min {
                *s = v[idx];
            }
        });
    }
    for_active_nodes(&mut g.velocity, n, active, |idx, v| {
        node(idx, v, nodes[idx].mass)
    });
}

/// The inward wall normal along axis `a` of the node at `coord`, if it lies in a wall layer.
#[inline(always)]
pub fn wall_normal(coord: [usize; 3], n: [usize; 3], cells: usize, a: usize) -> Option<DVec3> {
    let mut normal = DVec3::ZERO;
    if coord[a] < cells {
        normal[a] = 1.0;
    } else if coord[a] + cells >= n[a] {
        normal[a] = -1.0;
    } else {
        return None;
    }
    Some(normal)
}

/// Calls `f(coord, index, node)` for every non-empty node (`mass > m_min`) of an x-major node
/// array that lies in a wall layer, one x-plane per parallel task, without dividing flat
/// indices (the integer divisions cost more than the response on the half of the nodes that
/// are in no layer). Empty nodes are skipped: P2G left their velocity at +0, which no wall
/// response changes (see `contact_response`), and the P2G adjoint drops their adjoint, so the
/// walls and their adjoint have nothing to do there.
///
/// With `active` (the grid's [`ActiveRows`]), only the active spans are visited: every other
/// node is empty.
#[inline(always)]
pub fn for_wall_nodes<T: Send>(
    nodes: &mut [T],
    mass: &[Node],
    m_min: f64,
    n: [usize; 3],
    cells: usize,
    active: Option<&ActiveRows>,
    f: impl Fn([usize; 3], usize, &mut T) + Sync,
) {
    let in_layer = |c: usize, a: usize| c < cells || c + cells >= n[a];
    let plane_len = n[1] * n[2];
    nodes
        .par_chunks_mut(plane_len)
        .enumerate()
        .for_each(|(i, plane)| {
            for (j, row) in plane.chunks_mut(n[2]).enumerate() {
                let (k0, k1) = active.map_or((0, n[2]), |a| {
                    let s = a.span[i * n[1] + j];
                    (s[0] as usize, s[1] as usize)
                });
                let edge = in_layer(i, 0) || in_layer(j, 1);
                let row0 = i * plane_len + j * n[2];
                for (k, node) in row[k0..k1].iter_mut().enumerate() {
                    let k = k0 + k;
                    if (edge || in_layer(k, 2)) && mass[row0 + k].mass > m_min {
                        f([i, j, k], row0 + k, node);
                    }
                }
            }
        });
}

pub fn domain_walls(
    params: Res<SimParams>,
    walls: Res<DomainWalls>,
    mut grid: ResMut<Grid>,
    mut save: Option<ResMut<WallInputVelocity>>,
) {
    let (n, cells) = (grid.n, walls.cells);
    let g = &mut *grid;
    let m_min = params.empty_node_mass;
    let active = g.active.as_ref();
    if let Some(s) = save.as_deref_mut() {
        // The backward driver's recomputation: the input of every node acted on is saved (a
        // walk over the wall layers, far cheaper than copying the whole grid).
        let v = &g.velocity;
        for_wall_nodes(&mut s.0, &g.nodes, m_min, n, cells, active, |_, idx, s| {
            *s = v[idx]
        });
    }
    for_wall_nodes(
        &mut g.velocity,
        &g.nodes,
        m_min,
        n,
        cells,
        active,
        |coord, _, v| {
            for normal in (0..3).filter_map(|a| wall_normal(coord, n, cells, a)) {
                *v = contact_response(*v, DVec3::ZERO, normal, walls.mode, walls.friction);
            }
        },
    );
}
