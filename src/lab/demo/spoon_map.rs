//! A demonstrator's spoon is not the robot's (seed B aligns a similar but different object with
//! the reconstructed one). The motion is carried over through the bowls' frames: the robot's
//! bowl follows the demonstrated bowl's path, and the scoop goes as deep *relative to the
//! bowl*.
//!
//! - **Kept:** the path and orientation of the bowl's lowest point (the frame with the tool's
//!   axes at that point). The stroke, the lift, the transport and both angles are then the
//!   demonstrator's.
//! - **Rescaled:** the scoop depth, by the ratio of the bowls' depths. A bowl half as deep,
//!   pushed as deep as the demonstrator's, would bury its rim and take a different load. Its
//!   range in the skill is scaled by `demo depth / robot depth` for the fit, so the fitted θ_d
//!   is the robot's.
//! - **Not rescaled:** the rotation centre. A skill turns the tool about its own origin (the
//!   bowl sphere's centre), which lies a bowl radius above the bottom. A bowl of another
//!   radius turns about another point, so the carried-over path is matched in least squares
//!   (the path loss), not exactly.

use crate::math::pose::Pose;
use crate::math::sdf::Spoon;
use crate::skills::SkillSpec;
use glam::DVec3;

/// The bowl's lowest point in the spoon's frame.
pub fn bowl_bottom(s: &Spoon) -> DVec3 {
    DVec3::new(0.0, -s.bowl_radius - 0.5 * s.thickness, 0.0)
}

/// The pose of spoon `to` whose bowl bottom and axes are those of spoon `from` at `p`.
pub fn transfer(p: &Pose, from: &Spoon, to: &Spoon) -> Pose {
    Pose {
        translation: p.translation + p.rotation * (bowl_bottom(from) - bowl_bottom(to)),
        rotation: p.rotation,
    }
}

/// The skill as a demonstrator with spoon `demo` performs the robot's (spoon `robot`) Θ: the
/// scoop depth's range scaled by the bowls' depth ratio.
pub fn demonstrated_skill(sk: &SkillSpec, robot: &Spoon, demo: &Spoon) -> SkillSpec {
    let ratio = demo.bowl_depth / robot.bowl_depth;
    let mut out = sk.clone();
    out.ranges.scoop_depth = (
        ratio * sk.ranges.scoop_depth.0,
        ratio * sk.ranges.scoop_depth.1,
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lab::render::silhouette::{reshaped, tests::spoon};
    use crate::math::pose::quat_from_rotation_vector;

    #[test]
    fn transfer_keeps_the_bowl_bottom_and_undoes_itself() {
        let (a, b) = (spoon(), reshaped(&spoon(), [0.004, 0.002, -0.01]));
        let p = Pose {
            translation: DVec3::new(0.01, 0.05, -0.02),
            rotation: quat_from_rotation_vector(DVec3::new(0.3, -0.8, 0.4)),
        };
        let q = transfer(&p, &a, &b);
        let gap = (p.to_world(bowl_bottom(&a)) - q.to_world(bowl_bottom(&b))).length();
        assert!(gap < 1e-15, "the bowls' bottoms are {gap} m apart");
        assert!((q.translation - p.translation).length() > 0.003);
        let back = transfer(&q, &b, &a);
        assert!((back.translation - p.translation).length() < 1e-15);
    }
}
