//! `powderlab calibrate`: fit a powder's physical parameters to observations through the
//! adjoint; `powderlab observe`: what a camera would see of a scene (synthetic observations).

use anyhow::{bail, Result};
use powderlab::lab::calibrate::observation::{self, Observation};
use powderlab::lab::calibrate::plot::{curves_svg, Curve};
use powderlab::lab::calibrate::{self, params, AdamConfig, Calibration, Eval, Journal};
use powderlab::scene::Scene;
use powderlab::util::{create_output_dir, write_atomic};
use std::path::PathBuf;

/// Fit friction angle, stiffness or contact friction to observed height maps or point clouds by
/// gradient descent through the simulation; writes fitted.ron, report.md, loss.svg, trace.csv
/// and calibration.rrd to --out.
#[derive(clap::Args)]
pub struct Args {
    /// The scene to calibrate; its values of the fitted parameters are the start.
    scene: PathBuf,
    /// An observation: a height map (.csv, or 16-bit .png) or a point cloud (.ply), optionally
    /// at a global step
    /// (FILE@STEP; default the scene's last step), optionally of one body's particles only
    /// (BODY=FILE: a coloured layer segmented from a camera's images). Repeat for a sequence.
    #[arg(long, required = true)]
    observed: Vec<String>,
    /// The parameters to fit, comma separated: friction_deg, youngs_modulus, poisson_ratio
    /// (MATERIAL.PARAM where several materials have it), COLLIDER.friction.
    #[arg(long, value_delimiter = ',', required = true)]
    fit: Vec<String>,
    /// Search bounds NAME=LO:HI (defaults: friction_deg 10:60, poisson_ratio 0.05:0.45,
    /// friction 0:1.5, youngs_modulus the scene's value ÷ 30 to × 30, in decades).
    #[arg(long)]
    bounds: Vec<String>,
    /// Start NAME=VALUE instead of the scene's value.
    #[arg(long)]
    start: Vec<String>,
    /// cmaes (CMA-ES on the forward loss only; the default, best with one parameter,
    /// docs/results/calibration.md), bfgs (a scan, then a bounded trust-region quasi-Newton
    /// method on the adjoint gradient; best with several, such as one per layer) or adam (Adam on
    /// the adjoint gradient).
    #[arg(long, default_value = "cmaes")]
    method: String,
    /// Compute in forward rollouts; a gradient rollout counts 1 + the backward pass's cost.
    #[arg(long, default_value_t = 40.0)]
    budget: f64,
    /// Adam's step in unit coordinates (a share of each parameter's range).
    #[arg(long, default_value_t = AdamConfig::default().lr)]
    lr: f64,
    /// The soft height's temperature (m; default a tenth of the particle spacing).
    #[arg(long)]
    tau: Option<f64>,
    /// Skip the curvature at the optimum (it costs two gradient rollouts per parameter).
    #[arg(long)]
    no_curvature: bool,
    /// Output folder (default runs/calibrate-<scene name>). A folder holding a run with the same
    /// settings is resumed.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Worker threads (default: the scene's setting; 0 = all cores).
    #[arg(long, value_parser = super::threads_arg)]
    threads: Option<usize>,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

pub fn run(a: Args) -> Result<()> {
    let mut scene = Scene::load(&a.scene)?;
    let fit = params::parse(&scene, &a.fit, &a.bounds).map_err(anyhow::Error::msg)?;
    for (p, v) in super::assignments(&scene, "--start", &a.start)? {
        if !fit.iter().any(|q| q.target == p.target) {
            bail!("--start {}: not one of the --fit parameters", p.label);
        }
        p.apply(&mut scene, v);
    }
    if let Err(e) = scene.validate() {
        bail!("--start: the scene with these values is refused: {e}");
    }
    // Every point of the search box must be a scene the loader accepts.
    for p in &fit {
        for v in [p.lo, p.hi] {
            let mut trial = scene.clone();
            p.apply(&mut trial, v);
            if let Err(e) = trial.validate() {
                bail!(
                    "--bounds {}: the bound {v} is refused ({e}); give bounds inside the admissible range",
                    p.label
                );
            }
        }
    }
    if !matches!(a.method.as_str(), "adam" | "bfgs" | "cmaes") {
        bail!("--method {}: expected cmaes, bfgs or adam", a.method);
    }
    if !(a.budget.is_finite() && a.budget >= 1.0) {
        bail!("--budget {}: expected at least 1 forward rollout", a.budget);
    }
    if let Some(t) = a.tau.filter(|t| !(t.is_finite() && *t > 0.0)) {
        bail!("--tau {t}: expected a positive length in metres");
    }
    let observed = a
        .observed
        .iter()
        .map(|o| observation::read_arg(o))
        .collect::<Result<Vec<_>, _>>()
        .map_err(anyhow::Error::msg)?;
    let mut cal = Calibration::new(&scene, fit, &observed, a.tau).map_err(anyhow::Error::msg)?;
    cal.threads = a.threads;
    for p in &cal.params {
        let v = p.value(&scene);
        if !(p.lo..=p.hi).contains(&v) {
            bail!(
                "{}: the start {v} is outside the bounds {}:{}; pass --bounds {}=LO:HI or --start",
                p.label,
                p.lo,
                p.hi,
                p.label
            );
        }
    }
    let stem = a
        .scene
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scene".into());
    let out = a
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("runs/calibrate-{stem}")));
    create_output_dir(&out, "--out")?;
    let settings = serde_json::json!({
        "scene": scene.source,
        "observed": a.observed,
        "fit": cal.params.iter().map(|p| serde_json::json!({"label": p.label, "lo": p.lo, "hi": p.hi, "log": p.log})).collect::<Vec<_>>(),
        "method": a.method,
        "budget": a.budget,
        "lr": a.lr,
        "tau": a.tau,
        "start": a.start,
    });
    let settings_path = out.join("settings.json");
    if let Ok(old) = std::fs::read_to_string(&settings_path) {
        let old: serde_json::Value = serde_json::from_str(&old).unwrap_or_default();
        if old != settings {
            bail!(
                "--out {}: holds a calibration with other settings; choose another folder or delete it",
                out.display()
            );
        }
    }
    write_atomic(
        &settings_path,
        serde_json::to_string_pretty(&settings)?.as_bytes(),
    )?;
    let mut journal = Journal::open(&out.join("rollouts.jsonl"))?;

    let u0 = cal.start();
    let curvature_cost = if a.no_curvature {
        0.0
    } else {
        let k = cal.params.len() as f64;
        1.0 + 2.0 * k * k
    };
    if !a.quiet {
        // What the fit may cost, at the start's values (a stiffer powder tried later may need
        // more substeps; the stability guard decides per rollout).
        let mut sim = powderlab::sim::Simulation::new(
            &scene,
            &powderlab::sim::SimOptions::threads(a.threads),
        )?;
        let rollout = sim.work(cal.steps);
        let all = a.budget + curvature_cost;
        let total = rollout.times(all);
        eprintln!(
            "work: a rollout {}; {all:.0} forward rollouts' worth in all (a gradient counted at its cost): {:.2e} particle-substeps, about {} at that rate",
            rollout.describe(),
            total.particle_substeps(),
            total.duration()
        );
    }
    let pb = super::bar((a.budget + curvature_cost).ceil() as u64, a.quiet);
    pb.set_message(a.method.clone());
    let mut spent = 0.0;
    let step = |e: &Eval, spent: &mut f64| {
        *spent += e.cost;
        pb.set_position(spent.round() as u64);
        pb.set_message(format!("{}: loss {:.3e}", a.method, e.loss));
    };
    let trace: Vec<Eval> = if a.method == "adam" {
        let cfg = AdamConfig {
            lr: a.lr,
            ..Default::default()
        };
        calibrate::adam(&u0, a.budget, cfg, |i, u, g| {
            let e = journal.eval(&cal, "adam", i, u, g)?;
            step(&e, &mut spent);
            Ok(e)
        })?
    } else if a.method == "bfgs" {
        let cfg = calibrate::TrustConfig::for_dims(u0.len());
        calibrate::trust_region(&u0, a.budget, cfg, 0xCA1, |i, u, g| {
            let e = journal.eval(&cal, "bfgs", i, u, g)?;
            step(&e, &mut spent);
            Ok(e)
        })?
    } else {
        calibrate::cmaes(&u0, a.budget.floor() as usize, 0xCA1, |i, u, g| {
            let e = journal.eval(&cal, "cmaes", i, u, g)?;
            step(&e, &mut spent);
            Ok(e)
        })?
    };
    let best = calibrate::lowest(&trace)
        .expect("at least one rollout")
        .clone();
    let ident = if a.no_curvature {
        None
    } else {
        pb.set_message("curvature at the optimum");
        let mut k = 0;
        Some(calibrate::identifiability(
            &cal,
            &best.u,
            calibrate::CURVATURE_STEP,
            |u| {
                let e = journal.eval(&cal, "curvature", k, u, false)?;
                k += 1;
                step(&e, &mut spent);
                Ok(e)
            },
        )?)
    };
    pb.finish_and_clear();

    let fitted = cal.scene_at(&best.u);
    let ron = ron::ser::to_string_pretty(&fitted, ron::ser::PrettyConfig::default())?;
    write_atomic(
        &out.join("fitted.ron"),
        format!(
            "// {} calibrated by `powderlab calibrate` ({}): {}\n{ron}\n",
            a.scene.display(),
            a.method,
            cal.describe(&best.values)
        )
        .as_bytes(),
    )?;
    let mut csv = String::from("rollout,compute,loss,best_loss");
    for p in &cal.params {
        csv.push_str(&format!(",{}", p.label));
    }
    csv.push('\n');
    let (mut c, mut b) = (0.0, f64::INFINITY);
    let mut curve = Vec::new();
    for (i, e) in trace.iter().enumerate() {
        c += e.cost;
        b = b.min(e.loss);
        curve.push((c, b));
        csv.push_str(&format!("{i},{c},{:e},{b:e}", e.loss));
        for v in &e.values {
            csv.push_str(&format!(",{v}"));
        }
        csv.push('\n');
    }
    write_atomic(&out.join("trace.csv"), csv.as_bytes())?;
    curves_svg(
        &out.join("loss.svg"),
        &format!("{}: best loss so far ({})", stem, a.method),
        "compute (forward rollouts)",
        "loss",
        &[Curve {
            label: a.method.clone(),
            colour: calibrate::plot::colour(&a.method),
            points: curve,
            faint: false,
        }],
    )?;
    let mut md = format!(
        "# Calibration of {}\n\nMethod {}, {} rollouts ({:.1} forward rollouts of compute), best loss {:.4e} (start {:.4e}).\n\n| parameter | start | fitted | bounds | std. error | pinned down |\n|---|---|---|---|---|---|\n",
        a.scene.display(),
        a.method,
        trace.len(),
        trace.iter().map(|e| e.cost).sum::<f64>(),
        best.loss,
        trace[0].loss
    );
    for (i, p) in cal.params.iter().enumerate() {
        let (se, pinned) = match &ident {
            Some(id) => (
                format!("{:.3e}", id.std_error[i]),
                if id.relative[i] < calibrate::PINNED_SHARE {
                    "yes"
                } else {
                    "no"
                }
                .to_string(),
            ),
            None => ("–".into(), "–".into()),
        };
        md.push_str(&format!(
            "| {} | {:.5} | {:.5} | {}:{} | {se} | {pinned} |\n",
            p.label, trace[0].values[i], best.values[i], p.lo, p.hi
        ));
    }
    if let Some(id) = &ident {
        md.push_str(&format!(
            "\nCurvature of the loss in unit coordinates (central second differences of the loss, step {}): eigenvalues {:?}.\n",
            id.step,
            id.eigenvalues.iter().map(|l| format!("{l:.3e}")).collect::<Vec<_>>()
        ));
    }
    md.push_str("\n![loss](loss.svg)\n");
    write_atomic(&out.join("report.md"), md.as_bytes())?;
    write_atomic(
        &out.join("summary.json"),
        serde_json::to_string_pretty(&serde_json::json!({
            "best": best,
            "identifiability": ident,
            "rollouts": trace.len(),
            "replayed": journal.replayed,
        }))?
        .as_bytes(),
    )?;
    #[cfg(feature = "rerun")]
    record(&out.join("calibration.rrd"), &fitted, &cal, &observed)?;

    println!(
        "calibrated {} by {} in {} rollouts:",
        a.scene.display(),
        a.method,
        trace.len()
    );
    for (i, p) in cal.params.iter().enumerate() {
        let se = ident
            .as_ref()
            .map(|id| format!(" ± {:.3e}", id.std_error[i]))
            .unwrap_or_default();
        println!(
            "  {} = {:.5}{se} (start {:.5})",
            p.label, best.values[i], trace[0].values[i]
        );
    }
    println!(
        "  loss {:.4e} (start {:.4e}); outputs in {}",
        best.loss,
        trace[0].loss,
        out.display()
    );
    Ok(())
}

