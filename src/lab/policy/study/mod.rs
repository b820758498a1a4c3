//! The policy studies: the distilled policy against per-scene optimisation (`policy.md`) and
//! the pour closed on a load cell (`pour.md`).

pub mod policy;
pub mod pour;

use crate::lab::policy::pour::Gravimetric;
use crate::lab::policy::{dataset, eval, net, reinforce};
use crate::lab::study::args::{Common, Page};
use crate::lab::study::{machine, write_page, Ctx, Report, Study};
use crate::scene::{ControlSpec, Scene};
use anyhow::{bail, Result};
use std::path::PathBuf;

/// The command's line for a page: `base`, with `--first-draw` where it is not 0.
fn with_first_draw(base: String, first_draw: usize) -> String {
    match first_draw {
        0 => base,
        k => format!("{base} --first-draw {k}"),
    }
}

/// The distilled policy against per-scene optimisation (policy.md).
pub struct PolicyStudy;

#[derive(clap::Args)]
pub struct PolicyArgs {
    #[command(flatten)]
    pub common: Common,
    #[command(flatten)]
    pub page: Page,
    /// The policy's scene (default scenes/policy_dosing.ron).
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// The first held-out draw: draws 0–19 chose the policy's design (the design draws); 20
    /// and above have judged nothing yet (a verdict stream).
    #[arg(long, default_value_t = 0)]
    pub first_draw: usize,
}

impl PolicyArgs {
    fn scene(&self) -> Result<Scene> {
        let path = self
            .scene
            .clone()
            .unwrap_or_else(|| PathBuf::from("scenes/policy_dosing.ron"));
        Ok(Scene::load(&path)?)
    }

    /// Seed B's Sim2Real step on the randomised dosing scene: 160 labelled scenes with 2
    /// perturbed copies each and their hindsight samples, the fit, the fine-tune, 20 held-out
    /// scenes.
    fn settings(&self, scene: &Scene) -> policy::Settings {
        policy::Settings {
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
                first_draw: self.first_draw,
            },
        }
    }
}

impl Study for PolicyStudy {
    const NAME: &'static str = "policy";
    const ABOUT: &'static str = "The distilled policy against per-scene optimisation (policy.md)";
    type Args = PolicyArgs;
    type Outcome = policy::Outcome;

    fn run(a: &PolicyArgs, ctx: Ctx) -> Result<policy::Outcome> {
        let scene = a.scene()?;
        dataset::spec_of(&scene)?;
        let pb = ctx.bar(1);
        let o = policy::run(
            &scene,
            &a.settings(&scene),
            &a.common.out.join("policy"),
            &|step, k, n| {
                pb.set_length(n as u64);
                pb.set_position(k as u64);
                pb.set_message(step.to_string());
            },
        )?;
        pb.finish_and_clear();
        Ok(o)
    }

    fn page(a: &PolicyArgs, o: policy::Outcome, _: Ctx) -> Result<Report> {
        let scene = a.scene()?;
        let command = with_first_draw(
            format!("powderlab study policy --out {}", a.common.out.display()),
            a.first_draw,
        );
        let md = policy::report(&o, &a.settings(&scene), &scene, &command, &machine());
        crate::util::create_output_dir(&a.page.results, "--results")?;
        policy::figure(&a.page.results.join("policy.svg"), &o.curve, &o.iterations)?;
        write_page(&a.page.results, "policy.md", &md)?;
        Ok(Report {
            text: md,
            wrote: "policy.md and policy.svg".into(),
            dir: a.page.results.clone(),
            json: serde_json::json!({ "scenes": o.rows.len() }),
            failed: false,
        })
    }
}

/// Pouring closed on a load cell (pour.md).
pub struct Pour;

#[derive(clap::Args)]
pub struct PourArgs {
    #[command(flatten)]
    pub common: Common,
    #[command(flatten)]
    pub page: Page,
    /// The first held-out draw (as `study policy --first-draw`, whose policy it compares with).
    #[arg(long, default_value_t = 0)]
    pub first_draw: usize,
}

/// The pour's coarse (5 mm) and fine (2.5 mm) scenes.
const COARSE: &str = "scenes/policy_dosing.ron";
const FINE: &str = "scenes/policy_dosing_fine.ron";

