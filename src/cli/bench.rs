//! `powderlab bench`: throughput in particle-substeps per second, wall time, peak memory and
//! per-stage times, of the forward pass or of forward + backward.

use anyhow::Result;
use powderlab::components::Grid;
use powderlab::sim::{SimOptions, Simulation};
use powderlab::util::peak_rss_bytes;
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

/// Measure throughput (particle-substeps per second), wall time, peak memory and stages.
#[derive(clap::Args)]
pub struct Args {
    scene: PathBuf,
    /// Global steps to time (default: the scene's horizon).
    #[arg(long)]
    steps: Option<usize>,
    #[arg(long, value_parser = super::threads_arg)]
    threads: Option<usize>,
    /// Time each stage separately (adds a little overhead).
    #[arg(long)]
    stages: bool,
    /// Time forward + backward (the gradient of the scene's loss) instead of the forward.
    #[arg(long)]
    backward: bool,
    /// Memory budget of the backward tape in MB.
    #[arg(long, default_value_t = 4096)]
    budget_mb: usize,
    /// Sweep every grid node in every stage instead of the active spans (the reference the
    /// active-block grid is measured against; the results are the same bits).
    #[arg(long)]
    dense_grid: bool,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

/// Runs the command.
pub fn run(a: Args) -> Result<()> {
    if a.backward {
        backward(
            a.scene,
            a.steps,
            a.threads,
            a.budget_mb,
            a.dense_grid,
            a.json,
        )
    } else {
        forward(a.scene, a.steps, a.threads, a.stages, a.dense_grid, a.json)
    }
}

fn backward(
    scene: PathBuf,
    steps: Option<usize>,
    threads: Option<usize>,
    budget_mb: usize,
    dense_grid: bool,
    json_out: bool,
) -> Result<()> {
    let sc = powderlab::scene::Scene::load(&scene)?;
    let mut sim = Simulation::new(&sc, &SimOptions::threads(threads))?;
    sim.world.resource_mut::<Grid>().sparse = !dense_grid;
    let steps = steps.unwrap_or(sim.horizon);
    let n = sim.particle_count();
    let loss = powderlab::adjoint::loss::scene_loss(&sc);
    let start = Instant::now();
    let g = powderlab::adjoint::tape::gradient(
        &mut sim,
        steps,
        &loss,
        powderlab::adjoint::tape::Tape::Budget(budget_mb << 20),
    )?;
    let wall = start.elapsed().as_secs_f64();
    let substeps = steps * sim.params().substeps;
    let rate = n as f64 * substeps as f64 / wall;
    let peak = peak_rss_bytes();
    let dt = sc.simulation.dt;
    let tool_v: Vec<serde_json::Value> = g
        .controls
        .iter()
        .map(|(name, u)| {
            let s: [f64; 3] = std::array::from_fn(|k| u.iter().map(|u| u[k] * dt).sum());
            json!({ "tool": name, "dloss_dvelocity": s })
        })
        .collect();
    let gv0: glam::DVec3 = g.v0.iter().flatten().copied().sum();
    if json_out {
        let more = json!({
            "particle_substeps_per_s_forward_backward": rate,
            "tape_bytes": g.tape_bytes,
            "checkpoint_every": g.checkpoint_every,
            "loss": g.loss,
            "grad_tool_velocity": tool_v,
            "grad_v0_sum": [gv0.x, gv0.y, gv0.z],
            "timing_s": g.timing.iter().map(|(k, v)| (k.clone(), json!(v))).collect::<serde_json::Map<_, _>>(),
        });
        println!("{}", run_json(&scene, &sim, n, steps, wall, peak, more));
    } else {
        println!("scene            {}", scene.display());
        println!("particles        {n}, {substeps} substeps ({steps} steps)");
        println!("loss             {:.9e}", g.loss);
        println!(
            "forward+backward {wall:.3} s ({:.3} M particle-substeps/s)",
            rate / 1e6
        );
        println!(
            "tape             {:.1} MB (checkpoint every {} steps); peak RSS {:.1} MB",
            g.tape_bytes as f64 / 1e6,
            g.checkpoint_every,
            peak as f64 / 1e6
        );
        for t in &tool_v {
            println!("dL/d tool velocity {t}");
        }
        println!(
            "sum of dL/dv0    ({:.6e}, {:.6e}, {:.6e})",
            gv0.x, gv0.y, gv0.z
        );
        let total: f64 = g.timing.iter().map(|e| e.1).sum();
        for (k, v) in &g.timing {
            println!("  {k:<34} {v:>8.3} s  {:>5.1} %", 100.0 * v / total);
        }
    }
    Ok(())
}

fn forward(
    scene: PathBuf,
    steps: Option<usize>,
    threads: Option<usize>,
    stages: bool,
    dense_grid: bool,
    json_out: bool,
) -> Result<()> {
    let mut sim = Simulation::from_file(
        &scene,
        &SimOptions {
            threads,
            stage_timers: stages,
            ..Default::default()
        },
    )?;
    if !json_out {
        super::describe_stability(&sim);
    }
    sim.world.resource_mut::<Grid>().sparse = !dense_grid;
    let steps = steps.unwrap_or(sim.horizon);
    let n = sim.particle_count();
    let start = Instant::now();
    let pb = super::bar(steps as u64, json_out);
    for _ in 0..steps {
        sim.step()?;
        pb.inc(1);
    }
    pb.finish_and_clear();
    let wall = start.elapsed().as_secs_f64();
    let substeps = sim.clock().total_substeps;
    let rate = n as f64 * substeps as f64 / wall;
    let stage_s = sim.stage_seconds();
    let peak = peak_rss_bytes();
    let states = sim.body_states();
    let mean_pos = {
        let all: Vec<_> = states.iter().flat_map(|b| b.x.iter().copied()).collect();
        all.iter().copied().sum::<glam::DVec3>() / all.len().max(1) as f64
    };
    let fingerprint = powderlab::components::state_fingerprint(&states);
    if json_out {
        let stages_obj: serde_json::Map<String, serde_json::Value> = stage_s
            .iter()
            .map(|(k, v)| (format!("{k}_s"), json!(v)))
            .collect();
        let more = json!({
            "particle_substeps_per_s": rate,
            "final_mean_position_m": [mean_pos.x, mean_pos.y, mean_pos.z],
            "state_fingerprint": format!("{fingerprint:016x}"),
            "stages": stages_obj,
        });
        println!("{}", run_json(&scene, &sim, n, steps, wall, peak, more));
    } else {
        println!("scene            {}", scene.display());
        println!("particles        {n}");
        println!(
            "substeps         {substeps} ({steps} steps, {} threads)",
            sim.threads()
        );
        println!("wall time        {wall:.3} s");
        println!("throughput       {:.3} M particle-substeps/s", rate / 1e6);
        println!("peak RSS         {:.1} MB", peak as f64 / 1e6);
        println!(
            "final mean x     ({:.6}, {:.6}, {:.6}) m",
            mean_pos.x, mean_pos.y, mean_pos.z
        );
        println!("state bits       {fingerprint:016x}");
        if !stage_s.is_empty() {
            let total: f64 = stage_s.iter().map(|s| s.1).sum();
            for (k, v) in &stage_s {
                println!("  {k:<20} {v:>8.3} s  {:>5.1} %", 100.0 * v / total);
            }
        }
    }
    Ok(())
}

/// A run's JSON report: the fields every run has (scene, its `n` particles, steps, substeps,
/// threads, wall time, peak RSS) and the object `more`'s.
fn run_json(
    scene: &std::path::Path,
    sim: &Simulation,
    n: usize,
    steps: usize,
    wall: f64,
    peak: u64,
    more: serde_json::Value,
) -> serde_json::Value {
    let mut v = json!({
        "scene": scene.display().to_string(),
        "particles": n,
        "steps": steps,
        "substeps_total": steps * sim.params().substeps,
        "threads": sim.threads(),
        "wall_s": wall,
        "peak_rss_bytes": peak,
    });
    if let (Some(o), serde_json::Value::Object(m)) = (v.as_object_mut(), more) {
        o.extend(m);
    }
    v
}
