//! The task studies of `powderlab study`: demonstrations, planning, the policy, the pour,
//! calibration and the reliability of scene loading.

use super::{args, print_page};
use anyhow::{bail, Context, Result};
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

/// `powderlab study demonstration`: five synthetic demonstrations filmed and fitted back, and
/// an expert's demonstration as the warm start of an optimisation.
pub(super) fn demonstration_cmd(a: args::Demonstration) -> Result<()> {
    use powderlab::lab::study::demonstration::{self, Setup};
    let scene_path = "scenes/powder_transport.ron";
    let scene = powderlab::scene::Scene::load(scene_path)?;
    let setup = Setup {
        size: (160, 120),
        every: 4,
        noise: 0.02,
    };
    let pb = super::super::bar(demonstration::THETAS.len() as u64, a.common.json);
    let pb2 = pb.clone();
    let start = Instant::now();
    let rows = demonstration::run(
        &scene,
        &a.common.out.join("demonstration"),
        &setup,
        &move |k| pb2.set_position(k as u64),
    )?;
    pb.finish_and_clear();
    if !a.common.json {
        eprintln!(
            "the warm start: an expert's demonstration, then CMA-ES from it and from random starts"
        );
    }
    let warm = powderlab::lab::study::warm_start::run(
        &scene,
        &a.common.out.join("demonstration/warm_start"),
        &setup,
    )?;
    let machine = powderlab::lab::study::optimizers::machine();
    let md = demonstration::report(
        &rows,
        scene_path,
        &setup,
        "powderlab study demonstration",
        &machine,
    ) + &powderlab::lab::study::warm_start::report(&warm);
    powderlab::util::create_output_dir(&a.page.results, "--results")?;
    powderlab::util::write_atomic(&a.page.results.join("demonstration.md"), md.as_bytes())?;
    print_page(
        a.common.json,
        &a.page.results,
        &md,
        start,
        "demonstration.md",
        json!({ "rows": rows.len() }),
    );
    Ok(())
}

/// `powderlab study planning`: multi-scoop dosing and the four push/pull classes over
/// randomised instances, A* against greedy and scripted (`--seeds` instances of each, 10 by
/// default).
pub(super) fn planning_cmd(a: args::Planning) -> Result<()> {
    use powderlab::lab::plan::dosing::Method;
    use powderlab::lab::study::planning;
    // The two tasks' scenes, or those `--tasks` names (a push plan or a dosing plan each).
    let tasks = if a.tasks.is_empty() {
        vec![
            PathBuf::from("scenes/multi_scoop_dosing.ron"),
            PathBuf::from("scenes/plate_push.ron"),
        ]
    } else {
        a.tasks.clone()
    };
    let (mut dosing, mut push) = (None, None);
    for t in &tasks {
        let s = powderlab::scene::Scene::load(t)?;
        match &s.plan {
            Some(powderlab::scene::plan::PlanSpec::Dosing(_)) => dosing = Some(s),
            Some(powderlab::scene::plan::PlanSpec::Push(_)) => push = Some(s),
            None => bail!("--tasks {}: the scene has no `plan` section", t.display()),
        }
    }
    let methods: Vec<Method> = if a.method == ["all"] {
        vec![Method::Astar, Method::Greedy, Method::Scripted]
    } else {
        a.method
            .iter()
            .map(|m| {
                Method::parse(m).ok_or_else(|| {
                    anyhow::anyhow!("--method {m}: expected astar, greedy, scripted or all")
                })
            })
            .collect::<Result<_>>()?
    };
    let instances = dosing
        .as_ref()
        .map_or(Vec::new(), |_| planning::instances(a.seeds, 2026));
    let pushes = push.as_ref().map_or(Vec::new(), |_| {
        powderlab::lab::study::push::push_instances(a.seeds, 2027)
    });
    let pb = super::super::bar(
        ((instances.len() + pushes.len()) * methods.len()) as u64,
        a.common.json,
    );
    let pb2 = pb.clone();
    let start = Instant::now();
    let rows = match &dosing {
        Some(scene) => planning::run(
            scene,
            &a.common.out.join("planning"),
            &instances,
            &methods,
            &|k, m| {
                pb2.inc(1);
                pb2.set_message(format!("dosing instance {k}: {}", m.name()));
            },
        )?,
        None => Vec::new(),
    };
    let push_rows = match &push {
        Some(scene) => powderlab::lab::study::push::run_push(
            scene,
            &a.common.out.join("planning/push"),
            &pushes,
            &methods,
            &|k, m| {
                pb2.inc(1);
                pb2.set_message(format!("push instance {k}: {}", m.name()));
            },
        )?,
        None => Vec::new(),
    };
    pb.finish_and_clear();
    let command = format!(
        "powderlab study planning --seeds {} --out {}",
        a.seeds,
        a.common.out.display()
    );
    let md = planning::report(
        &rows,
        &command,
        &powderlab::lab::study::optimizers::machine(),
    ) + &powderlab::lab::study::push::push_report(&push_rows);
    powderlab::util::create_output_dir(&a.page.results, "--results")?;
    powderlab::util::write_atomic(&a.page.results.join("planning.md"), md.as_bytes())?;
    print_page(
        a.common.json,
        &a.page.results,
        &md,
        start,
        "planning.md",
        json!({ "instances": rows.len(), "push_instances": push_rows.len() }),
    );
    Ok(())
}

