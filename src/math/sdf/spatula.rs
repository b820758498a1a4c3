//! The spatula: a thin rectangular blade and a capsule handle standing on the middle of its top
//! edge. Its SDF, Hessian, validation and mesh. Origin at the middle of the blade's bottom edge
//! (its lowest point); the blade spans local x (its width) and y (its height), its faces look
//! along ±z, so a stroke along local z pushes powder with a face.

use super::primitives::{
    box_hessian, capsule_hessian, capsule_mesh, positive, sd_box, sd_capsule_y,
};
use crate::error::FieldError;
use crate::math::mesh::{box_mesh, Mesh};
use glam::{DMat3, DQuat, DVec3};

/// A spatula's dimensions (m), as the scene gives them.
#[derive(Clone, Copy, Debug)]
pub struct Spatula {
    pub blade_width: f64,
    pub blade_height: f64,
    pub thickness: f64,
    pub handle_length: f64,
    pub handle_radius: f64,
}

impl Spatula {
    /// The blade's centre and half extents.
    fn blade(&self) -> (DVec3, DVec3) {
        (
            DVec3::new(0.0, 0.5 * self.blade_height, 0.0),
            DVec3::new(
                0.5 * self.blade_width,
                0.5 * self.blade_height,
                0.5 * self.thickness,
            ),
        )
    }

    /// The handle's centre (its axis runs along y through it): its rounded end rests on the
    /// middle of the blade's top edge.
    fn handle(&self) -> DVec3 {
        DVec3::new(
            0.0,
            self.blade_height + self.handle_radius + 0.5 * self.handle_length,
            0.0,
        )
    }

    /// Which part is nearer, with its distance and gradient: the blade (`true`) or the handle.
    fn nearest(&self, p: DVec3) -> (bool, f64, DVec3) {
        let (c, h) = self.blade();
        let (db, gb) = sd_box(p - c, h);
        let (dh, gh) = sd_capsule_y(
            p - self.handle(),
            0.5 * self.handle_length,
            self.handle_radius,
        );
        if db <= dh {
            (true, db, gb)
        } else {
            (false, dh, gh)
        }
    }

    pub fn sdf(&self, p: DVec3) -> (f64, DVec3) {
        let (_, d, g) = self.nearest(p);
        (d, g)
    }

    /// The Hessian of the nearer part (a kink where the two tie).
    pub fn hessian(&self, p: DVec3) -> DMat3 {
        let (blade, _, _) = self.nearest(p);
        if blade {
            let (c, h) = self.blade();
            box_hessian(p - c, h.into())
        } else {
            capsule_hessian(
                p - self.handle(),
                0.5 * self.handle_length,
                self.handle_radius,
            )
        }
    }

    pub fn bounding_radius(&self) -> f64 {
        DVec3::new(
            0.5 * self.blade_width,
            self.blade_height + self.handle_length + 2.0 * self.handle_radius,
            (0.5 * self.thickness).max(self.handle_radius),
        )
        .length()
    }

    pub fn min_wall(&self) -> f64 {
        self.thickness.min(2.0 * self.handle_radius)
    }

    pub fn validate(&self) -> Result<(), FieldError> {
        positive("blade_width", self.blade_width)?;
        positive("blade_height", self.blade_height)?;
        positive("thickness", self.thickness)?;
        positive("handle_length", self.handle_length)?;
        positive("handle_radius", self.handle_radius)
    }

    pub fn mesh(&self) -> Mesh {
        let (c, h) = self.blade();
        let mut m = box_mesh(h).transformed(DQuat::IDENTITY, c);
        m.append(
            capsule_mesh(0.5 * self.handle_length, self.handle_radius)
                .transformed(DQuat::IDENTITY, self.handle()),
        );
        m
    }
}
