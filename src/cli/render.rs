//! `powderlab render`: PNG frames of a run from one or more pinhole cameras.

use anyhow::{bail, Context, Result};
use powderlab::lab::render::{self, camera, Camera};
use powderlab::scene::Scene;
use powderlab::sim::{SimOptions, Simulation};
use std::path::PathBuf;

/// Render PNG frames of a run: powder as shaded splats, tools and cups ray-marched from their
/// SDFs; DIR/CAMERA_STEP.png.
#[derive(clap::Args)]
pub struct Args {
    scene: PathBuf,
    /// Camera file (JSON, see `src/lab/render/camera.rs`); default: one camera framing the scene
    /// from the front and above.
    #[arg(long)]
    cameras: Option<PathBuf>,
    /// Image size of the default camera, WIDTHxHEIGHT.
    #[arg(long, default_value = "640x480", value_parser = size_arg)]
    size: (u32, u32),
    /// Render every this many global steps (and the last one).
    #[arg(long, default_value_t = 5)]
    every: usize,
    /// Render only these steps (comma separated) instead of every `--every`.
    #[arg(long, value_delimiter = ',')]
    at: Vec<usize>,
    /// Global steps to run (default: the scene's horizon).
    #[arg(long)]
    steps: Option<usize>,
    /// Output folder.
    #[arg(long, default_value = "render")]
    out: PathBuf,
    #[arg(long, value_parser = super::threads_arg)]
    threads: Option<usize>,
}

pub fn size_arg(s: &str) -> Result<(u32, u32), String> {
    let parsed = s
        .split_once('x')
        .and_then(|(w, h)| Some((w.parse::<u32>().ok()?, h.parse::<u32>().ok()?)));
    match parsed {
        Some((w, h))
            if (1..=camera::MAX_SIDE).contains(&w) && (1..=camera::MAX_SIDE).contains(&h) =>
        {
            Ok((w, h))
        }
        _ => Err(format!(
            "expected WIDTHxHEIGHT with each from 1 to {}, such as 640x480; got '{s}'",
            camera::MAX_SIDE
        )),
    }
}

/// Runs the command.
pub fn run(a: Args) -> Result<()> {
    if a.every == 0 {
        bail!("--every 0: expected a positive number of steps between frames");
    }
    let scene = Scene::load(&a.scene)?;
    let mut cams: Vec<Camera> = match &a.cameras {
        Some(p) => camera::load(p).map_err(anyhow::Error::msg)?,
        None => Vec::new(),
    };
    let mut sim = Simulation::new(&scene, &SimOptions::threads(a.threads))?;
    if cams.is_empty() {
        cams.push(render::default_camera(&mut sim, a.size.0, a.size.1));
    }
    let steps = a.steps.unwrap_or(sim.horizon);
    if let Some(&s) = a.at.iter().find(|&&s| s > steps) {
        bail!("--at {s}: the run has {steps} steps; give steps from 0 to {steps}");
    }
    powderlab::util::create_output_dir(&a.out, "--out")?;
    let wanted = |k: usize| {
        if a.at.is_empty() {
            k.is_multiple_of(a.every) || k == steps
        } else {
            a.at.contains(&k)
        }
    };
    let pb = super::bar(steps as u64, false);
    let mut written = 0;
    for k in 0..=steps {
        if k > 0 {
            sim.step().with_context(|| format!("step {k}"))?;
            pb.inc(1);
        }
        if wanted(k) {
            for (name, png) in render::frames(&mut sim, &cams) {
                let path = a.out.join(format!("{name}_{k:05}.png"));
                powderlab::util::write_atomic(&path, &png)
                    .with_context(|| format!("{}: cannot write the frame", path.display()))?;
                written += 1;
            }
        }
    }
    pb.finish_and_clear();
    eprintln!(
        "{written} frames from {} camera(s) in {}",
        cams.len(),
        a.out.display()
    );
    Ok(())
}
