//! PLY output of particle state: binary little-endian, one vertex per particle with
//! `x y z vx vy vz` as doubles. Open3D and MeshLab read it; the bytes depend only on the state.

use crate::components::BodyState;
use std::path::Path;

/// Serialises all bodies' particles into one PLY point cloud.
pub fn to_ply(bodies: &[BodyState]) -> Vec<u8> {
    let n: usize = bodies.iter().map(|b| b.x.len()).sum();
    let names: Vec<&str> = bodies.iter().map(|b| b.name.as_str()).collect();
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment powderlab final state; bodies: {}\nelement vertex {n}\nproperty double x\nproperty double y\nproperty double z\nproperty double vx\nproperty double vy\nproperty double vz\nend_header\n",
        names.join(",")
    );
    let mut out = Vec::with_capacity(header.len() + n * 48);
    out.extend_from_slice(header.as_bytes());
    for b in bodies {
        for (x, v) in b.x.iter().zip(&b.v) {
            for c in [x.x, x.y, x.z, v.x, v.y, v.z] {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
    }
    out
}

/// Writes the PLY atomically.
pub fn write_ply(path: &Path, bodies: &[BodyState]) -> std::io::Result<()> {
    crate::util::write_atomic(path, &to_ply(bodies))
}

/// Reads back the vertices of a file written by [`to_ply`] (for tests and tools).
pub fn read_ply(bytes: &[u8]) -> Option<Vec<[f64; 6]>> {
    let end = bytes.windows(11).position(|w| w == b"end_header\n")? + 11;
    let header = std::str::from_utf8(&bytes[..end]).ok()?;
    let n: usize = header
        .lines()
        .find(|l| l.starts_with("element vertex"))?
        .split_whitespace()
        .nth(2)?
        .parse()
        .ok()?;
    let body = &bytes[end..];
    if body.len() != n * 48 {
        return None;
    }
    Some(
        body.chunks_exact(48)
            .map(|c| {
                std::array::from_fn(|k| f64::from_le_bytes(c[8 * k..8 * k + 8].try_into().unwrap()))
            })
            .collect(),
    )
}
