//! Which cases `powderlab validate` runs, at which resolutions, and about how long each takes.
//!
//! The quick set (no case named) is the exact and verification cases, about 20 s on 2 cores;
//! `--all` adds the planar and axisymmetric column collapses, the pile angle, Rankine's
//! vertical cut, the angle of repose against cohesion and the silo discharges through a slot
//! and a round orifice, about 60 minutes. The stability suite
//! has a table of its own ([`super::stability`]) and runs only when named.

use super::{axisym, bar, column, incline, pile, rankine, repose, silo, Check, Rheology};
use super::{
    collapse_checks, free_fall, halving_check, run_collapse, scale_invariance, small_a_band,
    Collapse, COLLAPSE_CELLS, LARGE_A, LARGE_A_SLOPE, LARGE_A_SLOPE_TOL,
};
use anyhow::bail;

/// Wall seconds of `validate silo_discharge` and `validate orifice_discharge` on 2 cores.
const SILO_ESTIMATE_S: f64 = 240.0;
const ORIFICE_ESTIMATE_S: f64 = 1250.0;

/// A validation case.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Case {
    FreeFall,
    Bar,
    SelfWeight,
    Incline,
    ColumnCollapse,
    AxisymmetricCollapse,
    PileAngle,
    Rankine,
    Repose,
    SiloDischarge,
    OrificeDischarge,
}

/// The flow law of the granular-flow cases' powder ([`Case::flows`]): the Drucker–Prager cone
/// the published checks use, or μ(I) with the cone's static friction
/// ([`Rheology::mu_i_matching`]) and grains of `grain_diameter` (m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Law {
    Cone,
    MuI { grain_diameter: f64 },
}

impl Law {
    /// The collapse or silo powder's rheology at Klár's `friction_deg`.
    fn rheology(self, friction_deg: f64) -> Rheology {
        match self {
            Law::Cone => Rheology::DruckerPrager,
            Law::MuI { grain_diameter } => Rheology::mu_i_matching(friction_deg, grain_diameter),
        }
    }
}

/// What a long run reports while it goes: `start` names the next simulation, `advance` gives
/// the fraction of it done.
pub trait Progress {
    fn start(&mut self, label: String);
    fn advance(&mut self, fraction: f64);
}

/// A [`Progress`] that reports nothing.
pub struct Silent;

impl Progress for Silent {
    fn start(&mut self, _: String) {}
    fn advance(&mut self, _: f64) {}
}

impl Case {
    /// Every case but the stability suite, in the order they run.
    pub const ALL: [Case; 11] = [
        Case::FreeFall,
        Case::Bar,
        Case::SelfWeight,
        Case::Incline,
        Case::ColumnCollapse,
        Case::AxisymmetricCollapse,
        Case::PileAngle,
        Case::Rankine,
        Case::Repose,
        Case::SiloDischarge,
        Case::OrificeDischarge,
    ];
    /// The cases `powderlab validate` runs when none is named.
    pub const QUICK: [Case; 4] = [Case::FreeFall, Case::Bar, Case::SelfWeight, Case::Incline];

    pub fn name(self) -> &'static str {
        match self {
            Case::FreeFall => "free_fall",
            Case::Bar => "bar",
            Case::SelfWeight => "self_weight",
            Case::Incline => "incline",
            Case::ColumnCollapse => "column_collapse",
            Case::AxisymmetricCollapse => "axisymmetric_collapse",
            Case::PileAngle => "pile_angle",
            Case::Rankine => "rankine",
            Case::Repose => "repose",
            Case::SiloDischarge => "silo_discharge",
            Case::OrificeDischarge => "orifice_discharge",
        }
    }

    /// Whether the case's powder flows under a law [`Law`] can change: the column collapses and
    /// the silos. The others check elasticity, static friction or the cone itself.
    pub fn flows(self) -> bool {
        matches!(
            self,
            Case::ColumnCollapse
                | Case::AxisymmetricCollapse
                | Case::SiloDischarge
                | Case::OrificeDischarge
        )
    }

    pub fn parse(s: &str) -> Option<Case> {
        Case::ALL.into_iter().find(|c| c.name() == s)
    }

    /// Wall seconds at the default resolution on 2 cores (an AMD EPYC, Zen 1), as measured by
    /// `powderlab validate CASE --threads 2` (the column collapse in an earlier, slower run);
    /// the cost of the resolution-dependent cases grows about as the cube of `--cells` (cells²
    /// particles in the slab, cells substeps).
    pub fn estimate_s(self, cells: Option<usize>) -> f64 {
        let (base, default_cells) = match self {
            Case::FreeFall => (0.2, None),
            Case::Bar => (4.2, None),
            Case::SelfWeight => (4.7, None),
            Case::Incline => (7.2, None),
            Case::ColumnCollapse => (740.0, Some(COLLAPSE_CELLS)),
            // Measured on the Intel VM beside a background study: 14 min before the a = 0.5
            // column at 40 cells was added (about 2 min more).
            Case::AxisymmetricCollapse => (960.0, Some(axisym::AXISYM_CELLS)),
            Case::PileAngle => (29.0, Some(pile::PILE_CELLS)),
            Case::Rankine => (120.0, Some(rankine::RANKINE_CELLS)),
            Case::Repose => (150.0, None),
            // Measured on the Intel VM (five slots and the lower fill, the cells fixed).
            Case::SiloDischarge => (SILO_ESTIMATE_S, None),
            Case::OrificeDischarge => (ORIFICE_ESTIMATE_S, None),
        };
        match (cells, default_cells) {
            (Some(c), Some(d)) => base * (c as f64 / d as f64).powi(3),
            _ => base,
        }
    }
}

