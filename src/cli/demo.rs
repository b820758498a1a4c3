//! `powderlab demo make|fit`: synthetic demonstrations, and the skill fitted to one.

use anyhow::{bail, Context, Result};
use powderlab::lab::demo::{self, fit::FitOptions, make::MakeOptions};
use powderlab::lab::render::{self, camera, Camera};
use powderlab::scene::Scene;
use powderlab::sim::{SimOptions, Simulation};
use powderlab::skills::Theta;
use serde_json::json;
use std::path::PathBuf;

/// Learning the skill from a demonstration: `make` films a synthetic one, `fit` tracks the
/// spoon in one and fits Θ to its path.
#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    what: What,
}

#[derive(clap::Subcommand)]
enum What {
    /// Film a synthetic demonstration of the scene's skill at Θ*: a hand with its own pace
    /// and a tremor; frames, masks, demo.json and truth.json in --out.
    Make(MakeArgs),
    /// Track the spoon in a demonstration folder and fit Θ to its path; writes fit.json.
    Fit(FitArgs),
}

#[derive(clap::Args)]
struct MakeArgs {
    scene: PathBuf,
    /// Θ* (five values in [-1, 1]).
    #[arg(
        long,
        value_delimiter = ',',
        required = true,
        allow_hyphen_values = true
    )]
    theta: Vec<f64>,
    /// Camera file (JSON); default: two cameras framing the scene, from the front and the side.
    #[arg(long)]
    cameras: Option<PathBuf>,
    /// Image size of the default cameras, WIDTHxHEIGHT.
    #[arg(long, default_value = "96x72", value_parser = super::render::size_arg)]
    size: (u32, u32),
    /// A frame every this many global steps.
    #[arg(long, default_value_t = 4)]
    every: usize,
    /// The hand's tremor (m).
    #[arg(long, default_value_t = 0.0003)]
    tremor: f64,
    /// The warp of the hand's pace, in [0, 1).
    #[arg(long, default_value_t = 0.3)]
    warp: f64,
    /// Gaussian pixel noise on the images (σ, fraction of full scale).
    #[arg(long, default_value_t = 0.02)]
    noise: f64,
    /// Leave the masks out (the fit then segments the spoon by its colour).
    #[arg(long)]
    no_masks: bool,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// The demonstrator's spoon, when not the scene's: BOWL_RADIUS,BOWL_DEPTH,HANDLE_LENGTH (m;
    /// its thickness and handle radius and rise are the scene's).
    #[arg(long, value_delimiter = ',')]
    spoon: Vec<f64>,
    #[arg(long, default_value = "demo")]
    out: PathBuf,
}

#[derive(clap::Args)]
struct FitArgs {
    /// The demonstration folder (demo.json and its frames).
    demo: PathBuf,
    /// The scene whose spoon and skill the demonstration shows.
    #[arg(long)]
    scene: PathBuf,
    /// Where to write the fit (default: DEMO/fit.json).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Take the demonstrator's spoon to be the scene's instead of fitting its shape.
    #[arg(long)]
    keep_shape: bool,
    /// Where to write the Rerun recording of the track over the frames (default: the fit's
    /// path with .rrd).
    #[arg(long)]
    rrd: Option<PathBuf>,
}

/// Runs the command.
pub fn run(a: Args) -> Result<()> {
    match a.what {
        What::Make(m) => make(m),
        What::Fit(f) => fit(f),
    }
}

fn make(a: MakeArgs) -> Result<()> {
    if a.every == 0 {
        bail!("--every 0: expected a positive number of steps between frames");
    }
    if !(0.0..1.0).contains(&a.warp) {
        bail!(
            "--warp {}: expected a value in [0, 1) (0 keeps the skill's pace)",
            a.warp
        );
    }
    for (flag, v) in [("--tremor", a.tremor), ("--noise", a.noise)] {
        if !(v.is_finite() && v >= 0.0) {
            bail!("{flag} {v}: expected a non-negative number");
        }
    }
    let Ok(theta) = <[f64; 5]>::try_from(a.theta.as_slice()).map(Theta) else {
        bail!(
            "--theta {:?}: expected five values in [-1, 1], such as 0.4,-0.3,0.5,-0.6,0.2",
            a.theta
        );
    };
    let scene = Scene::load(&a.scene)?;
    let spoon = match a.spoon.as_slice() {
        [] => None,
        &[r, d, l] => {
            let base = powderlab::rollout::skill_tool(&scene)
                .ok()
                .and_then(|i| scene.colliders[i].shape.spoon());
            let Some(base) = base else {
                bail!("--spoon: {} has no spoon with a skill to replace", a.scene.display());
            };
            let s = powderlab::lab::render::silhouette::reshaped(
                &base,
                [r - base.bowl_radius, d - base.bowl_depth, l - base.handle_length],
            );
            if let Err(e) = s.validate() {
                bail!("--spoon {r},{d},{l}: {} = {} is not {}", e.field, e.value, e.expected);
            }
            Some(s)
        }
        v => bail!("--spoon {v:?}: expected BOWL_RADIUS,BOWL_DEPTH,HANDLE_LENGTH in metres, such as 0.016,0.008,0.045"),
    };
    let cameras: Vec<Camera> = match &a.cameras {
        Some(p) => camera::load(p).map_err(anyhow::Error::msg)?,
        None => {
            let mut sim = Simulation::new(&scene, &SimOptions::default())?;
            let (lo, hi) = render::scene_box(&mut sim);
            vec![
                Camera::framing_at("front", lo, hi, a.size.0, a.size.1, 20.0),
                Camera::framing_at("side", lo, hi, a.size.0, a.size.1, 100.0),
            ]
        }
    };
    powderlab::util::create_output_dir(&a.out, "--out")?;
    let opts = MakeOptions {
        theta,
        cameras,
        every: a.every,
        tremor: a.tremor,
        warp: a.warp,
        noise: a.noise,
        masks: !a.no_masks,
        seed: a.seed,
        spoon,
    };
    let pb = super::bar(0, false);
    let truth = demo::make::make(&scene, &opts, &a.out, |k, n| {
        pb.set_length(n as u64);
        pb.set_position(k as u64);
    })?;
    pb.finish_and_clear();
    eprintln!(
        "{} frames from {} camera(s) in {}",
        truth.poses.len(),
        opts.cameras.len(),
        a.out.display()
    );
    Ok(())
}

