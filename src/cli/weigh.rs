//! `powderlab weigh`: one dose onto the scene's balance (`powderlab::lab::weigh`).

use anyhow::{bail, Result};
use clap::ValueEnum;
use powderlab::lab::weigh::{self, Dispense};
use powderlab::sim::rest::RestRule;
use powderlab::sim::SimOptions;
use powderlab::util::{create_output_dir, write_atomic};
use std::path::PathBuf;

/// How the dose is dispensed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Method {
    /// Tilt and tap on the balance's reading, with top-up scoops (`lab::weigh`'s rule).
    Rule,
}

#[derive(clap::Args)]
pub struct Args {
    /// Scene file with a balance and a skill tool (scenes/vial_weighing.ron).
    scene: PathBuf,
    /// The dose (mg); default the scene's task target.
    #[arg(long)]
    target_mg: Option<f64>,
    /// Set a powder parameter, NAME=VALUE, by the calibration's names (friction_deg, density,
    /// youngs_modulus, ...); repeatable.
    #[arg(long)]
    set: Vec<String>,
    /// Set a setting of the dispensing rule, NAME=VALUE (start_deg, tilt_deg_s, max_deg,
    /// tap_mm, tap_every, lead_mg, lead_s, wait_s, tolerance_mg, max_scoops); repeatable.
    #[arg(long)]
    dispense: Vec<String>,
    #[arg(long, value_enum, default_value_t = Method::Rule)]
    method: Method,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    json: bool,
    /// Write dose.json and weigh.rrd (the run, with the balance's reading beside it) here.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Worker threads (default: the scene's setting; 0 = all cores).
    #[arg(long, value_parser = super::threads_arg)]
    threads: Option<usize>,
    /// Simulate the resting powder in every step instead of setting it aside while nothing
    /// comes near it (`sim::rest`): the reference the rest rule is measured against.
    #[arg(long)]
    no_rest: bool,
}

pub fn run(a: Args) -> Result<()> {
    let scene = super::load_with_sets(&a.scene, &a.set)?;
    let mut d = Dispense::default();
    for s in &a.dispense {
        let Some((name, v)) = s.split_once('=') else {
            bail!("--dispense {s}: expected NAME=VALUE, e.g. tap_mm=0.5");
        };
        let Ok(v) = v.trim().parse::<f64>() else {
            bail!("--dispense {s}: '{v}' is not a number");
        };
        d.set(name.trim(), v)
            .map_err(|e| anyhow::anyhow!("--dispense {s}: {e}"))?;
    }
    let target_mg = match a.target_mg {
        Some(t) => t,
        None => match scene.task.as_ref().map(|t| t.target_value) {
            Some(powderlab::scene::TargetValue::Grams(g)) => g * 1e3,
            _ => bail!("--target-mg: not given, and the scene's task names no target in grams"),
        },
    };
    if !(target_mg.is_finite() && (0.0..=1e6).contains(&target_mg)) {
        bail!("--target-mg {target_mg}: expected a mass from 0 to 1e6 mg");
    }
    let Method::Rule = a.method;
    if let Some(dir) = &a.out {
        create_output_dir(dir, "--out")?;
    }
    let opts = SimOptions {
        rest: (!a.no_rest).then(RestRule::default),
        ..SimOptions::threads(a.threads)
    };
    let rrd = a.out.as_ref().map(|d| d.join("weigh.rrd"));
    let bar = super::bar(0, a.json);
    bar.set_message("steps");
    let mut progress = |step: usize, mg: f64| {
        bar.set_position(step as u64);
        if step.is_multiple_of(10) {
            bar.set_message(format!("steps, balance {mg:.1} mg"));
        }
    };
    let r = weigh::dose(&scene, target_mg, &d, &opts, rrd.as_deref(), &mut progress);
    bar.finish_and_clear();
    let r = r?;
    let obj = serde_json::json!({
        "scene": a.scene.display().to_string(),
        "method": "rule",
        "target_mg": r.target_mg,
        "delivered_mg": r.delivered_mg,
        "error_mg": r.error_mg,
        "reading_mg": r.reading_mg,
        "scoops": r.scoops,
        "taps": r.taps,
        "sim_s": r.sim_s,
        "wall_s": r.wall_s,
        "particle_substeps": r.particle_substeps,
        "rest": r.rest,
        "grain_mg": r.grain_mg,
        "dispense": d,
    });
    if let Some(dir) = &a.out {
        let mut full = obj.clone();
        full["trace_reading_mg_tilt_deg_height_mm"] = serde_json::json!(r.trace);
        write_atomic(
            &dir.join("dose.json"),
            serde_json::to_string_pretty(&full)?.as_bytes(),
        )?;
    }
    if a.json {
        println!("{obj}");
    } else {
        println!("scene            {}", a.scene.display());
        println!("target           {:.1} mg", r.target_mg);
        println!(
            "delivered        {:.2} mg (a grain weighs {:.3} mg)",
            r.delivered_mg, r.grain_mg
        );
        println!("error            {:+.2} mg", r.error_mg);
        println!("balance reads    {:.1} mg", r.reading_mg);
        println!("scoops           {}", r.scoops);
        println!("taps             {}", r.taps);
        println!("simulated        {:.2} s ({} steps)", r.sim_s, r.steps);
        println!(
            "wall time        {:.1} s ({:.3e} particle-substeps)",
            r.wall_s, r.particle_substeps
        );
        if let Some(p) = &rrd {
            println!("recording        {}", p.display());
        }
    }
    Ok(())
}