/// Runs one case and returns its checks. `cells` sets the collapse's cells across L₀
/// (default [`COLLAPSE_CELLS`]) or the pile's column (default [`pile::PILE_CELLS`]); `law`
/// sets the flowing cases' rheology (a case that does not flow refuses μ(I)). Under μ(I) every
/// check's note says so, and the collapse's scale invariance is left out: μ(I) has a length,
/// the grain, so a column twice as large is not the same flow at twice the size.
pub fn run(
    case: Case,
    cells: Option<usize>,
    threads: Option<usize>,
    law: Law,
    progress: &mut dyn Progress,
) -> anyhow::Result<Vec<Check>> {
    refuse(case, law)?;
    let mut checks = Vec::new();
    match case {
        Case::FreeFall => checks.extend(free_fall(threads)?),
        Case::Bar => {
            for n in [16, 32, 64] {
                let r = bar::run_bar(&bar::Bar::new(n), threads)?;
                checks.extend(bar::bar_checks(&r));
            }
        }
        Case::SelfWeight => {
            for ppc in [1, 8] {
                let mut rs = Vec::new();
                for n in [8, 16, 32] {
                    rs.push(column::run_column(&column::Column::new(n, ppc), threads)?);
                }
                checks.extend(column::column_checks(&rs));
            }
        }
        Case::Incline => {
            for ratio in [0.95, 1.05] {
                let r = incline::run_incline(&incline::Incline::new(ratio), threads)?;
                checks.extend(incline::incline_checks(&r));
            }
        }
        Case::ColumnCollapse => {
            let cells = cells.unwrap_or(COLLAPSE_CELLS);
            if cells < 4 {
                bail!(
                    "--cells {cells} is too coarse: use at least 4 ({COLLAPSE_CELLS} for the published check)"
                );
            }
            let mut collapse = |a: f64, cells: usize| {
                progress.start(format!("column collapse a = {a}, {cells} cells"));
                let mut c = Collapse::new(a, cells);
                c.rheology = law.rheology(c.friction_deg);
                run_collapse(&c, threads, |f| progress.advance(f))
            };
            let (small, at_one) = small_a_band(cells, &mut collapse)?;
            checks.extend(small);
            let mut large = Vec::new();
            for a in LARGE_A {
                large.push(collapse(a, cells)?);
            }
            checks.extend(collapse_checks(
                "large-a",
                &large,
                LARGE_A_SLOPE,
                LARGE_A_SLOPE_TOL,
                &format!("{cells} cells across L0 at every a"),
            ));
            let fine = collapse(1.0, 2 * cells)?;
            checks.push(halving_check(&at_one, &fine, cells));
            if law == Law::Cone {
                checks.push(scale_invariance(1.0, cells, threads)?);
            }
        }
        Case::AxisymmetricCollapse => {
            let cells = cells.unwrap_or(axisym::AXISYM_CELLS);
            if cells < 4 {
                bail!(
                    "--cells {cells} is too coarse: use at least 4 ({} for the published check)",
                    axisym::AXISYM_CELLS
                );
            }
            let mut collapse = |a: f64, cells: usize| {
                progress.start(format!("axisymmetric collapse a = {a}, {cells} cells"));
                let mut c = axisym::Axisym::new(a, cells);
                c.rheology = law.rheology(c.friction_deg);
                axisym::run_axisym(&c, threads, |f| progress.advance(f))
            };
            let mut rs = Vec::new();
            for a in axisym::AXISYM_A {
                rs.push(collapse(a, cells)?);
            }
            // a = 0.5 as high in cells as a = 1 (twice the cells across R0), for the slope.
            let half = collapse(0.5, 2 * cells)?;
            let at_one = rs.iter().find(|r| r.aspect == 1.0).cloned();
            let equal_height: Vec<_> = std::iter::once(half).chain(at_one).collect();
            let fine = collapse(1.0, 2 * cells)?;
            checks.extend(axisym::axisym_checks(&rs, &equal_height, Some(&fine)));
        }
        Case::PileAngle => {
            use pile::{run_pile, Pile, MIN_PILE_CELLS, PILE_CELLS, PILE_FRICTION_DEG};
            let cells = cells.unwrap_or(PILE_CELLS);
            if cells < MIN_PILE_CELLS {
                bail!(
                    "--cells {cells} is too coarse for a pile: use at least {MIN_PILE_CELLS} \
                     ({PILE_CELLS} for the published check)"
                );
            }
            let mut rs = Vec::new();
            for phi in PILE_FRICTION_DEG {
                let p = Pile {
                    friction_deg: phi,
                    cells_across: cells,
                };
                progress.start(format!("pile at φ = {phi}°, {cells} cells"));
                rs.push(run_pile(&p, threads, |f| progress.advance(f))?);
            }
            checks.extend(pile::pile_checks(&rs));
        }
        Case::Rankine => {
            let cells = cells.unwrap_or(rankine::RANKINE_CELLS);
            if cells < 6 {
                bail!(
                    "--cells {cells} is too coarse for a cut: use at least 6 ({} for the published check)",
                    rankine::RANKINE_CELLS
                );
            }
            let mut rs = Vec::new();
            for phi in rankine::FRICTION_DEG {
                rs.push(rankine::run_rankine(phi, cells, threads, &mut |l| {
                    progress.start(l)
                })?);
            }
            checks.extend(rankine::rankine_checks(&rs));
        }
        Case::Repose => {
            let scene = crate::scene::Scene::shipped("repose_cylinder")?;
            let opts = crate::sim::SimOptions::threads(threads);
            let rows = repose::run(&scene, &opts, &mut |l| progress.start(l))?;
            checks.extend(repose::checks(&rows));
        }
        Case::SiloDischarge => {
            checks.extend(discharges(silo::Opening::Slot, threads, law, progress)?)
        }
        Case::OrificeDischarge => {
            checks.extend(discharges(silo::Opening::Round, threads, law, progress)?)
        }
    }
    if let Law::MuI { grain_diameter } = law {
        for c in &mut checks {
            let tag = format!("μ(I), grains of {} mm", grain_diameter * 1e3);
            c.note = if c.note.is_empty() {
                tag
            } else {
                format!("{tag}; {}", c.note)
            };
        }
    }
    Ok(checks)
}

