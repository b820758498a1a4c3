//! `study planning`: multi-scoop dosing over randomised instances, A* against the greedy and
//! scripted baselines (docs/results/planning.md).
//!
//! Each instance draws a target mass, a fill height and a friction angle, and each method plans
//! it from the same scene (`plan::output::plan_into`, without a recording). A plan's result and
//! its journal stay in `dir/instance-K/`, so a killed study resumes where it was.

use crate::lab::plan::dosing::{Dosing, Method, PlanResult};
use crate::lab::plan::output::{plan_file, plan_into, PlanTask};
use crate::lab::stats::{mean_sd as mean_std, median, sign_test, wilcoxon_less};
use crate::materials::drucker_prager::DruckerPrager;
use crate::scene::plan::PlanSpec;
use crate::scene::{ControlSpec, Fill, LossSpec, Scene, TargetValue};
use crate::util::SplitMix64;
use serde::{Deserialize, Serialize};
use std::fmt::Write;
use std::path::Path;

/// The ranges instances are drawn from, uniformly.
pub const TARGET_G: (f64, f64) = (8.0, 15.0);
pub const FILL_HEIGHT: (f64, f64) = (0.020, 0.030);
pub const FRICTION_DEG: (f64, f64) = (25.0, 35.0);

/// One randomised instance.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Instance {
    pub index: usize,
    pub target_g: f64,
    pub fill_height: f64,
    pub friction_deg: f64,
}

/// `n` instances drawn from `seed`.
pub fn instances(n: usize, seed: u64) -> Vec<Instance> {
    let mut rng = SplitMix64(seed);
    let mut draw = |(lo, hi): (f64, f64)| lo + (hi - lo) * rng.uniform();
    (0..n)
        .map(|index| Instance {
            index,
            target_g: (draw(TARGET_G) * 10.0).round() / 10.0,
            fill_height: draw(FILL_HEIGHT),
            friction_deg: draw(FRICTION_DEG),
        })
        .collect()
}

/// `base` (a scene with a dosing plan) set to the instance: the source's fill height and the
/// skill's surface height with it, every Drucker–Prager material's friction angle, the target
/// mass of the task and of the dosing loss.
pub fn scene_of(base: &Scene, inst: &Instance) -> anyhow::Result<Scene> {
    let mut s = base.clone();
    let Some(PlanSpec::Dosing(plan)) = &s.plan else {
        anyhow::bail!("{}: no dosing plan", base.path.display());
    };
    let source = plan.source.clone();
    let mut raised = None;
    for b in &mut s.bodies {
        if let Fill::InsideContainer { container, height } = &mut b.fill {
            if *container == source {
                raised = Some(inst.fill_height - *height);
                *height = inst.fill_height;
            }
        }
    }
    let raised = raised.ok_or_else(|| {
        anyhow::anyhow!(
            "{}: no body fills the source cup '{source}'",
            base.path.display()
        )
    })?;
    for c in &mut s.colliders {
        if let Some(ControlSpec::Skill(sk)) = &mut c.control {
            sk.surface_height += raised;
        }
    }
    for m in s.materials.values_mut() {
        if let Some(dp) = m.get_mut::<DruckerPrager>() {
            dp.friction_deg = inst.friction_deg;
        }
    }
    if let Some(t) = &mut s.task {
        t.target_value = TargetValue::Grams(inst.target_g);
    }
    if let Some(LossSpec::Dosing { grams, .. }) = &mut s.loss {
        *grams = inst.target_g;
    }
    s.validate()?;
    Ok(s)
}

/// One instance's plans, one per method.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Row {
    pub instance: Instance,
    pub plans: Vec<PlanResult>,
}

/// Plans every instance with every method into `dir`, keeping what is there.
/// `progress(instance, method)` hears of each plan as it starts.
pub fn run(
    base: &Scene,
    dir: &Path,
    instances: &[Instance],
    methods: &[Method],
    progress: &dyn Fn(usize, Method),
) -> anyhow::Result<Vec<Row>> {
    let mut rows = Vec::new();
    for inst in instances {
        let scene = scene_of(base, inst)?;
        let out = dir.join(format!("instance-{}", inst.index));
        let mut plans = Vec::new();
        for &m in methods {
            progress(inst.index, m);
            plans.push(kept_or::<Dosing>(&out, &scene, m, inst.index as u64)?);
        }
        rows.push(Row {
            instance: inst.clone(),
            plans,
        });
    }
    Ok(rows)
}

