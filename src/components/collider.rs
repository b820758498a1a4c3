//! Rigid colliders: kinematic tools (the spoon) and static containers (cups).

use crate::components::ContactMode;
use crate::math::pose::Pose;
use crate::math::sdf::Shape;
use bevy_ecs::prelude::*;
use glam::DVec3;

/// Whether a collider moves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ColliderKind {
    /// Follows a control sequence.
    Tool,
    /// Never moves.
    Container,
}

/// A rigid SDF collider.
#[derive(Component, Clone, Debug)]
pub struct Collider {
    pub name: String,
    /// Position in the scene file; systems visit colliders in this order.
    pub index: usize,
    pub kind: ColliderKind,
    pub shape: Shape,
    /// Coulomb friction coefficient.
    pub friction: f64,
    pub contact: ContactMode,
    /// Grid nodes with `φ < band` (m) are in contact.
    pub band: f64,
    /// Blend the grid response in by `1 − φ/band` instead of all or nothing
    /// (`crate::math::contact::band_weight`).
    pub soft_band: bool,
    /// `shape.bounding_radius()`, kept so the contact stages' reach tests do not recompute it
    /// per node and particle.
    pub bounding_radius: f64,
    /// Whether the particle-collision stage projects particles against this collider.
    pub particle_contact: bool,
    /// Project softly (C¹ in the particle's velocity and distance) instead of with a kink
    /// (`crate::systems::particle_collision`'s module docs).
    pub soft_particle_contact: bool,
}

/// Current pose and the rigid velocity over the current substep.
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct ColliderPose {
    pub pose: Pose,
    /// Linear velocity of the pose origin (m/s).
    pub linear: DVec3,
    /// Angular velocity (rad/s).
    pub angular: DVec3,
}

impl ColliderPose {
    /// Rigid-body velocity of the material point at world position `x`.
    #[inline]
    pub fn velocity_at(&self, x: DVec3) -> DVec3 {
        self.linear + self.angular.cross(x - self.pose.translation)
    }

    /// World-frame SDF and gradient.
    #[inline]
    pub fn sdf(&self, shape: &Shape, x: DVec3) -> (f64, DVec3) {
        self.sdf_at_local(shape, self.pose.to_local(x))
    }

    /// [`ColliderPose::sdf`] from the local point `self.pose.to_local(x)`, for callers that
    /// have it already.
    #[inline]
    pub fn sdf_at_local(&self, shape: &Shape, local: DVec3) -> (f64, DVec3) {
        let (phi, g) = shape.sdf(local);
        (phi, self.pose.rotation * g)
    }
}

/// A tool's control sequence: one 6-D displacement `(translation, rotation vector)` per global
/// step, in the world frame, applied as `u/N_sub` per substep. Past the end the tool holds still.
#[derive(Component, Clone, Debug, Default)]
pub struct Control {
    pub per_step: Vec<[f64; 6]>,
}

/// The grid nodes within a static container's contact band, found once. A container never
/// moves, so its SDF at the fixed grid nodes never changes; the grid-collision stage and its
/// adjoint look a node up here instead of evaluating the SDF every substep. The table keeps the
/// pose and grid it was built for, and [`NodeContacts::fits`] refuses it for any other, so a
/// caller that moves a container falls back to evaluating. The values are the SDF's own, so the
/// results are bit for bit those of evaluating it.
///
/// Memory: 4 bytes per grid node plus 32 bytes per node in the band.
#[derive(Component, Clone, Debug)]
pub struct NodeContacts {
    pose: Pose,
    origin: DVec3,
    dx: f64,
    n: [usize; 3],
    /// Per node: 1 + the index into `hits` of its contact, or 0 for none.
    slot: Vec<u32>,
    /// `(φ, world normal)` of each node in the band, in node order.
    hits: Vec<(f64, DVec3)>,
}

impl NodeContacts {
    /// Evaluates the container's SDF at every node within its reach (the same reach test as the
    /// stages': the bounding radius plus the band) and keeps the nodes with `φ < band`.
    pub fn build(c: &Collider, pose: &ColliderPose, grid: &crate::components::Grid) -> Self {
        let reach = c.bounding_radius + c.band;
        let mut slot = vec![0u32; grid.node_count()];
        let mut hits = Vec::new();
        for (idx, s) in slot.iter_mut().enumerate() {
            let x = grid.node_position(idx);
            if (x - pose.pose.translation).length_squared() > reach * reach {
                continue;
            }
            let (phi, normal) = pose.sdf(&c.shape, x);
            if phi < c.band {
                hits.push((phi, normal));
                *s = u32::try_from(hits.len()).expect("fewer than 2^32 grid nodes");
            }
        }
        Self {
            pose: pose.pose,
            origin: grid.origin,
            dx: grid.dx,
            n: grid.n,
            slot,
            hits,
        }
    }