/// The fitted run, with each observation as static points beside it.
#[cfg(feature = "rerun")]
fn record(
    path: &std::path::Path,
    fitted: &Scene,
    cal: &Calibration,
    observed: &[observation::Observed],
) -> Result<()> {
    use glam::DVec3;
    use powderlab::sim::{SimOptions, Simulation};
    let mut sim = Simulation::new(fitted, &SimOptions::threads(cal.threads))?;
    let mut rec = powderlab::record::Recorder::for_scene(path, &mut sim.world, fitted)?;
    for (k, o) in observed.iter().enumerate() {
        let pts: Vec<DVec3> = match &o.what {
            Observation::Cloud(p) => p.clone(),
            Observation::Heights { grid, heights } => (0..grid.len())
                .filter(|&c| heights[c].is_finite())
                .map(|c| {
                    DVec3::new(
                        grid.origin[0] + (c % grid.nx) as f64 * grid.pixel,
                        heights[c],
                        grid.origin[1] + (c / grid.nx) as f64 * grid.pixel,
                    )
                })
                .collect(),
        };
        rec.static_points(&format!("world/observed/{k}"), &pts, [230, 80, 60, 255])?;
    }
    rec.frame(&mut sim.world)?;
    for _ in 0..cal.steps {
        sim.step()?;
        rec.frame(&mut sim.world)?;
    }
    rec.finish()
}

