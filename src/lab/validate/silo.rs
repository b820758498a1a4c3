//! Silo discharge through a slot (Beverloo): the flow rate of a quasi-2D silo through a slot of
//! width `D` in its floor, against the slot's law `W = C·ρ_b·√g·(D − D₀)^{3/2}` (mass per unit
//! time and per unit depth), and its independence of the fill height.
//!
//! The silo is the planar collapse's slab (plane strain between frictionless walls, 4 cells
//! deep) cut in half at the slot's middle: the frictionless domain wall at `x = wall·dx` is the
//! plane of symmetry, the silo's far wall is the domain's (frictionless too), and its floor is a
//! rough plate two cells thick ([`SILO_PLATE_CELLS`], with the particle projection, so that no
//! grain crosses it) from `D/2` to that wall. What leaves through the slot falls into the room
//! below and heaps there. The rate is the slope of the discharged mass (the particles below the
//! plate) against time while 10 % to 40 % of the fill has left ([`WINDOW`]): after the opening's
//! start-up, and while the fill stands well above the slot.
//!
//! A Drucker–Prager continuum has no grain: its `D₀` is a grid length, not Beverloo's `k·d`.
//! [`beverloo_fit`] fits `C`, `D₀` and the exponent together; the check is on the exponent.

use super::{build, read_body, Check, Rheology};
use serde::Serialize;

/// Grid cells of the domain walls (as the collapse's).
pub const SILO_WALL_CELLS: usize = 3;
/// Depth of the slab in cells (as the collapse's [`super::COLLAPSE_SLAB_CELLS`]).
pub const SILO_SLAB_CELLS: usize = 4;
/// Thickness of the floor plate in cells.
pub const SILO_PLATE_CELLS: usize = 2;
/// Slot widths of `validate silo_discharge`, in cells (the full slot; the run holds half).
/// A 6-cell slot arches and stops after about 10 % has left (0.13 kg/(s·m), 1,735 s of running
/// to the time limit), so the series starts at 8.
pub const SLOTS: [usize; 4] = [8, 10, 12, 16];
/// The fill height of the slot series, in cells.
pub const FILL_CELLS: usize = 48;
/// The slot at which the fill height is varied, and the lower fill's height in cells.
pub const FILL_CHECK_SLOT: usize = 12;
pub const LOW_FILL_CELLS: usize = 32;
/// The discharged fractions between which the rate is read.
pub const WINDOW: (f64, f64) = (0.1, 0.4);
/// The slot law's exponent and the tolerance the issue sets (±0.2).
pub const SLOT_EXPONENT: f64 = 1.5;
pub const EXPONENT_TOL: f64 = 0.2;
/// Largest change of the rate with the fill height (10 %).
pub const FILL_TOL: f64 = 0.1;
/// The run stops at the time the window's end would take at this Beverloo constant (a rate
/// this low means the silo jammed, or flows far below any published silo).
const C_FLOOR: f64 = 0.1;

/// Settings of one discharge.
#[derive(Clone, Copy, Debug)]
pub struct Silo {
    /// Full slot width D in cells.
    pub slot_cells: usize,
    /// Half the silo's width in cells (the symmetry plane to the far wall).
    pub half_width_cells: usize,
    /// Fill height in cells.
    pub fill_cells: usize,
    /// Room below the plate in cells, for the discharged powder.
    pub below_cells: usize,
    /// Cell size (m).
    pub dx: f64,
    /// Klár friction angle (degrees), as the collapse's: 22° is 30° in plane strain.
    pub friction_deg: f64,
    /// Coulomb friction of the plate.
    pub plate_friction: f64,
    pub rheology: Rheology,
    /// E/(ρ·g·H) with H the fill height, as the collapse's.
    pub stiffness_ratio: f64,
    pub particles_per_cell: usize,
    pub cfl: f64,
}

