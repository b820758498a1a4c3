//! Triangle meshes for recordings, and the pieces the shapes build theirs from
//! (`Shape::mesh`): shapes of revolution (about local y) from a 2-D profile, a box directly.

use glam::{DQuat, DVec3};

/// An indexed triangle mesh in a shape's local frame.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    pub vertices: Vec<[f32; 3]>,
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    /// Adds `other`'s triangles.
    pub fn append(&mut self, other: Mesh) {
        let off = self.vertices.len() as u32;
        self.vertices.extend(other.vertices);
        self.triangles
            .extend(other.triangles.into_iter().map(|t| t.map(|i| i + off)));
    }

    /// The mesh rotated by `rot`, then moved by `t`.
    pub fn transformed(mut self, rot: DQuat, t: DVec3) -> Mesh {
        for v in &mut self.vertices {
            let p = rot * DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64) + t;
            *v = [p.x as f32, p.y as f32, p.z as f32];
        }
        self
    }
}

/// Segments around the axis of revolution.
const SEGMENTS: usize = 32;

/// Revolves the polyline `(ρ, y)` about the y axis.
pub fn revolve(profile: &[(f64, f64)]) -> Mesh {
    let mut m = Mesh::default();
    for &(r, y) in profile {
        for s in 0..SEGMENTS {
            let a = s as f64 / SEGMENTS as f64 * std::f64::consts::TAU;
            m.vertices
                .push([(r * a.cos()) as f32, y as f32, (r * a.sin()) as f32]);
        }
    }
    for i in 0..profile.len().saturating_sub(1) {
        for s in 0..SEGMENTS {
            let a = (i * SEGMENTS + s) as u32;
            let b = (i * SEGMENTS + (s + 1) % SEGMENTS) as u32;
            let c = a + SEGMENTS as u32;
            let d = b + SEGMENTS as u32;
            m.triangles.push([a, c, b]);
            m.triangles.push([b, c, d]);
        }
    }
    m
}

/// `n + 1` points of the circle of radius `r` about `(0, cy)` from angle `from` to `to`.
pub fn arc(r: f64, cy: f64, from: f64, to: f64, n: usize) -> Vec<(f64, f64)> {
    (0..=n)
        .map(|k| {
            let t = from + (to - from) * k as f64 / n as f64;
            (r * t.cos(), cy + r * t.sin())
        })
        .collect()
}

/// A box of half extents `h`.
pub fn box_mesh(h: DVec3) -> Mesh {
    let mut m = Mesh::default();
    for k in 0..8 {
        let s = DVec3::new(
            if k & 1 == 0 { -1.0 } else { 1.0 },
            if k & 2 == 0 { -1.0 } else { 1.0 },
            if k & 4 == 0 { -1.0 } else { 1.0 },
        );
        let p = s * h;
        m.vertices.push([p.x as f32, p.y as f32, p.z as f32]);
    }
    for f in [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ] {
        m.triangles.push([f[0], f[1], f[2]]);
        m.triangles.push([f[0], f[2], f[3]]);
    }
    m
}

/// The profile of a capsule along y, for [`revolve`].
pub fn capsule_profile(half_length: f64, r: f64) -> Vec<(f64, f64)> {
    use std::f64::consts::FRAC_PI_2;
    let mut p = arc(r, -half_length, -FRAC_PI_2, 0.0, 8);
    p.extend(arc(r, half_length, 0.0, FRAC_PI_2, 8));
    p
}

#[cfg(test)]
mod tests {
    use crate::math::sdf::Shape;
    use glam::DVec3;

    #[test]
    fn meshes_are_well_formed_and_lie_on_the_surface() {
        let shapes = [
            Shape::Cup {
                outer_radius: 0.03,
                height: 0.05,
                wall_thickness: 0.002,
                floor_thickness: 0.003,
                fillet_radius: None,
            },
            Shape::Box {
                half_extents: [0.05, 0.01, 0.05],
            },
            Shape::Cylinder {
                radius: 0.02,
                half_height: 0.01,
            },
            Shape::Spatula {
                blade_width: 0.04,
                blade_height: 0.02,
                thickness: 0.002,
                handle_length: 0.06,
                handle_radius: 0.003,
            },
        ];
        for s in shapes {
            let m = s.mesh();
            let n = m.vertices.len() as u32;
            assert!(m.triangles.iter().flatten().all(|&i| i < n));
            for v in &m.vertices {
                let p = DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64);
                // f32 vertices: 1e-6 m is a few ulps at these sizes.
                assert!(s.sdf(p).0.abs() < 1e-6, "{s:?}: {p} at {}", s.sdf(p).0);
            }
        }
    }
}
