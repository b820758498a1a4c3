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
        let (phi, g) = shape.sdf(self.pose.to_local(x));
        (phi, self.pose.rotation * g)
    }
}

/// A tool's control sequence: one 6-D displacement `(translation, rotation vector)` per global
/// step, in the world frame, applied as `u/N_sub` per substep. Past the end the tool holds still.
#[derive(Component, Clone, Debug, Default)]
pub struct Control {
    pub per_step: Vec<[f64; 6]>,
}