impl Silo {
    pub fn new(slot_cells: usize, fill_cells: usize) -> Silo {
        Silo {
            slot_cells,
            half_width_cells: 32,
            fill_cells,
            below_cells: 36,
            dx: 0.0025,
            friction_deg: 22.0,
            plate_friction: 0.577,
            rheology: Rheology::DruckerPrager,
            stiffness_ratio: 100.0,
            particles_per_cell: 8,
            cfl: 0.5,
        }
    }

    /// y of the plate's underside (m): what lies below it has left the silo.
    pub fn plate_bottom(&self) -> f64 {
        (SILO_WALL_CELLS + self.below_cells) as f64 * self.dx
    }

    /// The bulk density of the fill (kg/m³): the material's, since the particles fill their
    /// cells at its density.
    pub fn bulk_density(&self) -> f64 {
        1500.0
    }

    /// The slot width D (m).
    pub fn slot(&self) -> f64 {
        self.slot_cells as f64 * self.dx
    }
}

/// The RON scene of a half silo (see the module docs).
pub fn silo_scene(s: &Silo) -> String {
    let dx = s.dx;
    let wall = SILO_WALL_CELLS;
    let nx = 2 * wall + s.half_width_cells;
    let ny = 2 * wall + s.below_cells + SILO_PLATE_CELLS + s.fill_cells + 4;
    let nz = 2 * wall + SILO_SLAB_CELLS - 1;
    let x_sym = wall as f64 * dx;
    let x_far = (nx - wall) as f64 * dx;
    let y_pb = s.plate_bottom();
    let y_pt = y_pb + SILO_PLATE_CELLS as f64 * dx;
    let (z0, z1) = (
        (wall - 1) as f64 * dx,
        (wall - 1 + SILO_SLAB_CELLS) as f64 * dx,
    );
    // The plate runs from the slot's edge into the far wall's cells, across the whole depth.
    let plate_x0 = x_sym + 0.5 * s.slot();
    let plate_x1 = nx as f64 * dx;
    let e = s.stiffness_ratio * s.bulk_density() * 9.81 * s.fill_cells as f64 * dx;
    let material = s.rheology.material(e, s.friction_deg, 0.0);
    format!(
        r#"Scene(
    simulation: (cells: ({nx}, {ny}, {nz}), dx: {dx}, dt: 0.005, substeps: 1, stability: Auto,
                 cfl: {cfl}, walls: (cells: {wall}, contact: Separate, friction: 0.0)),
    materials: {{ "sand": {material} }},
    bodies: [(name: "fill", material: "sand",
              fill: Box(min: ({x_sym}, {y_pt}, {z0}), max: ({x_far}, {y_top}, {z1})),
              particles_per_cell: {ppc})],
    colliders: [(name: "plate", kind: Container,
                 shape: Box(half_extents: ({hx}, {hy}, {hz})),
                 position: ({cx}, {cy}, {cz}), friction: {mu}, particle_contact: true)],
)"#,
        cfl = s.cfl,
        y_top = y_pt + s.fill_cells as f64 * dx,
        ppc = s.particles_per_cell,
        hx = 0.5 * (plate_x1 - plate_x0),
        hy = 0.5 * SILO_PLATE_CELLS as f64 * dx,
        hz = nz as f64 * dx,
        cx = 0.5 * (plate_x0 + plate_x1),
        cy = 0.5 * (y_pb + y_pt),
        cz = 0.5 * nz as f64 * dx,
        mu = s.plate_friction,
    )
}

/// Outcome of one discharge.
#[derive(Clone, Debug, Serialize)]
pub struct SiloResult {
    pub slot_cells: usize,
    pub fill_cells: usize,
    /// The slot width D (m).
    pub slot: f64,
    /// Mass flow rate of the whole (two-sided) silo per unit depth (kg/(s·m)); `None` when the
    /// window's end was not reached by the time limit.
    pub rate: Option<f64>,
    /// `W/(ρ_b·√g·D^{3/2})`, the slot's Beverloo constant without an offset.
    pub beverloo_c: Option<f64>,
    /// `(t, discharged fraction)` after every step.
    #[serde(skip)]
    pub trace: Vec<(f64, f64)>,
    pub particles: usize,
    pub substeps: u64,
    pub substeps_per_step: usize,
    pub wall_s: f64,
}

