//! Rigid poses and the rotation-vector exponential used by kinematic tools.

use glam::{DQuat, DVec3};

/// Unit quaternion for the rotation vector `r` (axis·angle, radians): `exp(r)`.
#[inline]
pub fn quat_from_rotation_vector(r: DVec3) -> DQuat {
    let angle = r.length();
    if angle < 1e-300 {
        DQuat::IDENTITY
    } else {
        DQuat::from_axis_angle(r / angle, angle)
    }
}

/// The rotation vector of a unit quaternion (`log`, the inverse of
/// [`quat_from_rotation_vector`]), with the angle in [0, π].
#[inline]
pub fn quat_to_rotation_vector(q: DQuat) -> DVec3 {
    let q = if q.w < 0.0 { -q } else { q };
    let (axis, angle) = q.to_axis_angle();
    if angle.abs() < 1e-300 {
        DVec3::ZERO
    } else {
        axis * angle
    }
}

/// A rigid pose: `world = rotation · local + translation`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    pub translation: DVec3,
    pub rotation: DQuat,
}

impl Default for Pose {
    fn default() -> Self {
        Self {
            translation: DVec3::ZERO,
            rotation: DQuat::IDENTITY,
        }
    }
}

impl Pose {
    /// Local coordinates of a world point.
    #[inline]
    pub fn to_local(&self, p: DVec3) -> DVec3 {
        self.rotation.inverse() * (p - self.translation)
    }
    /// World coordinates of a local point.
    #[inline]
    pub fn to_world(&self, p: DVec3) -> DVec3 {
        self.rotation * p + self.translation
    }
    /// Applies a world-frame displacement: translate by `dt` and rotate by the rotation vector
    /// `dr` about the pose origin.
    #[inline]
    pub fn displaced(&self, dt: DVec3, dr: DVec3) -> Pose {
        Pose {
            translation: self.translation + dt,
            rotation: (quat_from_rotation_vector(dr) * self.rotation).normalize(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_inverts_exp() {
        for r in [
            DVec3::new(0.3, -0.2, 0.1),
            DVec3::new(0.0, 0.0, 3.0),
            DVec3::new(-1.0, 2.0, 0.5),
        ] {
            let back = quat_to_rotation_vector(quat_from_rotation_vector(r));
            assert!((back - r).length() < 1e-12, "{r} -> {back}");
        }
        assert_eq!(quat_to_rotation_vector(DQuat::IDENTITY), DVec3::ZERO);
    }

    #[test]
    fn exp_of_rotation_vector() {
        let q = quat_from_rotation_vector(DVec3::new(0.0, 0.0, std::f64::consts::FRAC_PI_2));
        let v = q * DVec3::X;
        assert!((v - DVec3::Y).length() < 1e-15);
        assert_eq!(quat_from_rotation_vector(DVec3::ZERO), DQuat::IDENTITY);
    }

    #[test]
    fn local_world_round_trip() {
        let p = Pose::default().displaced(DVec3::new(0.1, 0.2, 0.3), DVec3::new(0.3, -0.2, 0.5));
        let x = DVec3::new(-0.4, 0.7, 0.05);
        assert!((p.to_world(p.to_local(x)) - x).length() < 1e-15);
    }
}