/// `powderlab study policy`: seed B's Sim2Real step on the randomised dosing scene (160
/// labelled scenes with 2 perturbed copies each and their hindsight samples, the fit, the
/// fine-tune, 20 held-out scenes).
pub(super) fn policy_cmd(a: args::Policy) -> Result<()> {
    use powderlab::lab::policy::{dataset, eval, net, reinforce};
    use powderlab::lab::study::policy;
    let path = a
        .scene
        .clone()
        .unwrap_or_else(|| PathBuf::from("scenes/policy_dosing.ron"));
    let scene = powderlab::scene::Scene::load(&path)?;
    dataset::spec_of(&scene)?;
    let settings = policy::Settings {
        dataset: dataset::Config {
            scene_hash: scene.fingerprint(),
            scenes: dataset::SCENES,
            budget: 10,
            augment: 2,
            augment_steps: 1,
            perturb: 0.1,
            seed: 0,
        },
        train: net::TrainConfig::default(),
        finetune: reinforce::ReinforceConfig::default(),
        eval: eval::EvalConfig {
            scenes: 20,
            budget: 30,
            seed: 0,
            first_draw: a.first_draw,
        },
    };
    let pb = super::super::bar(1, a.common.json);
    let start = Instant::now();
    let dir = a.common.out.join("policy");
    let o = policy::run(&scene, &settings, &dir, &|step, k, n| {
        pb.set_length(n as u64);
        pb.set_position(k as u64);
        pb.set_message(step.to_string());
    })?;
    pb.finish_and_clear();
    let mut command = format!("powderlab study policy --out {}", a.common.out.display());
    if a.first_draw != 0 {
        command.push_str(&format!(" --first-draw {}", a.first_draw));
    }
    let md = policy::report(
        &o,
        &settings,
        &scene,
        &command,
        &powderlab::lab::study::optimizers::machine(),
    );
    powderlab::util::create_output_dir(&a.page.results, "--results")?;
    policy::figure(&a.page.results.join("policy.svg"), &o.curve, &o.iterations)?;
    powderlab::util::write_atomic(&a.page.results.join("policy.md"), md.as_bytes())?;
    print_page(
        a.common.json,
        &a.page.results,
        &md,
        start,
        "policy.md and policy.svg",
        json!({ "scenes": o.rows.len() }),
    );
    Ok(())
}