/// An error where `case` does not flow and `law` is μ(I).
pub fn refuse(case: Case, law: Law) -> anyhow::Result<()> {
    if matches!(law, Law::MuI { .. }) && !case.flows() {
        let flowing: Vec<_> = Case::ALL
            .into_iter()
            .filter(|c| c.flows())
            .map(|c| c.name())
            .collect();
        bail!(
            "--rheology mu_i: {} has no flow law to change; μ(I) applies to {}",
            case.name(),
            flowing.join(", ")
        );
    }
    Ok(())
}

/// A silo's series ([`silo::Opening::series`]): one discharge per opening at the series' fill,
/// then the fill check's opening at the lower fill, and their checks.
fn discharges(
    opening: silo::Opening,
    threads: Option<usize>,
    law: Law,
    progress: &mut dyn Progress,
) -> anyhow::Result<Vec<Check>> {
    let mut discharge = |d: usize, h: usize| {
        progress.start(format!(
            "{}, D {d} cells, fill {h} cells",
            opening.case().replace('_', " ")
        ));
        let mut s = match opening {
            silo::Opening::Slot => silo::Silo::new(d, h),
            silo::Opening::Round => silo::Silo::round(d, h),
        };
        s.rheology = law.rheology(s.friction_deg);
        silo::run_silo(&s, threads, |f| progress.advance(f))
    };
    let (widths, fill, check, low_fill) = opening.series();
    let mut rs = Vec::new();
    for &d in widths {
        rs.push(discharge(d, fill)?);
    }
    let low = discharge(check, low_fill)?;
    let tall = rs
        .iter()
        .find(|r| r.opening_cells == check)
        .cloned()
        .expect("the fill check's opening is one of the series'");
    Ok(silo::silo_checks(opening, &rs, &tall, &low))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_case_parses_back_from_its_name() {
        for c in Case::ALL {
            assert_eq!(Case::parse(c.name()), Some(c));
        }
        assert_eq!(Case::parse("stability"), None);
    }

    #[test]
    fn a_case_that_does_not_flow_refuses_mu_i_before_it_runs() {
        let law = Law::MuI {
            grain_diameter: 1e-3,
        };
        for c in Case::ALL.into_iter().filter(|c| !c.flows()) {
            let e = run(c, None, Some(1), law, &mut Silent).unwrap_err();
            assert!(e.to_string().contains(c.name()), "{e}");
        }
        assert_eq!(Case::ALL.iter().filter(|c| c.flows()).count(), 4);
    }

    #[test]
    fn the_quick_set_is_a_fraction_of_all() {
        let quick: f64 = Case::QUICK.iter().map(|c| c.estimate_s(None)).sum();
        let all: f64 = Case::ALL.iter().map(|c| c.estimate_s(None)).sum();
        assert!(quick < 120.0 && all > 10.0 * quick, "{quick} s of {all} s");
        assert_eq!(
            Case::ColumnCollapse.estimate_s(Some(2 * COLLAPSE_CELLS)),
            8.0 * Case::ColumnCollapse.estimate_s(None)
        );
    }
}
