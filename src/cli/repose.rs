//! `powderlab repose`: the angle of repose of a scene's powder by its heap test
//! (`powderlab::lab::repose`).

use anyhow::{bail, Result};
use powderlab::lab::repose;
use powderlab::scene::Scene;
use powderlab::sim::SimOptions;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// A heap-test scene (scenes/repose_cylinder.ron: a tube of powder lifted off a rough
    /// floor).
    scene: PathBuf,
    /// Set a powder parameter, NAME=VALUE, by the calibration's names (friction_deg, cohesion,
    /// density, youngs_modulus, ...); repeatable.
    #[arg(long)]
    set: Vec<String>,
    /// Packings to run (lattice jitter seeds first-seed, first-seed + 1, ...); the angle is
    /// their mean, and its spread their sample standard deviation.
    #[arg(long, default_value_t = 3)]
    seeds: u64,
    /// The first packing's seed.
    #[arg(long, default_value_t = 0)]
    first_seed: u64,
    /// Fit this powder parameter (cohesion or friction_deg) to an observed angle of repose,
    /// `--angle-deg`, instead of measuring the scene's (FLIP's inference step, one parameter).
    #[arg(long, requires = "angle_deg")]
    fit: Option<String>,
    /// The observed angle of repose (degrees) that `--fit` matches.
    #[arg(long, requires = "fit")]
    angle_deg: Option<f64>,
    /// The observed angle's standard deviation (degrees), for the fitted value's spread.
    #[arg(long, default_value_t = 0.5)]
    angle_sd: f64,
    /// The fitted parameter's search range, NAME=LO:HI (default cohesion 0:20 Pa, friction_deg
    /// 10:60).
    #[arg(long)]
    bounds: Vec<String>,
    /// Heap tests a fit may run (each over --seeds packings), its bounds' two included.
    #[arg(long, default_value_t = 8)]
    evals: usize,
    /// Worker threads (default: the scene's setting; 0 = all cores).
    #[arg(long, value_parser = super::threads_arg)]
    threads: Option<usize>,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

pub fn run(a: Args) -> Result<()> {
    let scene = super::load_with_sets(&a.scene, &a.set)?;
    if !(1..=1000).contains(&a.seeds) {
        bail!("--seeds {}: expected 1 to 1000 packings", a.seeds);
    }
    let seeds: Vec<u64> = (a.first_seed..a.first_seed + a.seeds).collect();
    if let (Some(name), Some(target)) = (&a.fit, a.angle_deg) {
        return fit(&a, &scene, name, target, &seeds);
    }
    let pb = super::bar(a.seeds, a.json);
    pb.set_message("heaps");
    let r = repose::repose(&scene, &seeds, &SimOptions::threads(a.threads), &mut |k| {
        pb.set_position(k as u64)
    });
    pb.finish_and_clear();
    let r = r?;
    if a.json {
        println!("{}", serde_json::to_string(&r)?);
        return Ok(());
    }
    let spread = r.sd_deg.map_or("one packing".to_string(), |s| {
        format!("± {s:.2}° over {} packings", r.heaps.len())
    });
    println!("scene          {}", a.scene.display());
    if let Some(f) = r.friction_deg {
        println!("friction angle {f:.1}°");
    }
    if let Some(c) = r.cohesion_pa {
        println!("cohesion       {c:.1} Pa");
    }
    println!("angle of repose {:.2}° ({spread})", r.angle_deg);
    for h in &r.heaps {
        println!(
            "  seed {:>3}: {:.2}° (flanks {:.1}°–{:.1}°), height {:.1} mm, radius {:.1} mm, {}, {:.1} s",
            h.seed,
            h.angle_deg,
            h.flanks_deg.iter().copied().fold(f64::INFINITY, f64::min),
            h.flanks_deg.iter().copied().fold(0.0, f64::max),
            h.height_m * 1e3,
            h.radius_m * 1e3,
            if h.at_rest {
                "at rest".to_string()
            } else {
                format!("NOT at rest (a grain at {:.1} mm/s)", h.max_speed * 1e3)
            },
            h.wall_s
        );
    }
    if r.same_packing && r.heaps.len() > 1 {
        eprintln!("note: the scene's lattice has no jitter, so every seed packs the powder alike");
    }
    Ok(())
}

/// `--fit`: the parameter whose heap stands at the observed angle.
fn fit(a: &Args, scene: &Scene, name: &str, target: f64, seeds: &[u64]) -> Result<()> {
    let p = powderlab::lab::calibrate::params::parse(scene, &[name.to_string()], &a.bounds)
        .map_err(|e| anyhow::anyhow!("{e}"))?
        .remove(0);
    let pb = super::bar(a.evals as u64, a.json);
    pb.set_message("heap tests");
    let r = repose::fit(
        scene,
        &p,
        repose::Observed {
            angle_deg: target,
            sd_deg: a.angle_sd,
        },
        seeds,
        &SimOptions::threads(a.threads),
        a.evals,
        &mut |v, angle| {
            pb.inc(1);
            pb.set_message(format!("{} = {v:.3}: {angle:.2}°", p.label));
        },
    );
    pb.finish_and_clear();
    let r = r?;
    if a.json {
        println!("{}", serde_json::to_string(&r)?);
        return Ok(());
    }
    println!("scene          {}", a.scene.display());
    println!(
        "observed       {:.2}° ± {:.2}°",
        r.target_deg, r.target_sd_deg
    );
    println!(
        "fitted         {} = {:.4} ± {:.4}",
        r.parameter, r.value, r.sd
    );
    println!(
        "slope          {:.3}° per unit; packings' spread {}",
        r.slope_deg,
        r.packing_sd_deg
            .map_or("not measured (one packing)".into(), |s| format!("{s:.2}°"))
    );
    for (v, angle) in &r.evaluations {
        println!("  {} = {v:.4}: {angle:.2}°", r.parameter);
    }
    Ok(())
}
