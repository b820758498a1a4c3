//! Rankine's critical height of an unsupported vertical cut (`powderlab validate rankine`).
//!
//! A cut of height `H` in a Mohr–Coulomb soil of cohesion `c` and friction angle `φ` stands when
//! `H < H_c = 4c·tan(45° + φ/2)/(ρg)`, and fails above. The case stands a column of the planar
//! collapse slab (aspect 1, against the left wall, so in plane strain) on a rough floor and finds
//! by bisection the cohesion at which it stops standing: above it the column's foot moves by
//! at most [`STANDS_FRACTION`] of its height, below it a wedge slides off. Since the only length of the problem is
//! `c/(ρg)` (the stiffness scales with the column's height), the critical cohesion at height `H`
//! gives the critical height at any cohesion: `H_c(c) = H·c/c_crit`.
//!
//! The Drucker–Prager cone meets Mohr–Coulomb in plane strain at its plane-strain friction angle
//! `φ_ps` ([`plane_strain_angle_deg`]) and at the same apex, the mean tension `c·cot φ`; its
//! plane-strain cohesion is then `c·tan φ_ps / tan φ`, and Rankine's height follows with `φ_ps`
//! and that cohesion. The published criterion: within 15 % ([`RANKINE_TOL`]).

use super::pile::plane_strain_angle_deg;
use super::{run_collapse, Check, Collapse};

/// Klár's friction angles of the three cases (degrees): plane-strain angles of 26.5°, 43.9°
/// and 58.6°.
pub const FRICTION_DEG: [f64; 3] = [20.0, 30.0, 35.0];
/// The criterion: the measured critical height within 15 % of Rankine's (the issue's).
pub const RANKINE_TOL: f64 = 0.15;
/// A column stands when its foot (the deposit front, counted in whole cells) moved by at most
/// this fraction of the column's height: 2.5 mm on the 50 mm column, one cell at 20 cells across
/// and two at 40, so that the criterion is the same distance at every resolution. A standing
/// face bulges by a fraction of a cell; a failing one sheds a wedge that runs out several.
pub const STANDS_FRACTION: f64 = 0.05;
/// Cells across the column (its width and its height, aspect 1).
pub const RANKINE_CELLS: usize = 20;
/// Bisection steps on the cohesion: the bracket [¼, 2]× Rankine's falls to 1/64 of its width.
pub const BISECTIONS: usize = 6;
/// Gravity and the slab's density (as [`super::collapse_scene`] writes them).
const G: f64 = 9.81;
const DENSITY: f64 = 1500.0;

/// The column of the case at cohesion `c`.
pub fn column(friction_deg: f64, c: f64, cells: usize) -> Collapse {
    let mut col = Collapse::new(1.0, cells);
    col.friction_deg = friction_deg;
    col.cohesion = c;
    // A floor as rough as the material, so the foot does not slide on a smoother floor.
    col.floor_friction = plane_strain_angle_deg(friction_deg).to_radians().tan();
    // A failed cut runs out by less than a cohesionless column does.
    col.room = 1.0;
    col
}

/// Rankine's critical cohesion for the column of height `h` (m) at Klár's `φ`: the cohesion
/// whose plane-strain Rankine height ([`rankine_heights`]'s first reading) is `h`.
pub fn rankine_cohesion(h: f64, friction_deg: f64) -> f64 {
    DENSITY * G * h / rankine_heights(friction_deg)[0]
}

/// Rankine's critical height in units of `c/(ρg)` for friction angle `phi` (radians) and a
/// cohesion `k` times the material's: `4k·tan(45° + φ/2)`.
fn rankine_height(phi: f64, k: f64) -> f64 {
    4.0 * k * (std::f64::consts::FRAC_PI_4 + phi / 2.0).tan()
}

/// Rankine's critical height over `c/(ρg)` by three readings of the cone at Klár's `φ`: its
/// plane-strain Mohr–Coulomb equivalent (the criterion), Klár's `φ` and `c` as a scene gives
/// them, and Davis's strength for a flow without dilation (`tan φ* = sin φ_ps`,
/// `c* = c_ps·cos φ_ps`), which bounds what a non-associated flow can hold.
pub fn rankine_heights(friction_deg: f64) -> [f64; 3] {
    let phi = friction_deg.to_radians();
    let ps = plane_strain_angle_deg(friction_deg).to_radians();
    let k_ps = ps.tan() / phi.tan();
    [
        rankine_height(ps, k_ps),
        rankine_height(phi, 1.0),
        rankine_height(ps.sin().atan(), k_ps * ps.cos()),
    ]
}

/// One case's outcome.
#[derive(Clone, Debug)]
pub struct RankineResult {
    pub friction_deg: f64,
    /// The column's height (m).
    pub height: f64,
    /// Rankine's critical cohesion at that height (Pa).
    pub rankine_c: f64,
    /// The highest cohesion tried that failed and the lowest that stood (Pa).
    pub failed_at: f64,
    pub stood_at: f64,
    /// Each run: the cohesion and how far the foot moved (cells).
    pub runs: Vec<(f64, f64)>,
}