/// The least-squares slope of `(t, fraction)` over the samples whose fraction lies within
/// `window`, times `scale`; `None` with fewer than three such samples.
pub fn discharge_rate(trace: &[(f64, f64)], window: (f64, f64), scale: f64) -> Option<f64> {
    let pts: Vec<(f64, f64)> = trace
        .iter()
        .copied()
        .filter(|&(_, f)| f >= window.0 && f <= window.1)
        .collect();
    if pts.len() < 3 {
        return None;
    }
    let n = pts.len() as f64;
    let (mt, mf) = (
        pts.iter().map(|p| p.0).sum::<f64>() / n,
        pts.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxy: f64 = pts.iter().map(|p| (p.0 - mt) * (p.1 - mf)).sum();
    let sxx: f64 = pts.iter().map(|p| (p.0 - mt).powi(2)).sum();
    (sxx > 0.0).then(|| scale * sxy / sxx)
}

/// Runs one discharge until [`WINDOW`]'s upper fraction has left, or to the time that would take
/// at Beverloo's constant [`C_FLOOR`].
pub fn run_silo(
    s: &Silo,
    threads: Option<usize>,
    mut progress: impl FnMut(f64),
) -> anyhow::Result<SiloResult> {
    let start = std::time::Instant::now();
    let name = format!("silo_discharge_d{}_h{}", s.slot_cells, s.fill_cells);
    let (_, mut sim) = build(&silo_scene(s), &name, threads)?;
    let dt = sim.params().dt;
    let y_pb = s.plate_bottom();
    let rho = s.bulk_density();
    // The half silo's fill per unit depth, and the whole silo's mass per unit depth.
    let half_area = (s.half_width_cells * s.fill_cells) as f64 * s.dx * s.dx;
    let law = |c: f64| c * rho * 9.81f64.sqrt() * s.slot().powf(SLOT_EXPONENT);
    let t_max = WINDOW.1 * 2.0 * rho * half_area / law(C_FLOOR);
    let max_steps = (t_max / dt).ceil() as usize;
    let mut trace = Vec::with_capacity(max_steps);
    let mut particles = 0;
    for k in 1..=max_steps {
        sim.step()?;
        let (left, n) = read_body(&mut sim, |x, _| {
            (x.iter().filter(|p| p.y < y_pb).count(), x.len())
        });
        particles = n;
        let f = left as f64 / n as f64;
        trace.push((k as f64 * dt, f));
        progress((f / WINDOW.1).max(k as f64 / max_steps as f64).min(1.0));
        if f > WINDOW.1 {
            break;
        }
    }
    let rate = discharge_rate(&trace, WINDOW, 2.0 * rho * half_area);
    Ok(SiloResult {
        slot_cells: s.slot_cells,
        fill_cells: s.fill_cells,
        slot: s.slot(),
        rate,
        beverloo_c: rate.map(|w| w / law(1.0)),
        trace,
        particles,
        substeps: sim.clock().total_substeps,
        substeps_per_step: sim.params().substeps,
        wall_s: start.elapsed().as_secs_f64(),
    })
}

/// `W = C·(D − D₀)^n` fitted to `(D, W)` points: `D₀` by a scan over `[−D_min, D_min)` in
/// thousandths of `D_min`, and at each `D₀` the least-squares line through
/// `(ln(D − D₀), ln W)`, keeping the `D₀` of least squared residual.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct BeverlooFit {
    pub exponent: f64,
    pub offset: f64,
    pub prefactor: f64,
    /// Root-mean-square residual of `ln W`.
    pub rms: f64,
}