/// `study pour`'s run time from scratch on this project's 2-core machine (min), for its page.
const POUR_MINUTES: f64 = 11.0;

impl PourArgs {
    /// The gravimetric pour on the policy page's held-out draws, at dx = 5 mm (20) and 2.5 mm
    /// (the first 6).
    fn settings(&self) -> pour::Settings {
        pour::Settings {
            scenes: 20,
            fine_scenes: 6,
            pour: Default::default(),
            faster_turn_back_deg: 720.0,
            // Taps of half a millimetre past 50°, below where a tilt alone starts the outflow
            // (about 63°), with the tilt creeping at 3°/s so the flow does not stall, up to 70°.
            tapped: Gravimetric {
                speed_deg: 3.0,
                fast_to_deg: 50.0,
                max_deg: 70.0,
                tap_mm: Some(0.5),
                ..Default::default()
            },
            seed: 0,
            first_draw: self.first_draw,
        }
    }
}

impl Study for Pour {
    const NAME: &'static str = "pour";
    const ABOUT: &'static str = "Pouring closed on a load cell (pour.md)";
    type Args = PourArgs;
    /// The coarse, fine, faster turn-back and tapped pours.
    type Outcome = [Vec<pour::Row>; 4];

    fn run(a: &PourArgs, ctx: Ctx) -> Result<Self::Outcome> {
        let (coarse, fine) = (Scene::load(COARSE)?, Scene::load(FINE)?);
        let settings = a.settings();
        let dir = a.common.out.join("pour");
        let faster = Gravimetric {
            turn_back_deg: Some(settings.faster_turn_back_deg),
            ..settings.pour
        };
        let back = format!("dx-5mm-back-{}", settings.faster_turn_back_deg);
        let mut rows: [Vec<pour::Row>; 4] = Default::default();
        for (k, (scene, g, n, sub)) in [
            (&coarse, &settings.pour, settings.scenes, "dx-5mm"),
            (&fine, &settings.pour, settings.fine_scenes, "dx-2.5mm"),
            (&coarse, &faster, settings.scenes, back.as_str()),
            (&coarse, &settings.tapped, settings.scenes, "dx-5mm-tapped"),
        ]
        .into_iter()
        .enumerate()
        {
            let pb = ctx.bar(n as u64);
            pb.set_message(sub.to_string());
            rows[k] = pour::run(
                scene,
                g,
                settings.seed,
                settings.first_draw,
                n,
                &dir.join(sub),
                &|k| pb.set_position(k as u64),
            )?;
            pb.finish_and_clear();
        }
        Ok(rows)
    }

    fn page(a: &PourArgs, rows: Self::Outcome, _: Ctx) -> Result<Report> {
        let coarse = Scene::load(COARSE)?;
        let settings = a.settings();
        let policy = pour::policy_trials(
            &a.common.out.join("policy"),
            settings.first_draw,
            settings.scenes,
        );
        let command = with_first_draw(
            format!("powderlab study pour --out {}", a.common.out.display()),
            a.first_draw,
        );
        let turn_back_deg = match coarse.colliders.iter().find_map(|c| c.control.as_ref()) {
            Some(ControlSpec::Skill(sk)) => sk.angular_speed_deg,
            _ => bail!("{COARSE}: its spoon has no skill"),
        };
        let md = pour::report(
            &rows[0],
            &rows[1],
            &rows[2],
            &rows[3],
            policy.as_deref(),
            &settings,
            &command,
            &machine(),
            POUR_MINUTES,
            turn_back_deg,
        );
        crate::util::create_output_dir(&a.page.results, "--results")?;
        let (c, f) = pour::shown(&rows[0], &rows[1]).unzip();
        pour::figure(&a.page.results.join("pour.svg"), c, f)?;
        write_page(&a.page.results, "pour.md", &md)?;
        Ok(Report {
            text: md,
            wrote: "pour.md and pour.svg".into(),
            dir: a.page.results.clone(),
            json: serde_json::json!({ "scenes": rows[0].len(), "fine_scenes": rows[1].len() }),
            failed: false,
        })
    }
}

crate::study_settings!(PolicyArgs, PourArgs);
