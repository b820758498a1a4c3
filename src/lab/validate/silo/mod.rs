//! Silo discharge (Beverloo): the flow rate of a silo through an opening of width `D` in its
//! floor, against Beverloo's law `W = C·ρ_b·√g·(D − D₀)^n`, and its independence of the fill
//! height. Two openings ([`Opening`]):
//!
//! - **a slot**, `n = 3/2` (mass per unit time and per unit depth): the planar collapse's slab
//!   (plane strain between frictionless walls, 4 cells deep) cut in half at the slot's middle.
//!   The frictionless domain wall at `x = wall·dx` is the plane of symmetry, the silo's far wall
//!   is the domain's (frictionless too), and its floor is a rough box plate from `D/2` to that
//!   wall;
//! - **a round orifice**, `n = 5/2` (mass per unit time): a quarter of a square silo, the two
//!   frictionless domain walls at `x = wall·dx` and `z = wall·dx` its planes of symmetry, the
//!   orifice's axis their intersection, and its floor a rough plate with a round hole
//!   ([`plate::OrificePlate`], a shape of the lab's own through the `ShapePlugin` extension
//!   point).
//!
//! Both plates are [`SILO_PLATE_CELLS`] thick, with the particle projection, so that no grain
//! crosses them. What leaves through the opening falls into the room below and heaps there. The
//! rate is the slope of the discharged mass (the particles below the plate) against time while
//! 10 % to 40 % of the fill has left ([`WINDOW`]): after the opening's start-up, and while the
//! fill stands well above the opening.
//!
//! A Drucker–Prager continuum has no grain: its `D₀` is a grid length, not Beverloo's `k·d`.
//! [`beverloo_fit`] fits `C`, `D₀` and the exponent together; the check is on the exponent.

pub mod fit;
pub mod plate;

pub use fit::{beverloo_fit, discharge_rate, BeverlooFit};

use super::{build, read_body, Check, Rheology};
use serde::Serialize;

/// Grid cells of the domain walls (as the collapse's).
pub const SILO_WALL_CELLS: usize = 3;
/// Depth of the slot's slab in cells (as the collapse's [`super::COLLAPSE_SLAB_CELLS`]).
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
/// Orifice diameters of `validate orifice_discharge`, in cells (the full orifice; the run
/// holds a quarter), up to the largest that a silo of [`ROUND_HALF_WIDTH_CELLS`] holds 2.5
/// times across. The series was fixed at 8–14 before any run; an 8-cell orifice (4 cells of
/// radius in the quarter) slowed to under an eighth of its rate after about 30 % had left and
/// did not reach the window's end (the validation page), so the case starts at 10, as the
/// slot's starts above the slot that arched.
pub const ORIFICES: [usize; 3] = [10, 12, 14];
/// Half the round silo's width in cells (its full width 36 cells, 2.57 times the largest
/// orifice).
pub const ROUND_HALF_WIDTH_CELLS: usize = 18;
/// The fill height of the orifice series (2.6 times the largest orifice), the orifice at which
/// it is varied, and the lower fill (two thirds of it, as the slot's).
pub const ROUND_FILL_CELLS: usize = 36;
pub const ROUND_FILL_CHECK: usize = 10;
pub const ROUND_LOW_FILL_CELLS: usize = 24;
/// The discharged fractions between which the rate is read.
pub const WINDOW: (f64, f64) = (0.1, 0.4);
/// The tolerance the issue sets on either law's exponent (±0.2).
pub const EXPONENT_TOL: f64 = 0.2;
/// Largest change of the rate with the fill height (10 %).
pub const FILL_TOL: f64 = 0.1;
/// The run stops at the time the window's end would take at this Beverloo constant (a rate
/// this low means the silo jammed, or flows far below any published silo).
const C_FLOOR: f64 = 0.1;

/// The silo's opening.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Opening {
    /// A slot across a plane-strain slab: half of it simulated, the rate per unit depth.
    Slot,
    /// A round orifice in a square silo: a quarter of it simulated.
    Round,
}

impl Opening {
    /// The validation series: its openings (cells), its fill height, and the opening and the
    /// lower fill of the fill check.
    pub fn series(self) -> (&'static [usize], usize, usize, usize) {
        match self {
            Opening::Slot => (&SLOTS, FILL_CELLS, FILL_CHECK_SLOT, LOW_FILL_CELLS),
            Opening::Round => (
                &ORIFICES,
                ROUND_FILL_CELLS,
                ROUND_FILL_CHECK,
                ROUND_LOW_FILL_CELLS,
            ),
        }
    }