/// The least-squares line `y = a + b·x` through `pts`: `(a, b, rms residual)`.
fn line(pts: &[(f64, f64)]) -> (f64, f64, f64) {
    let n = pts.len() as f64;
    let (mx, my) = (
        pts.iter().map(|p| p.0).sum::<f64>() / n,
        pts.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let b = sxy / sxx;
    let a = my - b * mx;
    let ss: f64 = pts.iter().map(|p| (p.1 - a - b * p.0).powi(2)).sum();
    (a, b, (ss / n).sqrt())
}

/// [`BeverlooFit`] of `(D, W)` points (at least three distinct `D`, every `W > 0`); `None`
/// otherwise. With `offset: false`, `D₀ = 0` (the plain log–log slope).
pub fn beverloo_fit(points: &[(f64, f64)], offset: bool) -> Option<BeverlooFit> {
    let mut ds: Vec<f64> = points.iter().map(|p| p.0).collect();
    ds.sort_by(f64::total_cmp);
    ds.dedup();
    if ds.len() < 3 || !points.iter().all(|p| p.0 > 0.0 && p.1 > 0.0) {
        return None;
    }
    let d_min = ds[0];
    let fit_at = |d0: f64| {
        let pts: Vec<(f64, f64)> = points
            .iter()
            .map(|&(d, w)| ((d - d0).ln(), w.ln()))
            .collect();
        let (a, b, rms) = line(&pts);
        BeverlooFit {
            exponent: b,
            offset: d0,
            prefactor: a.exp(),
            rms,
        }
    };
    if !offset {
        return Some(fit_at(0.0));
    }
    (-1000..1000)
        .map(|k| fit_at(d_min * k as f64 / 1000.0))
        .min_by(|a, b| a.rms.total_cmp(&b.rms))
}

/// The case's checks: the slot law's exponent with a fitted offset (the criterion), the plain
/// log–log slope and each run's constant (reported), and the rate's change with the fill height
/// between `tall` and `low` (the same slot).
pub fn silo_checks(results: &[SiloResult], tall: &SiloResult, low: &SiloResult) -> Vec<Check> {
    let case = "silo_discharge";
    let mut out = Vec::new();
    let reported = |quantity: String, measured: f64, published: f64, note: String| Check {
        case: case.into(),
        quantity,
        measured,
        published,
        tolerance: 0.0,
        kind: "reported",
        passed: true,
        note,
    };
    for r in results {
        let note = format!(
            "D = {} cells, fill {} cells; {} particles, {} substeps ({} a step), {:.0} s",
            r.slot_cells, r.fill_cells, r.particles, r.substeps, r.substeps_per_step, r.wall_s
        );
        match r.beverloo_c {
            Some(c) => out.push(reported(
                format!("W/(ρ√g D^1.5) at D = {} cells", r.slot_cells),
                c,
                f64::NAN,
                note,
            )),
            None => out.push(Check {
                case: case.into(),
                quantity: format!("discharge at D = {} cells", r.slot_cells),
                measured: r.trace.last().map_or(0.0, |t| t.1),
                published: WINDOW.1,
                tolerance: 0.0,
                kind: "reached",
                passed: false,
                note: format!("the window's end was not reached: the silo jammed; {note}"),
            }),
        }
    }
    let pts: Vec<(f64, f64)> = results
        .iter()
        .filter_map(|r| r.rate.map(|w| (r.slot_cells as f64, w)))
        .collect();
    match beverloo_fit(&pts, true) {
        Some(f) => out.push(Check {
            case: case.into(),
            quantity: "slot exponent, D0 fitted".into(),
            measured: f.exponent,
            published: SLOT_EXPONENT,
            tolerance: EXPONENT_TOL,
            kind: "abs<=tol",
            passed: (f.exponent - SLOT_EXPONENT).abs() <= EXPONENT_TOL,
            note: format!(
                "|exponent - 1.5| within the tolerance; D0 = {:.2} cells, C = {:.3} in cells, rms of ln W {:.3}, over {} slots",
                f.offset,
                f.prefactor,
                f.rms,
                pts.len()
            ),
        }),
        None => out.push(Check {
            case: case.into(),
            quantity: "slot exponent, D0 fitted".into(),
            measured: f64::NAN,
            published: SLOT_EXPONENT,
            tolerance: EXPONENT_TOL,
            kind: "abs<=tol",
            passed: false,
            note: format!("{} slots gave a rate: too few to fit", pts.len()),
        }),
    }
    if let Some(f) = beverloo_fit(&pts, false) {
        out.push(reported(
            "slot log-log slope, D0 = 0".into(),
            f.exponent,
            SLOT_EXPONENT,
            format!("rms of ln W {:.3}; reported, not a criterion", f.rms),
        ));
    }
    match (tall.rate, low.rate) {
        (Some(a), Some(b)) => {
            let change = (b - a).abs() / a;
            out.push(Check {
                case: case.into(),
                quantity: format!(
                    "rate change, fill {} -> {} cells",
                    tall.fill_cells, low.fill_cells
                ),
                measured: change,
                published: 0.0,
                tolerance: FILL_TOL,
                kind: "abs<=tol",
                passed: change <= FILL_TOL,
                note: format!("D = {} cells: {a:.4} and {b:.4} kg/(s m)", tall.slot_cells),
            });
        }
        _ => out.push(Check {
            case: case.into(),
            quantity: "rate change with the fill height".into(),
            measured: f64::NAN,
            published: 0.0,
            tolerance: FILL_TOL,
            kind: "abs<=tol",
            passed: false,
            note: "a run did not reach the window's end".into(),
        }),
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fit recovers an exponent and offset it was given, on exact data (to the scan's step
    /// of a thousandth of the smallest D).
    #[test]
    fn the_fit_recovers_a_law_it_was_given() {
        let pts: Vec<(f64, f64)> = [6.0, 8.0, 10.0, 12.0, 16.0]
            .iter()
            .map(|&d: &f64| (d, 0.7 * (d - 1.5f64).powf(1.5)))
            .collect();
        let f = beverloo_fit(&pts, true).unwrap();
        assert!((f.offset - 1.5).abs() < 0.01, "{f:?}");
        assert!((f.exponent - 1.5).abs() < 0.01, "{f:?}");
        assert!((f.prefactor - 0.7).abs() < 0.02, "{f:?}");
        let plain = beverloo_fit(&pts, false).unwrap();
        assert!(
            plain.exponent > 1.6,
            "an offset steepens the plain slope: {plain:?}"
        );
        assert!(beverloo_fit(&pts[..2], true).is_none());
        assert!(beverloo_fit(&[(1.0, 1.0), (2.0, -1.0), (3.0, 1.0)], true).is_none());
    }

    #[test]
    fn the_rate_is_the_slope_inside_the_window() {
        // A start-up, then 0.5 of the fill a second, then a tail: only the middle counts.
        let trace: Vec<(f64, f64)> = (0..200)
            .map(|k| {
                let t = k as f64 * 0.01;
                (t, if t < 0.2 { 0.0 } else { 0.5 * (t - 0.2) })
            })
            .collect();
        let r = discharge_rate(&trace, WINDOW, 3.0).unwrap();
        assert!((r - 1.5).abs() < 1e-9, "{r}");
        assert!(discharge_rate(&trace[..30], WINDOW, 1.0).is_none());
    }

    #[test]
    fn the_scene_parses_with_its_slot_open() {
        let s = Silo::new(8, 16);
        let scene =
            crate::scene::Scene::parse(&silo_scene(&s), std::path::Path::new("<validate:silo>"))
                .unwrap();
        let plate = &scene.colliders[0];
        // The plate's inner edge is D/2 from the plane of symmetry.
        let edge = plate.position.0 - plate_half_x(&plate.shape);
        let x_sym = SILO_WALL_CELLS as f64 * s.dx;
        assert!((edge - x_sym - 0.5 * s.slot()).abs() < 1e-12, "{edge}");
    }

    fn plate_half_x(shape: &crate::math::sdf::Shape) -> f64 {
        match shape {
            crate::math::sdf::Shape::Box { half_extents } => half_extents[0],
            _ => panic!("the plate is a box"),
        }
    }
}
