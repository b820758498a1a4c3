//! The angle of repose against cohesion (`powderlab validate repose`): the heap test of
//! `scenes/repose_cylinder.ron` ([`crate::lab::repose`]) at two friction angles and four
//! cohesions. The check is the law the issue asks for, that the heap stands steeper as the
//! cohesion rises at a fixed friction angle; the table beside it is published on
//! `docs/results/validation.md`.
//!
//! Beside each heap the page gives Culmann's critical slope angle ([`culmann_angle_deg`]) for a
//! slope of the heap's height in a Mohr–Coulomb soil of the same φ and c: the classic limit
//! equilibrium of a planar slip surface through the toe. It is a reference, not a criterion: a
//! heap's crest is rounded and its slip surfaces are not planes, and the Drucker–Prager cone
//! matches Mohr–Coulomb only on some stress paths.

use super::Check;
use crate::lab::repose::{heap, Heap};
use crate::scene::Scene;
use crate::sim::SimOptions;

/// The friction angles of the table (degrees).
pub const FRICTION_DEG: [f64; 2] = [25.0, 35.0];
/// The cohesions of the table (Pa): 0 up to where a 12 mm heap stands some 30° steeper.
pub const COHESION_PA: [f64; 4] = [0.0, 2.5, 5.0, 10.0];

/// One heap of the table.
#[derive(Clone, Debug)]
pub struct Row {
    pub friction_deg: f64,
    pub cohesion_pa: f64,
    pub heap: Heap,
    /// Culmann's critical slope angle for the heap's height (degrees).
    pub culmann_deg: f64,
}

/// Culmann's critical angle β of a slope of height `h` (m) in a soil of unit weight `γ = ρg`,
/// cohesion `c` (Pa) and friction angle `φ`: the β at which a planar slip surface through the
/// toe is at limit equilibrium, `h = 4c·sin β·cos φ / (ρg·(1 − cos(β − φ)))`. A cohesionless
/// slope stands at φ; one lower than Rankine's critical height `4c·tan(45° + φ/2)/(ρg)` stands
/// vertical (90°).
pub fn culmann_angle_deg(h: f64, c: f64, friction_deg: f64, unit_weight: f64) -> f64 {
    let phi = friction_deg.to_radians();
    if c <= 0.0 {
        return friction_deg;
    }
    let height =
        |beta: f64| 4.0 * c * beta.sin() * phi.cos() / (unit_weight * (1.0 - (beta - phi).cos()));
    let vertical = std::f64::consts::FRAC_PI_2;
    if height(vertical) >= h {
        return 90.0;
    }
    // The critical height falls from infinity at β = φ to Rankine's at 90°: bisect.
    let (mut lo, mut hi) = (phi + 1e-9, vertical);
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if height(mid) > h {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    (0.5 * (lo + hi)).to_degrees()
}

/// Runs the table's heaps on `scene` (the shipped heap test), one packing each;
/// `progress(label)` before each.
pub fn run(
    scene: &Scene,
    opts: &SimOptions,
    progress: &mut dyn FnMut(String),
) -> anyhow::Result<Vec<Row>> {
    let params = |names: &[&str]| {
        crate::lab::calibrate::params::parse(
            scene,
            &names.iter().map(|s| s.to_string()).collect::<Vec<_>>(),
            &[],
        )
        .map_err(|e| anyhow::anyhow!("the heap-test scene: {e}"))
    };
    let p = params(&["friction_deg", "cohesion"])?;
    let Some(body) = scene.bodies.first() else {
        anyhow::bail!("the heap-test scene has no powder");
    };
    let mut rows = Vec::new();
    for phi in FRICTION_DEG {
        for c in COHESION_PA {
            progress(format!("heap at φ = {phi}°, c = {c} Pa"));
            let mut s = scene.clone();
            p[0].apply(&mut s, phi);
            p[1].apply(&mut s, c);
            let h = heap(&s, s.simulation.seed, opts)?;
            rows.push(Row {
                friction_deg: phi,
                cohesion_pa: c,
                culmann_deg: culmann_angle_deg(
                    h.height_m,
                    c,
                    phi,
                    s.materials[&body.material].density()
                        * glam::DVec3::from(s.simulation.gravity).length(),
                ),
                heap: h,
            });
        }
    }
    Ok(rows)
}

/// One check per friction angle: the angle of repose rises with the cohesion. Each heap's
/// figures, and Culmann's angle, are in the note.
pub fn checks(rows: &[Row]) -> Vec<Check> {
    let mut out = Vec::new();
    for phi in FRICTION_DEG {
        let at: Vec<&Row> = rows.iter().filter(|r| r.friction_deg == phi).collect();
        let angles: Vec<f64> = at.iter().map(|r| r.heap.angle_deg).collect();
        let rising = angles.windows(2).all(|w| w[1] > w[0]);
        let at_rest = at.iter().all(|r| r.heap.at_rest);
        out.push(Check {
            case: "repose".into(),
            quantity: format!("angle of repose rises with cohesion at φ = {phi}°"),
            measured: f64::from(u8::from(rising && at_rest)),
            published: 1.0,
            tolerance: 0.0,
            kind: "1 = rising",
            passed: rising && at_rest,
            note: at
                .iter()
                .map(|r| {
                    format!(
                        "c = {} Pa: {:.1}° (height {:.1} mm, Culmann {:.1}°{})",
                        r.cohesion_pa,
                        r.heap.angle_deg,
                        r.heap.height_m * 1e3,
                        r.culmann_deg,
                        if r.heap.at_rest { "" } else { ", NOT at rest" }
                    )
                })
                .collect::<Vec<_>>()
                .join("; "),
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn culmann_meets_its_two_limits() {
        // Cohesionless: the friction angle; at Rankine's critical height: vertical.
        let gamma = 1500.0 * 9.81;
        assert_eq!(culmann_angle_deg(0.01, 0.0, 30.0, gamma), 30.0);
        let (c, phi) = (20.0, 30.0);
        let rankine = 4.0 * c * (45f64 + phi / 2.0).to_radians().tan() / gamma;
        assert_eq!(culmann_angle_deg(0.999 * rankine, c, phi, gamma), 90.0);
        let just_above = culmann_angle_deg(1.001 * rankine, c, phi, gamma);
        assert!(just_above < 90.0 && just_above > 89.0, "{just_above}");
        // Taller slopes of the same soil stand at lower angles, down towards φ.
        let tall = culmann_angle_deg(100.0 * rankine, c, phi, gamma);
        assert!(tall > phi && tall < 35.0, "{tall}");
    }
}
