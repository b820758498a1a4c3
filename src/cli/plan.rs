//! `powderlab plan SCENE`: a sequence of scoops to a dose larger than one spoonful, or of
//! spatula strokes that push or pull powder into a region, planned by A* over optimised actions
//! (or the greedy and scripted baselines), from the scene's `plan` section.

use anyhow::Result;
use powderlab::lab::plan::dosing::{dosing_plan, Dosing, Method};
use powderlab::lab::plan::output::plan_into;
use powderlab::lab::plan::push::Push;
use powderlab::scene::plan::PlanSpec;
use powderlab::scene::Scene;
use std::path::PathBuf;

/// Plan a multi-scoop dose or a push: writes plan-METHOD.json (every scoop's entry point and Θ
/// or every stroke, the outcome, rollouts and wall time), plan-METHOD.rrd (the actions one
/// after another) and a journal that a rerun after a kill replays.
#[derive(clap::Args)]
pub struct Args {
    /// A scene with a `plan` section (scenes/multi_scoop_dosing.ron).
    scene: PathBuf,
    /// astar (seed B's Algorithm 1), greedy (one optimised scoop after another) or scripted
    /// (the scene's Θ repeated); comma separated for several.
    #[arg(long, value_delimiter = ',', default_value = "astar")]
    method: Vec<String>,
    /// Output folder (default runs/<scene>/plan).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Seeds the optimiser's samples and the search's random relocations.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Skip the recording (it simulates every scoop of the plan once more).
    #[arg(long)]
    no_rrd: bool,
    /// Print the result as one JSON object per method.
    #[arg(long)]
    json: bool,
}

pub fn run(a: Args) -> Result<()> {
    let scene = Scene::load(&a.scene)?;
    if let Some(PlanSpec::Push(p)) = &scene.plan {
        return push(a, scene.clone(), p.clone());
    }
    let plan = dosing_plan(&scene)?;
    let (methods, out) = methods_and_out(&a)?;
    for method in methods {
        let bound = match method {
            Method::Astar => plan.max_expansions * plan.scoop_budget,
            Method::Greedy => plan.max_scoops * plan.scoop_budget,
            Method::Scripted => plan.max_scoops,
        };
        eprintln!(
            "{}: {} with {} rollouts per scoop, at most {bound} rollouts",
            a.scene.display(),
            method.name(),
            plan.scoop_budget
        );
        let pb = super::bar(bound as u64, a.json);
        let r = plan_into::<Dosing>(&out, scene.clone(), method, a.seed, !a.no_rrd, follow(&pb))?;
        pb.finish_and_clear();
        if a.json {
            println!("{}", serde_json::to_string(&r)?);
            continue;
        }
        println!(
            "{}: {} in {} scoops, {:.3} g of {:.3} g (error {:.3} g, tolerance {}); {} rollouts ({} replayed), {:.1} s",
            method.name(),
            if r.success { "success" } else { "failure" },
            r.scoops.len(),
            r.delivered_g,
            r.target_g,
            r.dose_error_g,
            r.tolerance_g,
            r.rollouts,
            r.replayed,
            r.wall_s
        );
        for (i, s) in r.scoops.iter().enumerate() {
            println!(
                "  scoop {}: entry ({:.4}, {:.4}) m, surface {:.4} m, Θ [{}], +{:.3} g → {:.3} g, {:.3} g discarded",
                i + 1,
                s.entry[0],
                s.entry[1],
                s.surface,
                s.theta.iter().map(|t| format!("{t:.3}")).collect::<Vec<_>>().join(", "),
                s.added_g,
                s.delivered_g,
                s.discarded_g
            );
        }
    }
    eprintln!("wrote {}", out.display());
    Ok(())
}

/// The methods asked for, and the output folder.
fn methods_and_out(a: &Args) -> Result<(Vec<Method>, PathBuf)> {
    let methods = a
        .method
        .iter()
        .map(|m| {
            Method::parse(m)
                .ok_or_else(|| anyhow::anyhow!("--method {m}: expected astar, greedy or scripted"))
        })
        .collect::<Result<Vec<_>>>()?;
    let out = a.out.clone().unwrap_or_else(|| {
        let stem = a.scene.file_stem().unwrap_or_default().to_string_lossy();
        PathBuf::from("runs").join(stem.as_ref()).join("plan")
    });
    Ok((methods, out))
}

/// `plan` for a push plan.
fn push(a: Args, scene: Scene, plan: powderlab::scene::plan::PushPlan) -> Result<()> {
    let (methods, out) = methods_and_out(&a)?;
    for method in methods {
        let bound = match method {
            Method::Astar => plan.max_expansions * plan.stroke_budget,
            Method::Greedy => plan.max_strokes * plan.stroke_budget,
            Method::Scripted => plan.max_strokes,
        };
        eprintln!(
            "{}: {} ({}) with {} rollouts per stroke, at most {bound} rollouts",
            a.scene.display(),
            method.name(),
            plan.class.name(),
            plan.stroke_budget
        );
        let pb = super::bar(bound as u64, a.json);
        let r = plan_into::<Push>(&out, scene.clone(), method, a.seed, !a.no_rrd, follow(&pb))?;
        pb.finish_and_clear();
        if a.json {
            println!("{}", serde_json::to_string(&r)?);
            continue;
        }
        println!(
            "{}: {} in {} strokes, {:.1} % of the powder in the region (success from {:.0} %); {} rollouts ({} replayed), {:.1} s",
            method.name(),
            if r.success { "success" } else { "failure" },
            r.strokes.len(),
            100.0 * r.in_region,
            100.0 * r.success_fraction,
            r.rollouts,
            r.replayed,
            r.wall_s
        );
        for (i, d) in r.strokes.iter().enumerate() {
            let s = &d.stroke;
            println!(
                "  stroke {}: lands at ({:.4}, {:.4}, {:.4}) m, yaw {:.1}°, {:.3} m long → {:.1} % in",
                i + 1,
                d.landing[0],
                d.landing[1],
                d.landing[2],
                s.yaw_deg,
                s.length,
                100.0 * d.in_region
            );
        }
    }
    eprintln!("wrote {}", out.display());
    Ok(())
}

/// A plan's progress shown on `pb`: the rollouts so far and the last rollout's outcome.
fn follow(pb: &indicatif::ProgressBar) -> powderlab::lab::plan::journal::Progress {
    let bar = pb.clone();
    Box::new(move |n, msg| {
        bar.set_position(n as u64);
        bar.set_message(msg.to_string());
    })
}