/// `powderlab study pour`: the gravimetric pour on the policy page's held-out draws, at dx =
/// 5 mm (20) and 2.5 mm (the first 6).
pub(super) fn pour_cmd(a: args::Pour) -> Result<()> {
    use powderlab::lab::study::pour;
    let load = |p: &str| powderlab::scene::Scene::load(p);
    let coarse_scene = load("scenes/policy_dosing.ron")?;
    let fine_scene = load("scenes/policy_dosing_fine.ron")?;
    let settings = pour::Settings {
        scenes: 20,
        fine_scenes: 6,
        pour: Default::default(),
        faster_turn_back_deg: 720.0,
        // Taps of half a millimetre past 50°, below where a tilt alone starts the outflow (about
        // 63°), with the tilt creeping at 3°/s so the flow does not stall, up to 70°.
        tapped: powderlab::lab::policy::pour::Gravimetric {
            speed_deg: 3.0,
            fast_to_deg: 50.0,
            max_deg: 70.0,
            tap_mm: Some(0.5),
            ..Default::default()
        },
        seed: 0,
        first_draw: a.first_draw,
    };
    let start = Instant::now();
    let dir = a.common.out.join("pour");
    let faster = powderlab::lab::policy::pour::Gravimetric {
        turn_back_deg: Some(settings.faster_turn_back_deg),
        ..settings.pour
    };
    let back = format!("dx-5mm-back-{}", settings.faster_turn_back_deg);
    let mut rows = Vec::new();
    for (scene, g, n, sub) in [
        (&coarse_scene, &settings.pour, settings.scenes, "dx-5mm"),
        (
            &fine_scene,
            &settings.pour,
            settings.fine_scenes,
            "dx-2.5mm",
        ),
        (&coarse_scene, &faster, settings.scenes, back.as_str()),
        (
            &coarse_scene,
            &settings.tapped,
            settings.scenes,
            "dx-5mm-tapped",
        ),
    ] {
        let pb = super::super::bar(n as u64, a.common.json);
        pb.set_message(sub.to_string());
        let r = pour::run(
            scene,
            g,
            settings.seed,
            settings.first_draw,
            n,
            &dir.join(sub),
            &|k| pb.set_position(k as u64),
        )?;
        pb.finish_and_clear();
        rows.push(r);
    }
    let policy = pour::policy_trials(
        &a.common.out.join("policy"),
        settings.first_draw,
        settings.scenes,
    );
    let mut command = format!("powderlab study pour --out {}", a.common.out.display());
    if a.first_draw != 0 {
        command.push_str(&format!(" --first-draw {}", a.first_draw));
    }
    let md = pour::report(
        &rows[0],
        &rows[1],
        &rows[2],
        &rows[3],
        policy.as_deref(),
        &settings,
        &command,
        &powderlab::lab::study::optimizers::machine(),
        POUR_MINUTES,
        match coarse_scene
            .colliders
            .iter()
            .find_map(|c| c.control.as_ref())
        {
            Some(powderlab::scene::ControlSpec::Skill(sk)) => sk.angular_speed_deg,
            _ => bail!("scenes/policy_dosing.ron: its spoon has no skill"),
        },
    );
    powderlab::util::create_output_dir(&a.page.results, "--results")?;
    let (c, f) = pour::shown(&rows[0], &rows[1]).unzip();
    pour::figure(&a.page.results.join("pour.svg"), c, f)?;
    powderlab::util::write_atomic(&a.page.results.join("pour.md"), md.as_bytes())?;
    print_page(
        a.common.json,
        &a.page.results,
        &md,
        start,
        "pour.md and pour.svg",
        json!({ "scenes": rows[0].len(), "fine_scenes": rows[1].len() }),
    );
    Ok(())
}

/// `study pour`'s run time from scratch on this project's 2-core machine (min), for its page.
const POUR_MINUTES: f64 = 11.0;

/// `powderlab study calibration`: recovery of known parameters from noisy synthetic
/// observations, Adam and BFGS on the adjoint against CMA-ES at equal compute.
pub(super) fn calibration_cmd(a: args::Calibration) -> Result<()> {
    use powderlab::lab::study::calibration;
    if a.paired.seeds == 0 || a.paired.budget == 0 {
        bail!("study calibration: --seeds and --budget must be at least 1");
    }
    let budget = a.paired.budget as f64;
    let runs = calibration::CASES.len() * 5 * a.paired.seeds * calibration::METHODS.len();
    // The pairs, the joint fit and its curvature, and the grain sweep's gradient rollouts.
    let total = runs as f64 * budget + 2.0 * budget + 6.0 * 3.4 + calibration::GRAIN.3 as f64 * 3.4;
    for case in &calibration::CASES {
        super::super::announce_work(
            std::path::Path::new(case.scene),
            total / calibration::CASES.len() as f64,
        )?;
    }
    // The layered bed: its pairs (and each pair's rollout at the truth) and its curvature.
    let layers = {
        use calibration::layers as l;
        let pairs = (l::PAIRS_PER_SEED * a.paired.seeds) as f64;
        let k = l::LAYERS as f64;
        pairs * l::METHODS.len() as f64 * (l::BUDGET_FACTOR * budget + 1.0) + 1.0 + 2.0 * k * k
    };
    super::super::announce_work(std::path::Path::new(calibration::layers::SCENE), layers)?;
    let total = total + layers;
    let pb = super::super::bar(total.ceil() as u64, a.common.json);
    let pb2 = pb.clone();
    let done = std::sync::Mutex::new(0.0f64);
    let progress = move |c: f64| {
        let mut d = done.lock().expect("lock");
        *d += c;
        pb2.set_position(d.round() as u64);
    };
    rayon::ThreadPoolBuilder::new()
        .num_threads(a.threads.unwrap_or(0))
        .build_global()
        .context("starting the worker threads")?;
    let start = Instant::now();
    // Each rollout runs on one thread; the pairs run side by side.
    let outcome = calibration::run(
        &a.common.out.join("calibration"),
        a.paired.seeds,
        budget,
        Some(1),
        &progress,
    )?;
    pb.finish_and_clear();
    let command = format!(
        "powderlab study calibration --seeds {} --budget {}",
        a.paired.seeds, a.paired.budget
    );
    powderlab::util::create_output_dir(&a.page.results, "--results")?;
    let machine = powderlab::lab::study::optimizers::machine();
    let mut md = calibration::report(&outcome, &command, &machine, budget, &a.page.results)?;
    md.push_str(&calibration::layers::report(
        &outcome.layers,
        budget,
        &a.page.results,
    )?);
    powderlab::util::write_atomic(&a.page.results.join("calibration.md"), md.as_bytes())?;
    print_page(
        a.common.json,
        &a.page.results,
        &md,
        start,
        "calibration.md, calibration.svg and calibration_layers.svg",
        json!({ "runs": outcome.runs, "layers": outcome.layers.runs }),
    );
    Ok(())
}