/// Simulate a scene and write what a camera would see at a step: a height map (.csv) or a point
/// cloud (.ply), with optional noise; for tests, studies and tutorials of `calibrate`.
#[derive(clap::Args)]
pub struct ObserveArgs {
    scene: PathBuf,
    /// The observation file: .csv or .png (a height map; the PNG 16-bit at 10 µm per unit) or
    /// .ply (a point cloud).
    #[arg(long)]
    out: PathBuf,
    /// Parameter values for the run, NAME=VALUE (names as in calibrate --fit).
    #[arg(long)]
    set: Vec<String>,
    /// The global step observed (default the scene's last).
    #[arg(long)]
    step: Option<usize>,
    /// Only this body's particles (a .ply: a coloured layer segmented from a side camera's
    /// images); calibrate reads the file as BODY=FILE.
    #[arg(long)]
    body: Option<String>,
    /// Pixel size of a height map (m; default the particle spacing, about the millimetre a
    /// depth camera above a bench resolves).
    #[arg(long)]
    pixel: Option<f64>,
    /// Standard deviation of Gaussian noise on each height or coordinate (m).
    #[arg(long, default_value_t = 0.0)]
    noise: f64,
    /// Seed of the noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Worker threads (default: the scene's setting; 0 = all cores).
    #[arg(long, value_parser = super::threads_arg)]
    threads: Option<usize>,
}