fn fit(a: FitArgs) -> Result<()> {
    let scene = Scene::load(&a.scene)?;
    let d = demo::format::load(&a.demo).map_err(anyhow::Error::msg)?;
    let opts = FitOptions {
        fit_shape: !a.keep_shape,
        ..FitOptions::default()
    };
    let pb = super::bar(0, false);
    let r = demo::fit::fit(&d, &scene, &opts, |k, n| {
        pb.set_length(n as u64);
        pb.set_position(k as u64)
    })?;
    pb.finish_and_clear();
    let mut out = json!({
        "theta": r.theta,
        "path_loss_m2": r.path_loss,
        "spoon": {"bowl_radius": r.track.spoon.bowl_radius, "bowl_depth": r.track.spoon.bowl_depth, "handle_length": r.track.spoon.handle_length},
        "silhouette_loss_tracked_then_joint": r.track.rounds,
        "frames": d.frames.iter().zip(&r.track.poses).zip(&r.track.silhouette_loss).map(|(((k, _), p), l)| json!({
            "index": k,
            "translation": p.translation.to_array(),
            "rotation": p.rotation.to_array(),
            "silhouette_loss": l,
        })).collect::<Vec<_>>(),
    });
    println!(
        "Θ_demo = {:?} (path loss {:.3e} m²); spoon: bowl radius {:.2} mm, bowl depth {:.2} mm, handle {:.1} mm",
        r.theta.map(|t| (t * 1e4).round() / 1e4),
        r.path_loss,
        1e3 * r.track.spoon.bowl_radius,
        1e3 * r.track.spoon.bowl_depth,
        1e3 * r.track.spoon.handle_length
    );
    // A synthetic demonstration carries its truth: score against it.
    let truth_path = a.demo.join("truth.json");
    if truth_path.exists() {
        let t: demo::make::Truth = serde_json::from_str(
            &std::fs::read_to_string(&truth_path)
                .with_context(|| truth_path.display().to_string())?,
        )
        .with_context(|| format!("{}: not a truth file", truth_path.display()))?;
        let scene_spoon = scene.colliders[powderlab::rollout::skill_tool(&scene)?]
            .shape
            .spoon()
            .expect("demo fit tracked the skill's spoon");
        let s = demo::fit::score(&r, &t, &scene_spoon);
        println!(
            "against {}: pose error median {:.2} mm / {:.2}°, 95th percentile {:.2} mm / {:.2}°; Θ error mean {:.4}, largest {:.4}; shape error {:.1} %, {:.1} %, {:.1} %",
            truth_path.display(), s.pose_mm[0], s.pose_deg[0], s.pose_mm[1], s.pose_deg[1], s.theta_mean, s.theta_max,
            s.shape_pct[0], s.shape_pct[1], s.shape_pct[2]
        );
        out["score"] = serde_json::to_value(&s)?;
    }
    let path = a.out.unwrap_or_else(|| a.demo.join("fit.json"));
    powderlab::util::write_atomic(&path, serde_json::to_string_pretty(&out)?.as_bytes())
        .with_context(|| format!("{}: cannot write the fit", path.display()))?;
    eprintln!("fit: {}", path.display());
    #[cfg(feature = "rerun")]
    {
        let rrd = a.rrd.unwrap_or_else(|| path.with_extension("rrd"));
        demo::overlay::write(&rrd, &d, &r.track)
            .with_context(|| format!("{}: cannot write the recording", rrd.display()))?;
        eprintln!("recording: {}", rrd.display());
    }
    Ok(())
}