/// The plan of `method` kept in `out` from an earlier run, or a new one planned there from
/// `seed` without a recording: a killed study resumes at the first plan it had not written.
pub fn kept_or<T: PlanTask>(
    out: &Path,
    scene: &Scene,
    method: Method,
    seed: u64,
) -> anyhow::Result<T::Result>
where
    T::Result: serde::de::DeserializeOwned,
{
    let kept = std::fs::read_to_string(plan_file(out, method, "json"))
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok());
    match kept {
        Some(r) => Ok(r),
        None => plan_into::<T>(out, scene.clone(), method, seed, false, Box::new(|_, _| {})),
    }
}

/// The page.
pub fn report(rows: &[Row], command: &str, machine: &str) -> String {
    let mut md = String::new();
    let _ = writeln!(md, "# Planning: multi-scoop dosing, pushing and pulling\n");
    let _ = writeln!(
        md,
        "Regenerate: `{command}` (it keeps the plans already in its folder).  "
    );
    let wall: f64 = rows.iter().flat_map(|r| &r.plans).map(|p| p.wall_s).sum();
    let _ = writeln!(
        md,
        "Machine: {machine}. The dosing plans' recorded wall times sum to {:.0} s (a plan \
         resumed from its journal records its last run's time only).\n",
        wall
    );
    let _ = writeln!(md, "## Multi-scoop dosing\n");
    let n = rows.len();
    let Some(first) = rows.first() else {
        return md;
    };
    let tol = first.plans[0].tolerance_g;
    let _ = writeln!(
        md,
        "Scene: `scenes/multi_scoop_dosing.ron` (the default transport scene's spoon and cups; \
         the largest scoop of each method is in the table). {n} instances, each drawing a target mass in [{}, {}] g \
         (rounded to 0.1 g), a fill height in [{}, {}] mm and a friction angle in [{}, {}]°. \
         Success is a dose within ±{tol} g. Each scoop's optimiser (`OptWrench`) is CMA-ES \
         with the plan's budget of forward rollouts, the first at the previous scoop's Θ; \
         A* expands at most the plan's `max_expansions` nodes; greedy optimises one scoop \
         after another at the highest entry point without search; scripted repeats the \
         scene's Θ at the highest entry point until the dose is reached or passed. \
         Between scoops the powder outside both cups (left in the spoon, or spilt) is \
         discarded. A method's rollouts count every rollout its plan asked for, including \
         those it found in the instance's journal: the methods share one, so greedy replays \
         the scoops it has in common with A\\* rather than simulating them again, and the \
         study's wall time is less than the sum of the plans' costs.\n",
        TARGET_G.0,
        TARGET_G.1,
        FILL_HEIGHT.0 * 1e3,
        FILL_HEIGHT.1 * 1e3,
        FRICTION_DEG.0,
        FRICTION_DEG.1,
    );
    let _ = writeln!(
        md,
        "| method | success (±{tol} g) | dose error (g), mean ± std | median | scoops, mean | rollouts, mean | G particle-substeps, mean | largest scoop (g) |"
    );
    let _ = writeln!(md, "|---|---|---|---|---|---|---|---|");
    let methods: Vec<Method> = first.plans.iter().map(|p| p.method).collect();
    let column = |m: usize, f: &dyn Fn(&PlanResult) -> f64| -> Vec<f64> {
        rows.iter().map(|r| f(&r.plans[m])).collect()
    };
    for (m, method) in methods.iter().enumerate() {
        let err = column(m, &|p| p.dose_error_g);
        let ok = column(m, &|p| if p.success { 1.0 } else { 0.0 });
        let (e, es) = mean_std(&err);
        let _ =
            writeln!(
            md,
            "| {} | {}/{n} ({:.0} %) | {e:.3} ± {es:.3} | {:.3} | {:.1} | {:.1} | {:.2} | {:.2} |",
            method.name(),
            ok.iter().sum::<f64>() as usize,
            100.0 * ok.iter().sum::<f64>() / n as f64,
            median(&err),
            mean_std(&column(m, &|p| p.scoops.len() as f64)).0,
            mean_std(&column(m, &|p| p.rollouts as f64)).0,
            mean_std(&column(m, &|p| p.particle_substeps / 1e9)).0,
            column(m, &|p| p.scoops.iter().map(|s| s.added_g).fold(0.0, f64::max))
                .into_iter()
                .fold(0.0, f64::max),
        );
    }
    if let Some(a) = methods.iter().position(|m| *m == Method::Astar) {
        let wins = |m: usize| rows.iter().filter(|r| r.plans[m].success).count();
        let best_other = (0..methods.len())
            .filter(|&b| b != a)
            .map(wins)
            .max()
            .unwrap_or(0);
        let met = wins(a) >= best_other && 10 * wins(a) >= 8 * n;
        let _ = writeln!(
            md,
            "\n**The issue's target (A\\* succeeds at least as often as either baseline, and at \
             least 80 % of the time): {}.** A\\* succeeded on {} of {n}, the better baseline \
             on {best_other}.\n",
            if met { "met" } else { "missed" },
            wins(a)
        );
        let failures: Vec<String> = rows
            .iter()
            .filter(|r| !r.plans[a].success)
            .map(|r| {
                let p = &r.plans[a];
                format!(
                    "instance {} ({:.3} g of {:.1} g after {} expansions)",
                    r.instance.index, p.delivered_g, p.target_g, p.expansions
                )
            })
            .collect();
        if !failures.is_empty() {
            let _ = writeln!(
                md,
                "A\\*'s failures: {}. A search ends when its expansions reach the plan's \
                 `max_expansions` or when no node is left to expand (a relocated node whose \
                 scoop fails is not relocated again).\n",
                failures.join("; ")
            );
        }
        for (b, other) in methods.iter().enumerate().filter(|(b, _)| *b != a) {
            let ea = column(a, &|p| p.dose_error_g);
            let eb = column(b, &|p| p.dose_error_g);
            let sa: Vec<bool> = rows.iter().map(|r| r.plans[a].success).collect();
            let sb: Vec<bool> = rows.iter().map(|r| r.plans[b].success).collect();
            let fmt =
                |p: Option<f64>| p.map_or("– (no difference)".into(), |p| format!("{p:.4}"));
            let _ = writeln!(
                md,
                "A\\* against {}: one-sided Wilcoxon p = {} that A\\*'s dose error is smaller; \
                 exact sign test p = {} that A\\* succeeds more often (paired instances).  ",
                other.name(),
                fmt(wilcoxon_less(&ea, &eb)),
                fmt(sign_test(&sa, &sb)),
            );
        }
    }
    let _ = writeln!(md, "\n## Per instance\n");
    let mut head = String::from("| instance | target (g) | fill (mm) | φ (°) |");
    let mut rule = String::from("|---|---|---|---|");
    for m in &methods {
        let _ = write!(head, " {} delivered (g), scoops, rollouts |", m.name());
        rule.push_str("---|");
    }
    let _ = writeln!(md, "{head}\n{rule}");
    for r in rows {
        let i = &r.instance;
        let mut line = format!(
            "| {} | {:.1} | {:.1} | {:.1} |",
            i.index,
            i.target_g,
            i.fill_height * 1e3,
            i.friction_deg
        );
        for p in &r.plans {
            let _ = write!(
                line,
                " {:.3}{}, {}, {} |",
                p.delivered_g,
                if p.success { " ✓" } else { "" },
                p.scoops.len(),
                p.rollouts
            );
        }
        let _ = writeln!(md, "{line}");
    }
    let _ = writeln!(md, "\n✓ marks a plan within the tolerance.");
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_instance_changes_the_fill_the_surface_the_friction_and_the_dose() {
        let base = Scene::load(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/multi_scoop_dosing.ron"),
        )
        .unwrap();
        let inst = Instance {
            index: 0,
            target_g: 9.5,
            fill_height: 0.028,
            friction_deg: 27.0,
        };
        let s = scene_of(&base, &inst).unwrap();
        let Fill::InsideContainer { height, .. } = s.bodies[0].fill else {
            panic!()
        };
        assert_eq!(height, 0.028);
        let surface = |s: &Scene| match &s.colliders[2].control {
            Some(ControlSpec::Skill(sk)) => sk.surface_height,
            _ => panic!(),
        };
        assert!((surface(&s) - surface(&base) - 0.003).abs() < 1e-12);
        let dp = s.materials["powder"].get::<DruckerPrager>().unwrap();
        assert_eq!(dp.friction_deg, 27.0);
        assert_eq!(
            s.loss,
            Some(LossSpec::Dosing {
                grams: 9.5,
                width: None
            })
        );
        let all = instances(10, 1);
        assert!(all.iter().all(|i| (8.0..=15.0).contains(&i.target_g)));
        assert_eq!(all, instances(10, 1));
    }
}