pub fn observe(a: ObserveArgs) -> Result<()> {
    let scene = super::load_with_sets(&a.scene, &a.set)?;
    let ext = a.out.extension().and_then(|e| e.to_str()).unwrap_or("");
    let heights = match ext {
        "csv" | "png" => true,
        "ply" => false,
        _ => bail!(
            "--out {}: expected a .csv or .png (height map) or .ply (point cloud) file name",
            a.out.display()
        ),
    };
    powderlab::util::check_output_file(&a.out, "--out")?;
    let pixel = a.pixel.unwrap_or_else(|| {
        scene
            .bodies
            .iter()
            .map(|b| scene.particle_spacing(b))
            .fold(scene.simulation.dx, f64::min)
    });
    if !(pixel.is_finite() && pixel > 0.0) {
        bail!("--pixel {pixel}: expected a positive length in metres");
    }
    if !(a.noise.is_finite() && a.noise >= 0.0) {
        bail!(
            "--noise {}: expected a standard deviation ≥ 0 in metres",
            a.noise
        );
    }
    let step = match a.step.or(scene.simulation.steps) {
        Some(s) => s,
        None => bail!("--step: the scene sets no steps; say which global step to observe"),
    };
    let o = match &a.body {
        None => calibrate::observe(&scene, step, heights, pixel, a.noise, a.seed, a.threads)?,
        Some(name) => {
            let names: Vec<&str> = scene.bodies.iter().map(|b| b.name.as_str()).collect();
            let Some(b) = names.iter().position(|n| n == name) else {
                bail!("--body {name}: the scene has no such body (it has {names:?})");
            };
            if heights {
                bail!(
                    "--body {name}: one body's particles are written as a point cloud; name a .ply --out"
                );
            }
            calibrate::observe_bodies(&scene, step, a.noise, a.seed, a.threads)?.swap_remove(b)
        }
    };
    let bytes = match &o {
        Observation::Heights { grid, heights } if ext == "png" => {
            // 10 µm per unit spans 0.65 m; the lowest height of the domain reads 1, not 0
            // (unseen).
            let scale = 1e-5;
            observation::heights_png(grid, heights, scene.domain().0.y - scale, scale)
        }
        Observation::Heights { grid, heights } => {
            observation::heights_csv(grid, heights).into_bytes()
        }
        Observation::Cloud(p) => observation::cloud_ply(p),
    };
    write_atomic(&a.out, &bytes)?;
    println!(
        "wrote the {} at step {step} to {}",
        o.kind(),
        a.out.display()
    );
    Ok(())
}
