//! Adjoint of stage 8, grid collision. Domain walls: the forward applies the contact response
//! for each axis in turn, with a fixed axis normal and zero wall velocity; the adjoint replays
//! the three responses from the input velocity the forward saved ([`WallInputVelocity`]) and
//! applies `contact_response_adj` in reverse. Exact inside each contact regime, one-sided at
//! the switches (see `crate::math::contact`).
//!
//! Colliders: the adjoint replays each node's sequence of collider responses from the saved
//! input velocity ([`ColliderInputVelocity`]) and reverses it, accumulating `∂L/∂v` and `∂L/∂μ`
//! per collider, and for a tool the adjoints of its pose and velocity
//! (`NodeAdj::add_tool_contact`). The band test `φ < band` is a contact on/off switch: the
//! gradient is that of the side the forward pass took (one-sided; see
//! [`collider_contact_adjoint`] for the soft band).

use crate::components::*;
use crate::math::contact::{band_weight, contact_response, contact_response_adj};
use crate::systems::grid_collision::{for_wall_nodes, wall_normal};
use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3};
use rayon::prelude::*;

pub use crate::components::{ColliderInputVelocity, WallInputVelocity};

/// Adjoints of a collider's parameters and motion: `∂L/∂μ`, and for a tool `∂L/∂t` (its
/// current translation), `∂L/∂θ` (its current rotation, as a world-frame rotation-vector
/// perturbation `δR = [δθ]×·R`), and `∂L/∂v_lin`, `∂L/∂ω` (its velocities over the substep).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct ColliderAdj {
    pub friction: f64,
    pub translation: DVec3,
    pub rotation: DVec3,
    pub linear: DVec3,
    pub angular: DVec3,
}

/// Nodes or particles per chunk of the collider-gradient reduction (fixed, so the sum order is
/// too). Small enough that the default scene's 3,773 particles make several chunks: a single
/// chunk ran the particle-collision adjoint on one thread.
pub(crate) const REDUCE_CHUNK: usize = 512;

/// Most colliders a node's response sequence is replayed for.
pub const MAX_COLLIDERS: usize = 4;

/// A collider's adjoints summed over one chunk of nodes or particles (a partial of
/// [`ColliderAdj`]).
#[derive(Clone, Copy, Default)]
pub struct NodeAdj {
    pub(crate) friction: f64,
    pub(crate) translation: DVec3,
    pub(crate) rotation: DVec3,
    pub(crate) linear: DVec3,
    pub(crate) angular: DVec3,
}

impl NodeAdj {
    /// Adds the adjoints of a tool's pose and velocity from one contact: `n̄` of the normal
    /// `n = R·∇φ_l(Rᵀ(x − t))`, `φ̄` of the distance and `v̄_b` of `v_b = v_lin + ω × (x − t)`.
    /// Returns `∂L/∂x` of the contact point.
    ///
    /// ```text
    /// x̄ = φ̄·n + R·H·Rᵀ·n̄ + v̄_b × ω,   t̄ −= x̄
    /// θ̄ += φ̄·(n × r) + n × n̄ + (R·H·Rᵀ·n̄) × r,   v̄_lin += v̄_b,   ω̄ += r × v̄_b
    /// ```
    pub(crate) fn add_tool_contact(
        &mut self,
        pose: &ColliderPose,
        h_world: DMat3,
        x: DVec3,
        n: DVec3,
        (g_phi, g_n, g_vb): (f64, DVec3, DVec3),
    ) -> DVec3 {
        let r = x - pose.pose.translation;
        let hn = h_world * g_n;
        let g_x = n * g_phi + hn + g_vb.cross(pose.angular);
        self.translation -= g_x;
        self.rotation += n.cross(r) * g_phi + n.cross(g_n) + hn.cross(r);
        self.linear += g_vb;
        self.angular += r.cross(g_vb);
        g_x
    }
}

/// `R·H·Rᵀ`: the world-frame Hessian of a collider's SDF at `x`.
pub(crate) fn world_hessian(
    shape: &crate::math::sdf::Shape,
    pose: &ColliderPose,
    x: DVec3,
) -> DMat3 {
    let r = DMat3::from_quat(pose.pose.rotation);
    r * shape
        .sdf_hessian(pose.pose.to_local(x))
        .unwrap_or(DMat3::ZERO)
        * r.transpose()
}

/// Per-collider adjoints accumulated over one chunk of [`REDUCE_CHUNK`] grid nodes or
/// particles.
pub type ChunkAdj = [NodeAdj; MAX_COLLIDERS];

/// Adds the chunks' collider adjoints, in chunk order, into the colliders' [`ColliderAdj`]:
/// the chunks are fixed-size, so the sum order does not depend on the thread count.
pub(crate) fn add_collider_adjoints<'a>(
    chunks: &[ChunkAdj],
    colliders: impl Iterator<Item = &'a mut ColliderAdj>,
) {
    for (ci, ca) in colliders.enumerate() {
        for ch in chunks {
            let p = &ch[ci];
            ca.friction += p.friction;
            ca.translation += p.translation;
            ca.rotation += p.rotation;
            ca.linear += p.linear;
            ca.angular += p.angular;
        }
    }
}