impl RankineResult {
    /// The measured critical cohesion: the middle of the last bracket.
    pub fn critical_c(&self) -> f64 {
        0.5 * (self.failed_at + self.stood_at)
    }
    /// Measured over Rankine's critical height at any cohesion: `c_Rankine / c_crit`.
    pub fn height_ratio(&self) -> f64 {
        self.rankine_c / self.critical_c()
    }
    /// The measured critical height over `c/(ρg)`.
    pub fn height_over_cohesive_length(&self) -> f64 {
        self.height * DENSITY * G / self.critical_c()
    }
}

/// How far the foot of `col` moved (cells).
fn foot_moved(col: &Collapse, threads: Option<usize>) -> anyhow::Result<f64> {
    let r = run_collapse(col, threads, |_| {})?;
    Ok(r.runout_ratio * col.cells_across as f64)
}

/// Whether a foot that moved `cells` (a whole number, up to round-off) of a column `cells_across`
/// wide and high stands: at most [`STANDS_FRACTION`] of the height, with a quarter cell for the
/// round-off of the count.
pub fn stands(moved_cells: f64, cells_across: usize) -> bool {
    moved_cells <= STANDS_FRACTION * cells_across as f64 + 0.25
}

/// Finds the critical cohesion at Klár's `φ` by bisection; `progress(label)` before each run.
pub fn run_rankine(
    friction_deg: f64,
    cells: usize,
    threads: Option<usize>,
    progress: &mut dyn FnMut(String),
) -> anyhow::Result<RankineResult> {
    let h = column(friction_deg, 0.0, cells).length;
    let rankine_c = rankine_cohesion(h, friction_deg);
    let (mut lo, mut hi) = (0.25 * rankine_c, 2.0 * rankine_c);
    let mut runs = Vec::new();
    let mut try_c = |c: f64, runs: &mut Vec<(f64, f64)>| -> anyhow::Result<bool> {
        progress(format!("cut at φ = {friction_deg}°, c = {c:.1} Pa"));
        let moved = foot_moved(&column(friction_deg, c, cells), threads)?;
        runs.push((c, moved));
        Ok(stands(moved, cells))
    };
    if try_c(lo, &mut runs)? || !try_c(hi, &mut runs)? {
        anyhow::bail!(
            "rankine at φ = {friction_deg}°: the bracket [{lo:.1}, {hi:.1}] Pa does not hold the \
             critical cohesion (runs: {runs:?})"
        );
    }
    for _ in 0..BISECTIONS {
        let mid = 0.5 * (lo + hi);
        if try_c(mid, &mut runs)? {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    Ok(RankineResult {
        friction_deg,
        height: h,
        rankine_c,
        failed_at: lo,
        stood_at: hi,
        runs,
    })
}

/// One check per case: the measured critical height within [`RANKINE_TOL`] of Rankine's.
pub fn rankine_checks(results: &[RankineResult]) -> Vec<Check> {
    results
        .iter()
        .map(|r| {
            Check::relative(
                "rankine",
                format!(
                    "critical height / Rankine's at φ = {}° (plane strain {:.1}°)",
                    r.friction_deg,
                    plane_strain_angle_deg(r.friction_deg)
                ),
                r.height_ratio(),
                1.0,
                RANKINE_TOL,
            )
            .with_note(format!(
                "H_c = {:.2} c/ρg against Rankine's {:.2} (plane strain), {:.2} (Klár's φ and c), \
                 {:.2} (Davis); column {:.0} mm high, stood at c = {:.1} Pa, failed at {:.1} Pa, \
                 Rankine's c {:.1} Pa; foot moved (cells) {}",
                r.height_over_cohesive_length(),
                rankine_heights(r.friction_deg)[0],
                rankine_heights(r.friction_deg)[1],
                rankine_heights(r.friction_deg)[2],
                r.height * 1e3,
                r.stood_at,
                r.failed_at,
                r.rankine_c,
                r.runs
                    .iter()
                    .map(|(c, m)| format!("{c:.1} Pa: {m:.1}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rankine_cohesion_is_the_height_formula_inverted() {
        // At φ = 30° (plane strain 43.9°) a 5 cm cut needs c_ps = ρgH/(4 tan 66.96°).
        let h = 0.05;
        let c = rankine_cohesion(h, 30.0);
        let ps = plane_strain_angle_deg(30.0).to_radians();
        let c_ps = c * ps.tan() / 30f64.to_radians().tan();
        let back = 4.0 * c_ps * (std::f64::consts::FRAC_PI_4 + ps / 2.0).tan() / (DENSITY * G);
        assert!((back - h).abs() < 1e-12, "{back}");
        // Twice the height, twice the cohesion.
        assert!((rankine_cohesion(2.0 * h, 30.0) - 2.0 * c).abs() < 1e-9);
        // The criterion's reading is the one rankine_cohesion inverts.
        let k = DENSITY * G * h / c;
        assert!((rankine_heights(30.0)[0] - k).abs() < 1e-9 * k);
        // Klár's φ as given at 30°: 4·tan 60°.
        assert!((rankine_heights(30.0)[1] - 4.0 * 3f64.sqrt()).abs() < 1e-12);
    }
}
