//! A body's particles before they are jittered and cleared of the colliders: the lattice its
//! fill is cut from (box, column, cylinder, or a cup's cavity up to a height).

use super::*;
use crate::math::sdf::Shape;
use glam::DVec3;

/// The lattice a body's fill is cut from: its first corner, its spacing and its point count
/// per axis (for `InsideContainer`, in the cup's own frame). The counts are in f64, so that the
/// memory check measures an absurd fill before `fill_points` allocates it.
pub(super) fn fill_lattice(scene: &Scene, body: &BodySpec) -> (DVec3, f64, DVec3) {
    let h = scene.particle_spacing(body);
    let (lo, hi) = fill_bounds(scene, body);
    let n = ((hi - lo) / h + DVec3::splat(1e-9))
        .floor()
        .max(DVec3::ZERO);
    (lo, h, n)
}

/// The box the fill's lattice spans (for `InsideContainer`, in the cup's own frame).
fn fill_bounds(scene: &Scene, body: &BodySpec) -> (DVec3, DVec3) {
    match &body.fill {
        Fill::Box { min, max } => (DVec3::from(*min), DVec3::from(*max)),
        Fill::Column {
            base,
            length,
            aspect,
            depth,
        } => {
            let b = DVec3::from(*base);
            (b, b + DVec3::new(*length, aspect * length, *depth))
        }
        Fill::Cylinder {
            base,
            radius,
            height,
            quarter,
        } => {
            let b = DVec3::from(*base);
            let below = if *quarter { 0.0 } else { *radius };
            (
                b - DVec3::new(below, 0.0, below),
                b + DVec3::new(*radius, *height, *radius),
            )
        }
        Fill::InsideContainer { container, height } => {
            let (r, floor) = cup_cavity(fill_container(scene, container));
            (DVec3::new(-r, floor, -r), DVec3::new(r, floor + height, r))
        }
    }
}

/// The collider an `InsideContainer` fill names.
fn fill_container<'a>(scene: &'a Scene, container: &str) -> &'a ColliderSpec {
    scene
        .colliders
        .iter()
        .find(|c| c.name == container)
        .expect("validated")
}

/// The cavity radius and floor height of a cup collider, in its own frame.
fn cup_cavity(c: &ColliderSpec) -> (f64, f64) {
    let Shape::Cup {
        outer_radius,
        wall_thickness,
        floor_thickness,
        ..
    } = c.shape
    else {
        unreachable!("validated: fill container is a cup")
    };
    (outer_radius - wall_thickness, floor_thickness)
}

/// Particles of a fill, before collider clearance and domain checks.
pub(super) fn fill_points(scene: &Scene, body: &BodySpec) -> Vec<DVec3> {
    let lattice = |keep: &dyn Fn(DVec3) -> bool| -> Vec<DVec3> {
        let (lo, h, n) = fill_lattice(scene, body);
        let (nx, ny, nz) = (n.x as usize, n.y as usize, n.z as usize);
        let mut out = Vec::with_capacity(nx * ny * nz);
        for i in 0..nx {
            for j in 0..ny {
                for k in 0..nz {
                    let p = lo + DVec3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5) * h;
                    if keep(p) {
                        out.push(p);
                    }
                }
            }
        }
        out
    };
    match &body.fill {
        Fill::Box { .. } | Fill::Column { .. } => lattice(&|_| true),
        Fill::Cylinder { base, radius, .. } => {
            let b = DVec3::from(*base);
            lattice(&|p| (p.x - b.x).hypot(p.z - b.z) < *radius)
        }
        Fill::InsideContainer { container, .. } => {
            let c = fill_container(scene, container);
            let (r, _) = cup_cavity(c);
            let pose = Scene::collider_pose(c);
            lattice(&|p| p.x.hypot(p.z) < r)
                .into_iter()
                .map(|p| pose.to_world(p))
                .collect()
        }
    }
}
