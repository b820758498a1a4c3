//! What the policy sees of a scene: the drawn quantities, the mass delivered so far, and a
//! coarse height field of the powder in the source cup.
//!
//! The layout (the features' names, in order) is written into every dataset and policy file;
//! a policy trained on another layout is refused ([`check_layout`]).

use crate::math::sdf::Shape;
use crate::scene::randomize::{Draw, Randomization};
use crate::scene::Scene;
use glam::DVec3;

/// Cells per side of the source cup's height field.
pub const HEIGHT_CELLS: usize = 3;

/// The features' names, in order.
pub fn layout() -> Vec<String> {
    let mut names: Vec<String> = Draw::NAMES
        .iter()
        .map(|n| {
            if *n == "youngs_modulus" {
                "ln_youngs_modulus".to_string()
            } else {
                n.to_string()
            }
        })
        .collect();
    names.push("delivered_g".into());
    for r in 0..HEIGHT_CELLS {
        for c in 0..HEIGHT_CELLS {
            names.push(format!("height_{r}_{c}"));
        }
    }
    names
}

/// The features of `scene` (drawn as `draw` from `spec`) with the powder at `x` and
/// `delivered_g` grams already in the target cup. Heights are above the source cup's base (m);
/// an empty cell reads 0.
pub fn features(
    spec: &Randomization,
    scene: &Scene,
    draw: &Draw,
    x: &[DVec3],
    delivered_g: f64,
) -> Vec<f64> {
    let mut f: Vec<f64> = draw.values().to_vec();
    f[3] = f[3].ln();
    f.push(delivered_g);
    f.extend(height_field(spec, scene, x));
    f
}

/// The highest particle over each of `HEIGHT_CELLS²` cells of the square around the source
/// cup's inner radius, row-major in (x, z), above the cup's base.
pub fn height_field(spec: &Randomization, scene: &Scene, x: &[DVec3]) -> Vec<f64> {
    let n = HEIGHT_CELLS;
    let mut h = vec![0.0_f64; n * n];
    let Some(cup) = scene.colliders.iter().find(|c| c.name == spec.source) else {
        return h;
    };
    let r = match cup.shape {
        Shape::Cup {
            outer_radius,
            wall_thickness,
            ..
        } => outer_radius - wall_thickness,
        _ => return h,
    };
    let (cx, base, cz) = cup.position;
    let cell = 2.0 * r / n as f64;
    for p in x {
        let (u, v) = ((p.x - (cx - r)) / cell, (p.z - (cz - r)) / cell);
        if u < 0.0 || v < 0.0 || u >= n as f64 || v >= n as f64 || p.y < base {
            continue;
        }
        let k = u as usize * n + v as usize;
        h[k] = h[k].max(p.y - base);
    }
    h
}

/// Refuses `found` (a file's layout) when it is not `expected`, naming the first difference.
pub fn check_layout(
    file: &std::path::Path,
    found: &[String],
    expected: &[String],
) -> anyhow::Result<()> {
    if found == expected {
        return Ok(());
    }
    let first = found
        .iter()
        .zip(expected)
        .position(|(a, b)| a != b)
        .unwrap_or(found.len().min(expected.len()));
    anyhow::bail!(
        "{}: field metadata.features: the file's feature layout ({} features, the {}th is \
         '{}') is not this build's ({} features, the {}th is '{}'); retrain it with \
         `powderlab policy train`",
        file.display(),
        found.len(),
        first + 1,
        found.get(first).map_or("none", String::as_str),
        expected.len(),
        first + 1,
        expected.get(first).map_or("none", String::as_str),
    )
}