    /// Beverloo's exponent: 3/2 for a slot, 5/2 for a round orifice.
    pub fn exponent(self) -> f64 {
        match self {
            Opening::Slot => 1.5,
            Opening::Round => 2.5,
        }
    }

    /// How many copies of the simulated part make the whole silo.
    pub fn copies(self) -> f64 {
        match self {
            Opening::Slot => 2.0,
            Opening::Round => 4.0,
        }
    }

    /// The validation case's name.
    pub fn case(self) -> &'static str {
        match self {
            Opening::Slot => "silo_discharge",
            Opening::Round => "orifice_discharge",
        }
    }

    fn word(self) -> &'static str {
        match self {
            Opening::Slot => "slot",
            Opening::Round => "orifice",
        }
    }

    fn rate_unit(self) -> &'static str {
        match self {
            Opening::Slot => "kg/(s m)",
            Opening::Round => "kg/s",
        }
    }
}

/// Settings of one discharge.
#[derive(Clone, Copy, Debug)]
pub struct Silo {
    pub opening: Opening,
    /// Full opening width (the slot's, or the orifice's diameter) D in cells.
    pub opening_cells: usize,
    /// Half the silo's width in cells (a plane of symmetry to the far wall).
    pub half_width_cells: usize,
    /// Fill height in cells.
    pub fill_cells: usize,
    /// Room below the plate in cells, for the discharged powder.
    pub below_cells: usize,
    /// Cell size (m).
    pub dx: f64,
    /// Klár friction angle (degrees), as the collapse's: 22° is 30° in plane strain. The
    /// orifice's silo has the same powder.
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
    /// A half silo with a slot of `slot_cells`.
    pub fn new(slot_cells: usize, fill_cells: usize) -> Silo {
        Silo {
            opening: Opening::Slot,
            opening_cells: slot_cells,
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

    /// A quarter silo with a round orifice of `diameter_cells`, the slot's powder and plate.
    pub fn round(diameter_cells: usize, fill_cells: usize) -> Silo {
        Silo {
            opening: Opening::Round,
            half_width_cells: ROUND_HALF_WIDTH_CELLS,
            // The heap below a quarter orifice is narrower than the slot's.
            below_cells: 30,
            ..Silo::new(diameter_cells, fill_cells)
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

    /// The opening's width D (m).
    pub fn width(&self) -> f64 {
        self.opening_cells as f64 * self.dx
    }

    /// The fill of the simulated part: its area (m², per unit depth) for a slot, its volume
    /// (m³) for an orifice.
    pub fn fill_measure(&self) -> f64 {
        let (w, h) = (
            self.half_width_cells as f64 * self.dx,
            self.fill_cells as f64 * self.dx,
        );
        match self.opening {
            Opening::Slot => w * h,
            Opening::Round => w * w * h,
        }
    }

    /// Beverloo's law without an offset at constant `c`: `c·ρ_b·√g·D^n`.
    pub fn law(&self, c: f64) -> f64 {
        c * self.bulk_density() * 9.81f64.sqrt() * self.width().powf(self.opening.exponent())
    }
}

/// The RON scene of a half silo with a slot, or a quarter silo with an orifice (see the module
/// docs).
pub fn silo_scene(s: &Silo) -> String {
    let dx = s.dx;
    let wall = SILO_WALL_CELLS;
    let round = s.opening == Opening::Round;
    let nx = 2 * wall + s.half_width_cells;
    let ny = 2 * wall + s.below_cells + SILO_PLATE_CELLS + s.fill_cells + 4;
    let nz = if round {
        nx
    } else {
        2 * wall + SILO_SLAB_CELLS - 1
    };
    let x_sym = wall as f64 * dx;
    let x_far = (nx - wall) as f64 * dx;
    let y_pb = s.plate_bottom();
    let y_pt = y_pb + SILO_PLATE_CELLS as f64 * dx;
    let (z0, z1) = if round {
        (x_sym, x_far)
    } else {
        (
            (wall - 1) as f64 * dx,
            (wall - 1 + SILO_SLAB_CELLS) as f64 * dx,
        )
    };
    let half_t = 0.5 * SILO_PLATE_CELLS as f64 * dx;
    let cy = 0.5 * (y_pb + y_pt);
    let plate = if round {
        // An annulus about the symmetry planes' intersection, reaching past the domain's corner.
        let outer = std::f64::consts::SQRT_2 * nx as f64 * dx;
        format!(
            "shape: Custom({tag}((hole_radius: {r}, outer_radius: {outer}, half_thickness: {half_t}))),
                 position: ({x_sym}, {cy}, {x_sym})",
            tag = plate::OrificePlate::TAG_NAME,
            r = 0.5 * s.width(),
        )
    } else {
        // The plate runs from the slot's edge into the far wall's cells, across the whole depth.
        let plate_x0 = x_sym + 0.5 * s.width();
        let plate_x1 = nx as f64 * dx;
        format!(
            "shape: Box(half_extents: ({hx}, {half_t}, {hz})), position: ({cx}, {cy}, {cz})",
            hx = 0.5 * (plate_x1 - plate_x0),
            hz = nz as f64 * dx,
            cx = 0.5 * (plate_x0 + plate_x1),
            cz = 0.5 * nz as f64 * dx,
        )
    };
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
    colliders: [(name: "plate", kind: Container, {plate}, friction: {mu},
                 particle_contact: true)],
)"#,
        cfl = s.cfl,
        y_top = y_pt + s.fill_cells as f64 * dx,
        ppc = s.particles_per_cell,
        mu = s.plate_friction,
    )
}

/// Outcome of one discharge.
#[derive(Clone, Debug, Serialize)]
pub struct SiloResult {
    pub opening_cells: usize,
    pub fill_cells: usize,
    /// The opening's width D (m).
    pub width: f64,
    /// Mass flow rate of the whole silo: per unit depth (kg/(s·m)) through a slot, kg/s
    /// through an orifice; `None` when the window's end was not reached by the time limit (the
    /// opening arched).
    pub rate: Option<f64>,
    /// `W/(ρ_b·√g·D^n)`, Beverloo's constant without an offset.
    pub beverloo_c: Option<f64>,
    /// `(t, discharged fraction)` after every step.
    #[serde(skip)]
    pub trace: Vec<(f64, f64)>,
    pub particles: usize,
    pub substeps: u64,
    pub substeps_per_step: usize,
    pub wall_s: f64,
}

/// Runs one discharge until [`WINDOW`]'s upper fraction has left, or to the time that would take
/// at Beverloo's constant [`C_FLOOR`].
pub fn run_silo(
    s: &Silo,
    threads: Option<usize>,
    mut progress: impl FnMut(f64),
) -> anyhow::Result<SiloResult> {
    let start = std::time::Instant::now();
    plate::register();
    let name = format!(
        "{}_d{}_h{}",
        s.opening.case(),
        s.opening_cells,
        s.fill_cells
    );
    let (_, mut sim) = build(&silo_scene(s), &name, threads)?;
    let dt = sim.params().dt;
    let y_pb = s.plate_bottom();
    // The whole silo's mass (per unit depth for a slot).
    let mass = s.opening.copies() * s.bulk_density() * s.fill_measure();
    let t_max = WINDOW.1 * mass / s.law(C_FLOOR);
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
    let rate = discharge_rate(&trace, WINDOW, mass);
    Ok(SiloResult {
        opening_cells: s.opening_cells,
        fill_cells: s.fill_cells,
        width: s.width(),
        rate,
        beverloo_c: rate.map(|w| w / s.law(1.0)),
        trace,
        particles,
        substeps: sim.clock().total_substeps,
        substeps_per_step: sim.params().substeps,
        wall_s: start.elapsed().as_secs_f64(),
    })
}

/// The case's checks for `opening`: Beverloo's exponent with a fitted offset (the criterion),
/// the plain log–log slope and each run's constant (reported), and the rate's change with the
/// fill height between `tall` and `low` (the same opening).
pub fn silo_checks(
    opening: Opening,
    results: &[SiloResult],
    tall: &SiloResult,
    low: &SiloResult,
) -> Vec<Check> {
    let (case, word, n) = (opening.case(), opening.word(), opening.exponent());
    let mut out = Vec::new();
    let check = |quantity: String, measured: f64, published: f64, tolerance: f64| Check {
        case: case.into(),
        quantity,
        measured,
        published,
        tolerance,
        kind: "abs<=tol",
        passed: (measured - published).abs() <= tolerance,
        note: String::new(),
    };
    let reported = |quantity: String, measured: f64, published: f64, note: String| Check {
        kind: "reported",
        passed: true,
        note,
        ..check(quantity, measured, published, 0.0)
    };
    for r in results {
        let note = format!(
            "D = {} cells, fill {} cells; {} particles, {} substeps ({} a step), {:.0} s",
            r.opening_cells, r.fill_cells, r.particles, r.substeps, r.substeps_per_step, r.wall_s
        );
        match r.beverloo_c {
            Some(c) => out.push(reported(
                format!("W/(ρ√g D^{n}) at D = {} cells", r.opening_cells),
                c,
                f64::NAN,
                note,
            )),
            None => out.push(Check {
                kind: "reached",
                passed: false,
                note: format!("the window's end was not reached: the silo jammed; {note}"),
                ..check(
                    format!("discharge at D = {} cells", r.opening_cells),
                    r.trace.last().map_or(0.0, |t| t.1),
                    WINDOW.1,
                    0.0,
                )
            }),
        }
    }
    let pts: Vec<(f64, f64)> = results
        .iter()
        .filter_map(|r| r.rate.map(|w| (r.opening_cells as f64, w)))
        .collect();
    let quantity = format!("{word} exponent, D0 fitted");
    match beverloo_fit(&pts, true) {
        Some(f) => out.push(Check {
            note: format!(
                "criterion |exponent - {n}| <= tolerance; D0 = {:.2} cells, C = {:.4e} with D in cells, rms of ln W {:.3}, over {} {word}s{}",
                f.offset,
                f.prefactor,
                f.rms,
                pts.len(),
                if pts.len() == 3 {
                    " (three rates fix the three constants: no residual is left to judge the fit)"
                } else {
                    ""
                }
            ),
            ..check(quantity, f.exponent, n, EXPONENT_TOL)
        }),
        None => out.push(Check {
            passed: false,
            note: format!("{} {word}s gave a rate: too few to fit", pts.len()),
            ..check(quantity, f64::NAN, n, EXPONENT_TOL)
        }),
    }
    if let Some(f) = beverloo_fit(&pts, false) {
        out.push(reported(
            format!("{word} log-log slope, D0 = 0"),
            f.exponent,
            n,
            format!("rms of ln W {:.3}; reported, not a criterion", f.rms),
        ));
    }
    let quantity = format!(
        "rate change, fill {} -> {} cells",
        tall.fill_cells, low.fill_cells
    );
    match (tall.rate, low.rate) {
        (Some(a), Some(b)) => out.push(Check {
            note: format!(
                "D = {} cells: {a:.4} and {b:.4} {}",
                tall.opening_cells,
                opening.rate_unit()
            ),
            ..check(quantity, (b - a).abs() / a, 0.0, FILL_TOL)
        }),
        _ => out.push(Check {
            passed: false,
            note: "a run did not reach the window's end".into(),
            ..check(quantity, f64::NAN, 0.0, FILL_TOL)
        }),
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::sdf::Shape;
    use glam::DVec3;

    fn parse(s: &Silo) -> crate::scene::Scene {
        plate::register();
        crate::scene::Scene::parse(&silo_scene(s), std::path::Path::new("<validate:silo>")).unwrap()
    }

    #[test]
    fn the_scene_parses_with_its_slot_open() {
        let s = Silo::new(8, 16);
        let plate = &parse(&s).colliders[0];
        let Shape::Box { half_extents } = plate.shape else {
            panic!("the slot's plate is a box")
        };
        // The plate's inner edge is D/2 from the plane of symmetry.
        let edge = plate.position.0 - half_extents[0];
        let x_sym = SILO_WALL_CELLS as f64 * s.dx;
        assert!((edge - x_sym - 0.5 * s.width()).abs() < 1e-12, "{edge}");
    }

    /// The quarter silo's plate is open within D/2 of the symmetry planes' corner and closed
    /// everywhere else over the fill, to the domain's far corner.
    #[test]
    fn the_round_silo_has_its_orifice_on_the_symmetry_axis() {
        let s = Silo::round(10, 12);
        let scene = parse(&s);
        let c = &scene.colliders[0];
        let Shape::Custom(shape) = &c.shape else {
            panic!("the orifice's plate is the lab's shape")
        };
        let x_sym = SILO_WALL_CELLS as f64 * s.dx;
        let far = (2 * SILO_WALL_CELLS + s.half_width_cells) as f64 * s.dx;
        let r = 0.5 * s.width();
        let at = |x: f64, z: f64| {
            shape
                .sdf(DVec3::new(x, c.position.1, z) - DVec3::from(c.position))
                .0
        };
        // In the hole, just inside its rim, and at the far corner.
        assert!(at(x_sym, x_sym) > 0.0 && at(x_sym + 0.99 * r, x_sym) > 0.0);
        assert!(at(x_sym + 1.01 * r, x_sym) < 0.0 && at(far, far) < 0.0);
        // The fill fills the quarter: its square across, from the plate up.
        let crate::scene::Fill::Box { min, max } = &scene.bodies[0].fill else {
            panic!("a box of powder")
        };
        assert!((min.0 - x_sym).abs() < 1e-12 && (min.2 - x_sym).abs() < 1e-12);
        assert!((max.0 - max.2).abs() < 1e-12);
        assert!((s.fill_measure() - (max.0 - min.0).powi(2) * (max.1 - min.1)).abs() < 1e-12);
    }
}
