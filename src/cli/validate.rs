//! `powderlab validate`: exact solutions and published experiments (the cases and their
//! resolutions are [`powderlab::lab::validate::suite`]'s), and the stability suite.

use anyhow::{bail, Result};
use powderlab::lab::validate::suite::{self, Case, Law, Progress};
use powderlab::util::check_output_file;
use serde_json::json;
use std::path::PathBuf;

/// Check against exact solutions and published experiments.
#[derive(clap::Args)]
pub struct Args {
    /// free_fall, bar, self_weight, incline, column_collapse, axisymmetric_collapse,
    /// pile_angle, rankine, repose, silo_discharge, orifice_discharge or stability. Without
    /// a case the quick set runs (free_fall, bar, self_weight, incline: about 20 s on 2 cores).
    case: Option<String>,
    /// Every case but stability (about an hour on 2 cores); with `--rheology mu_i`, every case
    /// whose powder flows.
    #[arg(long, conflicts_with = "case")]
    all: bool,
    /// The flowing cases' rheology (column_collapse, axisymmetric_collapse, silo_discharge,
    /// orifice_discharge): `cone`, the Drucker–Prager cone of the published checks, or `mu_i`,
    /// μ(I) with the cone's static friction and grains of --grain-mm.
    #[arg(long, value_enum, default_value = "cone")]
    rheology: Flow,
    /// The μ(I) grain diameter in millimetres (with --rheology mu_i; default 1).
    #[arg(long)]
    grain_mm: Option<f64>,
    /// Grid cells across the collapsing column (default 20, the published check: every
    /// large-a column, and the tallest small-a one, whose band stands 1.5× as many cells
    /// high), across the axisymmetric column's radius (default 20), the pile's column (default
    /// 40, at least 10) or Rankine's cut (default 20).
    #[arg(long)]
    cells: Option<usize>,
    #[arg(long, value_parser = super::threads_arg)]
    threads: Option<usize>,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
    /// Also write the JSON report here.
    #[arg(long)]
    report: Option<PathBuf>,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum Flow {
    Cone,
    #[value(name = "mu_i")]
    MuI,
}

/// Moves an indicatif bar through each simulation of a case.
struct Bar {
    pb: indicatif::ProgressBar,
    quiet: bool,
}

impl Progress for Bar {
    fn start(&mut self, label: String) {
        self.pb.finish_and_clear();
        self.pb = super::bar(1000, self.quiet);
        self.pb.set_message(label);
    }
    fn advance(&mut self, fraction: f64) {
        self.pb.set_position((fraction * 1000.0) as u64);
    }
}

/// Runs the command.
pub fn run(a: Args) -> Result<()> {
    if let Some(p) = &a.report {
        check_output_file(p, "--report")?;
    }
    let cases: Vec<Case> = match a.case.as_deref() {
        Some("stability") => return stability(a.threads, a.json, a.report),
        Some("all") => bail!("validate all: use --all (every case but stability)"),
        Some(name) => match Case::parse(name) {
            Some(c) => vec![c],
            None => {
                let known: Vec<_> = Case::ALL.iter().map(|c| c.name()).collect();
                bail!(
                    "unknown validation case '{name}': expected one of {known:?}, stability, or none for the quick set"
                )
            }
        },
        None if a.all => Case::ALL.to_vec(),
        None => Case::QUICK.to_vec(),
    };
    let law = match (a.rheology, a.grain_mm) {
        (Flow::Cone, None) => Law::Cone,
        (Flow::Cone, Some(g)) => {
            bail!("--grain-mm {g}: the cone has no grain size; add --rheology mu_i")
        }
        (Flow::MuI, g) => {
            let g = g.unwrap_or(1.0);
            if !(g.is_finite() && g > 0.0) {
                bail!(
                    "--grain-mm {g}: the grain diameter must be a positive number of millimetres"
                );
            }
            Law::MuI {
                grain_diameter: g * 1e-3,
            }
        }
    };
    let cases: Vec<Case> = match law {
        Law::MuI { .. } if a.all => cases.into_iter().filter(|c| c.flows()).collect(),
        Law::MuI { .. } if a.case.is_none() => bail!(
            "--rheology mu_i: the quick set has no flow law to change; name a flowing case or use --all"
        ),
        _ => cases,
    };
    for &c in &cases {
        suite::refuse(c, law)?;
    }
    let estimate: f64 = cases.iter().map(|c| c.estimate_s(a.cells)).sum();
    if !a.json {
        let names: Vec<_> = cases.iter().map(|c| c.name()).collect();
        eprintln!(
            "validate: {} — about {} on 2 cores{}",
            names.join(", "),
            duration(estimate),
            if a.case.is_none() && !a.all {
                let rest: Vec<Case> = Case::ALL
                    .into_iter()
                    .filter(|c| !Case::QUICK.contains(c))
                    .collect();
                let names: Vec<_> = rest.iter().map(|c| c.name()).collect();
                let s: f64 = rest.iter().map(|c| c.estimate_s(None)).sum();
                format!(
                    "; --all adds {} (about {} more)",
                    names.join(", "),
                    duration(s)
                )
            } else {
                String::new()
            }
        );
    }
    let mut bar = Bar {
        pb: indicatif::ProgressBar::hidden(),
        quiet: a.json,
    };
    let mut checks = Vec::new();
    for c in cases {
        checks.extend(suite::run(c, a.cells, a.threads, law, &mut bar)?);
    }
    bar.pb.finish_and_clear();
    let passed = checks.iter().all(|c| c.passed);
    let obj = json!({ "passed": passed, "checks": checks });
    if super::report_or_json(&obj, a.report.as_deref(), a.json)? {
        println!(
            "{:<16} {:<40} {:>12} {:>12} {:>10} {:<12} result",
            "case", "quantity", "measured", "published", "tolerance", "kind"
        );
        for c in &checks {
            println!(
                "{:<16} {:<40} {:>12.5e} {:>12.5e} {:>10.3e} {:<12} {}  {}",
                c.case,
                c.quantity,
                c.measured,
                c.published,
                c.tolerance,
                c.kind,
                match (c.kind, c.passed) {
                    ("reported", _) => "-",
                    (_, true) => "PASS",
                    (_, false) => "FAIL",
                },
                c.note
            );
        }
    }
    if !passed {
        std::process::exit(1);
    }
    Ok(())
}

/// Seconds as "40 s" or "12 min".
fn duration(s: f64) -> String {
    if s < 90.0 {
        format!("{s:.0} s")
    } else {
        format!("{:.0} min", s / 60.0)
    }
}

/// `validate stability`: every case of the suite, as a Markdown table (and JSON).
fn stability(threads: Option<usize>, json_out: bool, report: Option<PathBuf>) -> Result<()> {
    use powderlab::lab::validate::stability::{cases, markdown, run_case};
    let cases = cases();
    let pb = super::bar(cases.len() as u64, json_out);
    let mut results = Vec::new();
    for c in &cases {
        pb.set_message(c.name.clone());
        results.push(run_case(c, threads));
        pb.inc(1);
    }
    pb.finish_and_clear();
    let passed = results.iter().all(|r| r.outcome.acceptable());
    let obj = json!({ "passed": passed, "stability": results });
    if super::report_or_json(&obj, report.as_deref(), json_out)? {
        print!("{}", markdown(&results));
    }
    if !passed {
        eprintln!("a case ended unstable or non-finite (see the table)");
        std::process::exit(1);
    }
    Ok(())
}