/// Collider contact. For a node with `φ(x_i) < band`, `v′ = response(v, v_b, n)` with
/// `v_b = v_lin + ω × (x_i − t)` and `n = R·∇φ_local(Rᵀ(x_i − t))`; besides `v̄` and `μ̄` the
/// tool's pose and velocity adjoints follow [`NodeAdj::add_tool_contact`] (H: the Hessian of
/// the local SDF).
///
/// Exact within a contact regime; the separate/approach switch is one-sided. With a hard band
/// the band test moves with the tool: a node entering or leaving the band is a jump the adjoint
/// does not see (the reason finite differences through contact need a small step, see
/// shared/reference/RESULTS.md). A soft band blends the response in by `w(φ) = 1 − φ/band`,
/// which is continuous at the band's edge: the jump becomes a kink, and `φ̄ = w′·(r − v)·v̄′`
/// carries the pose's influence through the blend weight.
pub fn collider_contact_adjoint(
    params: Res<SimParams>,
    grid: Res<Grid>,
    input: Res<ColliderInputVelocity>,
    mut adj: ResMut<GridAdj>,
    mut chunks: Local<Vec<ChunkAdj>>,
    mut colliders: Query<(
        &Collider,
        &ColliderPose,
        Option<&NodeContacts>,
        &mut ColliderAdj,
    )>,
) {
    let mut cs: Vec<_> = colliders.iter_mut().collect();
    cs.sort_by_key(|c| c.0.index);
    assert!(
        cs.len() <= MAX_COLLIDERS,
        "the backward driver refuses more than {MAX_COLLIDERS} colliders"
    );
    let m_min = params.empty_node_mass;
    let view: Vec<(&Collider, &ColliderPose, Option<&NodeContacts>)> = cs
        .iter()
        .map(|(c, p, t, _)| (*c, *p, t.filter(|t| t.fits(p, &grid))))
        .collect();
    let node = |idx: usize, g: &mut DVec3, acc: &mut ChunkAdj| {
        if grid.nodes[idx].mass <= m_min {
            return;
        }
        let x = grid.node_position(idx);
        let mut hits = [(0usize, DVec3::ZERO, DVec3::ZERO, DVec3::ZERO, 0.0); MAX_COLLIDERS];
        let mut count = 0;
        let mut v = input.0[idx];
        for (ci, &(c, pose, table)) in view.iter().enumerate() {
            if let Some((phi, normal)) = node_contact(c, pose, table, idx, x) {
                let vb = pose.velocity_at(x);
                hits[count] = (ci, v, normal, vb, phi);
                let r = contact_response(v, vb, normal, c.contact, c.friction);
                let (w, _) = band_weight(phi, c.band, c.soft_band);
                v = if w == 1.0 { r } else { v + (r - v) * w };
                count += 1;
            }
        }
        for &(ci, vin, normal, vb, phi) in hits[..count].iter().rev() {
            let (c, pose, _) = view[ci];
            // v′ = v + w(φ)·(r − v): r̄ = w·v̄′, v̄ = (1 − w)·v̄′ + (∂r/∂v)ᵀ·r̄, φ̄ = w′·(r − v)·v̄′.
            let (w, dw) = band_weight(phi, c.band, c.soft_band);
            let g_out = *g;
            let a = contact_response_adj(vin, vb, normal, c.contact, c.friction, g_out * w);
            let g_phi = if dw != 0.0 {
                let r = contact_response(vin, vb, normal, c.contact, c.friction);
                dw * (r - vin).dot(g_out)
            } else {
                0.0
            };
            *g = if w == 1.0 {
                a.v
            } else {
                a.v + g_out * (1.0 - w)
            };
            acc[ci].friction += a.mu;
            if c.kind == ColliderKind::Tool {
                // Grid nodes do not move: the returned x̄ has nowhere to go.
                acc[ci].add_tool_contact(
                    pose,
                    world_hessian(&c.shape, pose, x),
                    x,
                    normal,
                    (g_phi, a.n, a.v_body),
                );
            }
        }
    };
    // One partial sum per chunk, into a buffer kept between substeps.
    chunks.clear();
    chunks.resize(
        adj.velocity.len().div_ceil(REDUCE_CHUNK),
        ChunkAdj::default(),
    );
    adj.velocity
        .par_chunks_mut(REDUCE_CHUNK)
        .zip(chunks.par_iter_mut())
        .enumerate()
        .for_each(|(c, (gs, acc))| {
            for (j, g) in gs.iter_mut().enumerate() {
                node(c * REDUCE_CHUNK + j, g, acc);
            }
        });
    add_collider_adjoints(&chunks, cs.iter_mut().map(|(_, _, _, a)| &mut **a));
}

pub fn domain_walls_adjoint(
    params: Res<SimParams>,
    walls: Res<DomainWalls>,
    grid: Res<Grid>,
    input: Res<WallInputVelocity>,
    mut adj: ResMut<GridAdj>,
) {
    let (n, cells) = (grid.n, walls.cells);
    let m_min = params.empty_node_mass;
    for_wall_nodes(
        &mut adj.velocity,
        &grid.nodes,
        m_min,
        n,
        cells,
        grid.active.as_ref(),
        |coord, idx, g| {
            let mut normals = [DVec3::ZERO; 3];
            let mut vin = [DVec3::ZERO; 3];
            let mut v = input.0[idx];
            let mut count = 0;
            for normal in (0..3).filter_map(|a| wall_normal(coord, n, cells, a)) {
                normals[count] = normal;
                vin[count] = v;
                v = contact_response(v, DVec3::ZERO, normal, walls.mode, walls.friction);
                count += 1;
            }
            for k in (0..count).rev() {
                *g = contact_response_adj(
                    vin[k],
                    DVec3::ZERO,
                    normals[k],
                    walls.mode,
                    walls.friction,
                    *g,
                )
                .v;
            }
        },
    );
}