/// `study reliability`: `simulate` on mutated scenes under a memory cap and a timeout; writes
/// docs/results/reliability.md. Resumes from OUT/reliability/cases.jsonl.
pub(super) fn reliability_cmd(a: args::Reliability) -> Result<()> {
    use powderlab::lab::study::reliability;
    let cfg = reliability::Config {
        cases: a.cases,
        cap_bytes: (a.cap_gb * (1u64 << 30) as f64) as u64,
        timeout_s: a.timeout_s,
        jobs: a.jobs,
    };
    if !(a.cap_gb > 0.0 && a.timeout_s > 0.0 && a.cases > 0 && a.jobs > 0) {
        bail!("--cases, --cap-gb, --timeout-s and --jobs must be positive");
    }
    let exe = std::env::current_exe().context("cannot find this executable")?;
    let dir = a.common.out.join("reliability");
    let pb = super::super::bar(cfg.cases as u64, a.common.json);
    let start = Instant::now();
    let records = reliability::run(&exe, std::path::Path::new("."), &dir, &cfg, &|k, n| {
        pb.set_length(n as u64);
        pb.set_position(k as u64);
    })?;
    pb.finish_and_clear();
    let command = format!(
        "powderlab study reliability --cases {} --cap-gb {} --timeout-s {} --jobs {}",
        cfg.cases, a.cap_gb, a.timeout_s, cfg.jobs
    );
    let md = reliability::report(
        &records,
        &cfg,
        &command,
        &powderlab::lab::study::optimizers::machine(),
    );
    let page = a.page.results.join("reliability.md");
    std::fs::create_dir_all(&a.page.results)
        .with_context(|| format!("cannot create {}", a.page.results.display()))?;
    powderlab::util::write_atomic(&page, md.as_bytes())
        .with_context(|| format!("writing {}", page.display()))?;
    let problems = records.iter().filter(|r| r.problem.is_some()).count();
    eprintln!(
        "{} cases in {:.0} s, {problems} breaking the acceptance; wrote {}",
        records.len(),
        start.elapsed().as_secs_f64(),
        page.display()
    );
    Ok(())
}

/// `powderlab study weighing`: the rule's doses on held-out draws; the page after every draw.
pub(super) fn weighing_cmd(a: args::Weighing) -> Result<()> {
    use powderlab::lab::study::weighing;
    let base = powderlab::scene::Scene::load(&a.scene)?;
    let d = powderlab::lab::weigh::Dispense::default();
    let opts = powderlab::sim::SimOptions {
        threads: a.threads,
        ..Default::default()
    };
    let folder = powderlab::lab::streams::folder("weighing", a.first_draw);
    let dir = a.common.out.join(folder);
    powderlab::util::create_output_dir(&a.page.results, "--results")?;
    let threads = match a.threads {
        Some(1) => "one thread".to_string(),
        Some(0) => "all cores".to_string(),
        Some(n) => format!("{n} threads"),
        None => format!("{} threads (the scene's setting)", base.simulation.threads),
    };
    let pb = super::super::bar(a.draws as u64, a.common.json);
    let rows = weighing::run(
        &base,
        &d,
        a.first_draw,
        a.draws,
        &opts,
        &dir,
        a.page_only,
        &mut |k, step, mg| {
            if step.is_multiple_of(10) {
                pb.set_message(format!("draw {k}: step {step}, balance {mg:.1} mg"));
            }
        },
        &mut |rows| {
            pb.set_position(rows.len() as u64);
            weighing::plot(rows, &a.page.results.join("weighing.svg"))?;
            powderlab::util::write_atomic(
                &a.page.results.join("weighing.md"),
                weighing::page(rows, &d, a.first_draw, a.draws, &threads).as_bytes(),
            )?;
            Ok(())
        },
    )?;
    pb.finish_and_clear();
    let s = weighing::summary(&rows);
    if a.common.json {
        println!(
            "{}",
            serde_json::json!({"doses": s.n, "mean_abs_mg": s.mean_abs_mg, "within_2mg": s.within})
        );
    } else {
        println!(
            "{} doses: mean |error| {:.2} mg, {:.0} % within ±2 mg; page {}",
            s.n,
            s.mean_abs_mg,
            100.0 * s.within,
            a.page.results.join("weighing.md").display()
        );
    }
    Ok(())
}