    /// Whether the table holds for a collider at `pose` on `grid`.
    pub fn fits(&self, pose: &ColliderPose, grid: &crate::components::Grid) -> bool {
        self.pose == pose.pose
            && self.origin == grid.origin
            && self.dx == grid.dx
            && self.n == grid.n
    }

    /// `(φ, normal)` of node `idx` if it is within the band.
    #[inline(always)]
    pub fn at(&self, idx: usize) -> Option<(f64, DVec3)> {
        match self.slot[idx] {
            0 => None,
            s => Some(self.hits[s as usize - 1]),
        }
    }
}

/// A collider's contact with grid node `idx` at `x`: `(φ, normal)` if the node is within its
/// band, from the collider's [`NodeContacts`] when it has one that fits (pass only such a
/// table), else by the reach test and the SDF.
#[inline(always)]
pub fn node_contact(
    c: &Collider,
    pose: &ColliderPose,
    table: Option<&NodeContacts>,
    idx: usize,
    x: DVec3,
) -> Option<(f64, DVec3)> {
    if let Some(t) = table {
        return t.at(idx);
    }
    let reach = c.bounding_radius + c.band;
    if (x - pose.pose.translation).length_squared() > reach * reach {
        return None;
    }
    let local = pose.pose.to_local(x);
    // φ > band for certain: the SDF would say "no contact" too.
    if c.shape.surely_clear(local, c.band) {
        return None;
    }
    let (phi, normal) = pose.sdf_at_local(&c.shape, local);
    (phi < c.band).then_some((phi, normal))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::components::{ContactMode, Grid};
    use glam::DQuat;

    fn cup() -> (Collider, ColliderPose) {
        let shape = Shape::Cup {
            outer_radius: 0.03,
            height: 0.05,
            wall_thickness: 0.002,
            floor_thickness: 0.003,
            fillet_radius: None,
        };
        let c = Collider {
            name: "cup".into(),
            index: 0,
            kind: ColliderKind::Container,
            bounding_radius: shape.bounding_radius(),
            shape,
            friction: 0.4,
            contact: ContactMode::Separate,
            band: 0.0025,
            soft_band: true,
            particle_contact: true,
            soft_particle_contact: false,
        };
        let pose = ColliderPose {
            pose: Pose {
                translation: DVec3::new(0.06, 0.0075, 0.05),
                rotation: DQuat::from_rotation_z(0.1),
            },
            ..Default::default()
        };
        (c, pose)
    }

    /// The table gives, bit for bit, what evaluating the SDF gives at every node, and some
    /// nodes are in the band (the test covers contacts, not only misses).
    #[test]
    fn node_table_equals_evaluating_the_sdf_at_every_node() {
        let (c, pose) = cup();
        let grid = Grid::new(DVec3::ZERO, 0.005, [26, 14, 20]);
        let table = NodeContacts::build(&c, &pose, &grid);
        assert!(table.fits(&pose, &grid));
        let mut hits = 0;
        for idx in 0..grid.node_count() {
            let x = grid.node_position(idx);
            let direct = node_contact(&c, &pose, None, idx, x);
            let looked_up = node_contact(&c, &pose, Some(&table), idx, x);
            let bits = |h: Option<(f64, DVec3)>| {
                h.map(|(p, n)| [p.to_bits(), n.x.to_bits(), n.y.to_bits(), n.z.to_bits()])
            };
            assert_eq!(bits(direct), bits(looked_up), "node {idx}");
            hits += usize::from(direct.is_some());
        }
        assert!(hits > 100, "{hits} nodes in the band");
    }

    /// A moved container, or another grid, does not use the table.
    #[test]
    fn node_table_refuses_another_pose_or_grid() {
        let (c, mut pose) = cup();
        let grid = Grid::new(DVec3::ZERO, 0.005, [26, 14, 20]);
        let table = NodeContacts::build(&c, &pose, &grid);
        assert!(!table.fits(&pose, &Grid::new(DVec3::ZERO, 0.004, [26, 14, 20])));
        pose.pose.translation.x += 1e-9;
        assert!(!table.fits(&pose, &grid));
    }
}
