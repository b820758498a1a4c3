//! Scene files: RON, `deny_unknown_fields`, every error located by file, line, column and field.
//!
//! A scene declares the simulation settings, named materials (a plug-in name with parameters),
//! particle bodies, rigid colliders (tools and containers) with their controls, the transport
//! task (for metrics), and the recording options. See `scenes/README.md` for every field and
//! its default.
//!
//! - [`types`]: what a scene file holds;
//! - [`parse`]: reading it, with the line and column of every error;
//! - [`validate`]: every field's range and every cross-reference;
//! - [`shipped`]: the scenes of `scenes/`, compiled in and loaded by name;
//! - [`prepare`]: the checks that need the scene's derived data (the particle fills, the tools'
//!   control sequences, the memory they take, the stable substep), and that data.
//!
//! The scene layer is below the simulation: it imports nothing from `sim`, `adjoint` or the
//! lab.

mod fill;
pub mod fuzz;
pub mod parse;
pub mod plan;
pub mod prepare;
pub mod randomize;
pub mod shipped;
pub mod types;
pub mod validate;
pub mod work;

pub use parse::locate;
pub use prepare::{
    Prepared, PreparedBody, PreparedCollider, StabilityReport, StartColumns, MAX_AUTO_SUBSTEPS,
};
pub use types::*;
pub use work::{WorkEstimate, WORK_LIMIT};

use crate::math::geometry::CupRegion;
use crate::math::pose::Pose;
use glam::{DQuat, DVec3};

impl Scene {
    /// A fingerprint of what fixes the scene's results: FNV-1a of its every field written as RON
    /// (defaults written out), so that a comment, a blank line or a default spelled out leaves
    /// it unchanged, and any change of a value changes it. Journals are keyed by it.
    pub fn fingerprint(&self) -> String {
        crate::util::fnv1a(&ron::to_string(self).expect("a parsed scene writes as RON"))
    }

    /// The height of the floor the powder rests on, which an empty pixel of a height map shows: the highest upward-facing plane container, else the domain
    /// walls' inner face.
    pub fn floor_height(&self) -> f64 {
        let walls = self.domain().0.y + self.simulation.walls.cells as f64 * self.simulation.dx;
        self.colliders
            .iter()
            .filter(|c| c.kind == ColliderKindSpec::Container)
            .filter_map(|c| match c.shape {
                crate::math::sdf::Shape::Plane { normal }
                    if DVec3::from(normal).normalize_or_zero().y > 0.999 =>
                {
                    Some(c.position.1)
                }
                _ => None,
            })
            .fold(walls, f64::max)
    }

    /// Rotation of a collider from its Euler angles.
    pub fn collider_rotation(c: &ColliderSpec) -> DQuat {
        let (a, b, g) = c.rotation_deg;
        DQuat::from_euler(
            glam::EulerRot::XYZ,
            a.to_radians(),
            b.to_radians(),
            g.to_radians(),
        )
    }

    /// A collider's start pose, as the scene places it.
    pub fn collider_pose(c: &ColliderSpec) -> Pose {
        Pose {
            translation: DVec3::from(c.position),
            rotation: Scene::collider_rotation(c),
        }
    }

    /// Height of a tool's lowest point at its start pose: where a skill's descent is measured
    /// from.
    pub fn tool_bottom(c: &ColliderSpec) -> f64 {
        Scene::collider_pose(c)
            .to_world(c.shape.lowest_local_point())
            .y
    }

    /// Particle spacing of a body (m): `dx/∛ppc`.
    pub fn particle_spacing(&self, body: &BodySpec) -> f64 {
        let ppa = (body.particles_per_cell as f64).cbrt().round();
        self.simulation.dx / ppa
    }

    /// Mass of one particle of each body (kg), in scene order.
    pub fn particle_masses(&self) -> Vec<f64> {
        self.bodies
            .iter()
            .map(|b| self.materials[&b.material].density() * self.particle_spacing(b).powi(3))
            .collect()
    }

    /// The cavity of the task's target cup, if the scene has a task.
    pub fn target_region(&self) -> Option<CupRegion> {
        self.cup_region(&self.task.as_ref()?.target)
    }

    /// The cavity of the collider named `name` at its start pose, if it is a cup.
    pub fn cup_region(&self, name: &str) -> Option<CupRegion> {
        let c = self.colliders.iter().find(|c| c.name == name)?;
        CupRegion::of(&c.shape, Scene::collider_pose(c))
    }

    /// Grid node (0,0,0) and the upper node corner.
    pub fn domain(&self) -> (DVec3, DVec3) {
        let s = &self.simulation;
        let lo = DVec3::from(s.domain_min);
        let n = s.cells;
        (
            lo,
            lo + DVec3::new((n.0 - 1) as f64, (n.1 - 1) as f64, (n.2 - 1) as f64) * s.dx,
        )
    }

    /// `∂L/∂Θ` of each tool driven by a skill, from the gradients with respect to the tools'
    /// per-step controls (`adjoint::tape::Gradients::controls`): the skill mapping's adjoint,
    /// with the phases' step counts held (straight-through rounding).
    pub fn skill_gradients(&self, controls: &[(String, Vec<[f64; 6]>)]) -> Vec<(String, [f64; 5])> {
        controls
            .iter()
            .filter_map(|(name, g_u)| {
                let c = self.colliders.iter().find(|c| &c.name == name)?;
                Some((name.clone(), c.skill_gradient(self.simulation.dt, g_u)?))
            })
            .collect()
    }
}

impl ColliderSpec {
    /// `∂L/∂Θ` of this collider's skill from `∂L/∂u` per global step; `None` without a skill.
    pub fn skill_gradient(&self, dt: f64, g_controls: &[[f64; 6]]) -> Option<[f64; 5]> {
        let Some(ControlSpec::Skill(sk)) = &self.control else {
            return None;
        };
        Some(sk.controls_adj(dt, Scene::tool_bottom(self), g_controls))
    }
}
