//! The push half of `study planning`: seed B's four classes over randomised layouts on
//! `scenes/plate_push.ron`, A* against greedy and scripted (docs/results/planning.md).

use super::planning::kept_or;
use crate::lab::plan::push::{Push, PushResult, STROKE_BACKWARD_COST};
use crate::lab::plan::Method;
use crate::lab::stats::sign_test;
use crate::scene::plan::{PlanSpec, PushClass, StrokeOptimiser};
use crate::scene::{Fill, Scene};
use crate::util::SplitMix64;
use serde::{Deserialize, Serialize};
use std::fmt::Write;
use std::path::Path;

/// The push instances' ranges: the patch's centre (x, z) and size (x, z) (m), and the region's
/// boundary for the left classes (the right classes mirror the instance about the plate's
/// middle, x = 0.1 m).
pub const PATCH_X: (f64, f64) = (0.09, 0.11);
pub const PATCH_Z: (f64, f64) = (0.05, 0.07);
pub const PATCH_SIZE_X: (f64, f64) = (0.02, 0.04);
pub const PATCH_SIZE_Z: (f64, f64) = (0.03, 0.06);
pub const BOUNDARY_LEFT: (f64, f64) = (0.045, 0.065);
/// The patch's height (m) and the plate's top (m) in `scenes/plate_push.ron`.
pub const PATCH_HEIGHT: f64 = 0.01;

/// One push instance: a layout and a class.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct PushInstance {
    pub index: usize,
    pub class: PushClass,
    pub centre: [f64; 2],
    pub size: [f64; 2],
    pub boundary: f64,
}

/// `n` layouts drawn from `seed`, each set in every class (the right classes mirrored).
pub fn push_instances(n: usize, seed: u64) -> Vec<PushInstance> {
    let mut rng = SplitMix64(seed);
    let mut draw = |(lo, hi): (f64, f64)| lo + (hi - lo) * rng.uniform();
    let layouts: Vec<([f64; 2], [f64; 2], f64)> = (0..n)
        .map(|_| {
            (
                [draw(PATCH_X), draw(PATCH_Z)],
                [draw(PATCH_SIZE_X), draw(PATCH_SIZE_Z)],
                draw(BOUNDARY_LEFT),
            )
        })
        .collect();
    let mut out = Vec::new();
    for class in PushClass::ALL {
        for (index, (c, size, b)) in layouts.iter().enumerate() {
            let mirror = class.side() > 0.0;
            out.push(PushInstance {
                index,
                class,
                centre: [if mirror { 0.2 - c[0] } else { c[0] }, c[1]],
                size: *size,
                boundary: if mirror { 0.2 - b } else { *b },
            });
        }
    }
    out
}

/// `base` (`scenes/plate_push.ron`) set to the instance: the powder's patch, the class and
/// the region's boundary.
pub fn push_scene_of(base: &Scene, inst: &PushInstance) -> anyhow::Result<Scene> {
    let mut s = base.clone();
    let Some(PlanSpec::Push(plan)) = &mut s.plan else {
        anyhow::bail!("{}: no push plan", base.path.display());
    };
    plan.class = inst.class;
    plan.boundary = inst.boundary;
    let top = plan
        .plate_box(base)
        .map(|(c, h)| c.y + h.y)
        .ok_or_else(|| anyhow::anyhow!("{}: no plate", base.path.display()))?;
    let (c, h) = (inst.centre, [0.5 * inst.size[0], 0.5 * inst.size[1]]);
    let body = s
        .bodies
        .first_mut()
        .ok_or_else(|| anyhow::anyhow!("{}: no powder", base.path.display()))?;
    body.fill = Fill::Box {
        min: (c[0] - h[0], top + 0.0005, c[1] - h[1]),
        max: (c[0] + h[0], top + 0.0005 + PATCH_HEIGHT, c[1] + h[1]),
    };
    s.validate()?;
    Ok(s)
}

/// The layouts' two streams: the ten the planner's settings were chosen on (and the page's
/// earlier tables came from), and ten that no setting was chosen on, drawn from their own seed.
pub const KEPT_SEED: u64 = 2027;
pub const FRESH_SEED: u64 = 4051;

/// A planner: a method and, except for scripted, its strokes' optimiser.
pub type Planner = (Method, StrokeOptimiser);

/// The planners the study runs for `methods`: A* and greedy with each optimiser, scripted once.
pub fn planners(methods: &[Method]) -> Vec<Planner> {
    let mut out = Vec::new();
    for &m in methods {
        if m == Method::Scripted {
            out.push((m, StrokeOptimiser::Cma));
        } else {
            out.extend(StrokeOptimiser::ALL.map(|o| (m, o)));
        }
    }
    out
}

fn planner_name((m, o): Planner) -> String {
    if m == Method::Scripted {
        m.name().into()
    } else {
        format!("{} ({})", m.name(), o.name())
    }
}

/// One push instance's plans, one per planner.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PushRow {
    pub instance: PushInstance,
    /// Whether the layout is of the fresh stream.
    pub fresh: bool,
    pub plans: Vec<PushResult>,
}

/// Plans every push instance (`(fresh, instance)`) with every planner into `dir`, keeping what
/// is there.
pub fn run_push(
    base: &Scene,
    dir: &Path,
    instances: &[(bool, PushInstance)],
    planners: &[Planner],
    progress: &dyn Fn(usize, Method),
) -> anyhow::Result<Vec<PushRow>> {
    let mut rows = Vec::new();
    for (k, (fresh, inst)) in instances.iter().enumerate() {
        let mut scene = push_scene_of(base, inst)?;
        let class = inst.class.name().replace(' ', "-");
        let stream = if *fresh { "fresh" } else { "kept" };
        let mut plans = Vec::new();
        for &(m, o) in planners {
            progress(k, m);
            if let Some(PlanSpec::Push(p)) = &mut scene.plan {
                p.optimiser = o;
            }
            let out = dir.join(format!("{stream}/{class}-{}/{}", inst.index, o.name()));
            plans.push(kept_or::<Push>(&out, &scene, m, inst.index as u64)?);
        }
        rows.push(PushRow {
            instance: inst.clone(),
            fresh: *fresh,
            plans,
        });
    }
    Ok(rows)
}

fn is(p: &PushResult, (m, o): Planner) -> bool {
    p.method == m && (m == Method::Scripted || p.optimiser == o)
}

/// The plan of `planner` in a row.
fn plan_of(r: &PushRow, planner: Planner) -> Option<&PushResult> {
    r.plans.iter().find(|p| is(p, planner))
}

/// The heading that starts the push section.
pub const SECTION: &str = "\n## Pushing and pulling powder";

/// The push section of the page: seed B's figure 3 for powder.
pub fn push_report(rows: &[PushRow], machine: &str) -> String {
    let mut md = String::new();
    let Some(first) = rows.first() else {
        return md;
    };
    let planners: Vec<Planner> = first
        .plans
        .iter()
        .map(|p| (p.method, p.optimiser))
        .collect();
    let frac = first.plans[0].success_fraction;
    let per_class = |fresh: bool| {
        rows.iter()
            .filter(|r| r.instance.class == PushClass::PushLeft && r.fresh == fresh)
            .count()
    };
    let wall: f64 = rows.iter().flat_map(|r| &r.plans).map(|p| p.wall_s).sum();
    let timing = |f: &dyn Fn(&PushResult) -> (f64, usize)| {
        rows.iter()
            .flat_map(|r| &r.plans)
            .map(f)
            .fold((0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1))
    };
    let (fw, gw) = (
        timing(&|p| p.forward_timing),
        timing(&|p| p.gradient_timing),
    );
    let budget = crate::scene::plan::PushPlan::default_budget();
    let multiple =
        (fw.1 > 0 && gw.1 > 0).then(|| (gw.0 / gw.1 as f64) / (fw.0 / fw.1 as f64) - 1.0);
    let _ = writeln!(md, "{SECTION} (seed B's figure 3)\n");
    let _ = writeln!(
        md,
        "Regenerate this section alone: `powderlab study planning --tasks scenes/plate_push.ron \
         --seeds {} --threads 1 --out study` (it keeps the dosing section above; the plans here \
         came from two such runs side by side, `--layouts kept` and `--layouts fresh`, and a \
         last one with both that found them kept).  \nMachine: {machine}. The push plans' recorded wall times sum to \
         {wall:.0} s (a resumed plan records its last run's time only).\n",
        per_class(false).max(per_class(true)),
    );
    let _ = writeln!(
        md,
        "Scene: `scenes/plate_push.ron`: a patch of powder {PATCH_HEIGHT_MM} mm high on a plate, \
         a spatula with a blade 40 mm wide. Layouts, each set in the four classes \
         (the right classes mirrored about the plate's middle): the patch's centre x in \
         [{:.0}, {:.0}] mm and z in [{:.0}, {:.0}] mm, its size {:.0}–{:.0} mm along the stroke \
         and {:.0}–{:.0} mm across it (wider than the blade from 40 mm on), the region's \
         boundary {:.0}–{:.0} mm from the plate's left edge for the left classes. Success is at \
         least {:.0} % of the mass in the region. **Kept layouts**: the {} of seed {KEPT_SEED}, \
         which the planner's settings were chosen on (the design stream). **Fresh layouts**: \
         {} of seed {FRESH_SEED}, which nothing was chosen on (the verdict stream).\n",
        PATCH_X.0 * 1e3,
        PATCH_X.1 * 1e3,
        PATCH_Z.0 * 1e3,
        PATCH_Z.1 * 1e3,
        PATCH_SIZE_X.0 * 1e3,
        PATCH_SIZE_X.1 * 1e3,
        PATCH_SIZE_Z.0 * 1e3,
        PATCH_SIZE_Z.1 * 1e3,
        (BOUNDARY_LEFT.0 - 0.025) * 1e3,
        (BOUNDARY_LEFT.1 - 0.025) * 1e3,
        100.0 * frac,
        per_class(false),
        per_class(true),
        PATCH_HEIGHT_MM = PATCH_HEIGHT * 1e3,
    );
    let _ = writeln!(
        md,
        "Each stroke's optimiser (`OptWrench`) has the plan's budget of {budget} forward \
         rollouts from the scripted stroke. **cma**: CMA-ES on the soft share outside. \
         **gradient**: line searches along the push loss's gradient by the adjoint, judged by \
         the same soft share, a gradient rollout charged 1 + {STROKE_BACKWARD_COST} forward \
         rollouts. Scripted is the straight stroke through the middle of the powder still \
         outside, repeated. The compute column counts every rollout's particle-substeps, a \
         gradient rollout's at 1 + {STROKE_BACKWARD_COST} times.\n",
    );
    if let Some(m) = multiple {
        // A gradient stroke: one gradient rollout, then forward trials up to the budget.
        let trials = (budget as f64 - (1.0 + STROKE_BACKWARD_COST)).floor();
        let _ =
            writeln!(
            md,
            "**The charge was {}.** The backward pass measured in this run cost {m:.2} forward \
             rollouts ({} gradient and {} forward rollouts timed, one thread each), not \
             {STROKE_BACKWARD_COST}. At the measured multiple a gradient stroke (one gradient \
             rollout and {trials:.0} forward trials) cost {:.1} forward rollouts against \
             CMA-ES's {budget}: {:+.0} % of its compute, in the {} favour in every comparison \
             below.\n",
            if m > STROKE_BACKWARD_COST { "low" } else { "high" },
            gw.1,
            fw.1,
            1.0 + m + trials,
            100.0 * ((1.0 + m + trials) / budget as f64 - 1.0),
            if 1.0 + m + trials > budget as f64 { "gradient's" } else { "CMA-ES's" },
        );
    }
    let _ = writeln!(
        md,
        "| planner | class | success, kept | success, fresh | mass in region, mean | strokes, \
         mean | rollouts, mean | G particle-substeps, mean |\n|---|---|---|---|---|---|---|---|"
    );
    for &pl in &planners {
        for class in PushClass::ALL {
            let rs: Vec<(&PushRow, &PushResult)> = rows
                .iter()
                .filter(|r| r.instance.class == class)
                .filter_map(|r| plan_of(r, pl).map(|p| (r, p)))
                .collect();
            let n = rs.len().max(1) as f64;
            let ok = |fresh: bool| {
                let sel: Vec<bool> = rs
                    .iter()
                    .filter(|(r, _)| r.fresh == fresh)
                    .map(|(_, p)| p.success)
                    .collect();
                let k = sel.iter().filter(|s| **s).count();
                if sel.is_empty() {
                    "–".to_string()
                } else {
                    format!(
                        "{k}/{} ({:.0} %)",
                        sel.len(),
                        100.0 * k as f64 / sel.len() as f64
                    )
                }
            };
            let mean =
                |f: &dyn Fn(&PushResult) -> f64| rs.iter().map(|(_, p)| f(p)).sum::<f64>() / n;
            let _ = writeln!(
                md,
                "| {} | {} | {} | {} | {:.1} % | {:.1} | {:.1} | {:.4} |",
                planner_name(pl),
                class.name(),
                ok(false),
                ok(true),
                100.0 * mean(&|p| p.in_region),
                mean(&|p| p.strokes.len() as f64),
                mean(&|p| p.rollouts as f64),
                mean(&|p| p.particle_substeps) * 1e-9,
            );
        }
    }
    let _ = writeln!(
        md,
        "\nSign tests over paired instances (exact, one-sided):\n"
    );
    let current = (Method::Astar, StrokeOptimiser::Cma);
    for (a, b) in [
        ((Method::Astar, StrokeOptimiser::Gradient), current),
        (current, (Method::Scripted, StrokeOptimiser::Cma)),
        (
            (Method::Astar, StrokeOptimiser::Gradient),
            (Method::Greedy, StrokeOptimiser::Gradient),
        ),
    ] {
        for fresh in [false, true] {
            let pairs: Vec<(bool, bool)> = rows
                .iter()
                .filter(|r| r.fresh == fresh)
                .filter_map(|r| Some((plan_of(r, a)?.success, plan_of(r, b)?.success)))
                .collect();
            if pairs.is_empty() {
                continue;
            }
            let (sa, sb): (Vec<bool>, Vec<bool>) = pairs.into_iter().unzip();
            let _ = writeln!(
                md,
                "- {} layouts: p = {} that {} succeeds more often than {} ({} against {} of {}).",
                if fresh { "fresh" } else { "kept" },
                sign_test(&sa, &sb)
                    .map_or("– (no discordant pair)".into(), |p| format!("{p:.4}")),
                planner_name(a),
                planner_name(b),
                sa.iter().filter(|s| **s).count(),
                sb.iter().filter(|s| **s).count(),
                sa.len(),
            );
        }
    }
    // Per stroke at equal compute: greedy's first stroke from the start, by each optimiser.
    let g = |o| (Method::Greedy, o);
    let firsts: Vec<(f64, f64)> = rows
        .iter()
        .filter_map(|r| {
            let c = plan_of(r, g(StrokeOptimiser::Cma))?
                .strokes
                .first()?
                .in_region;
            let d = plan_of(r, g(StrokeOptimiser::Gradient))?
                .strokes
                .first()?
                .in_region;
            Some((c, d))
        })
        .collect();
    if !firsts.is_empty() {
        let (c, d): (Vec<f64>, Vec<f64>) = firsts.iter().copied().unzip();
        let better = firsts.iter().filter(|(c, d)| d > c).count();
        let worse = firsts.iter().filter(|(c, d)| d < c).count();
        let _ = writeln!(
            md,
            "\n**Per stroke at equal compute.** The first stroke of every greedy plan starts from \
             the same state with the same budget (the patch starts outside the region, so its \
             share in the region afterwards is the mass the stroke moved in). Over {} \
             instances the gradient moved in {:.1} % on average, CMA-ES {:.1} %; the gradient \
             moved more on {better}, less on {worse}. One-sided Wilcoxon p {} that CMA-ES \
             moves less than the gradient.",
            firsts.len(),
            100.0 * crate::lab::stats::mean(&d),
            100.0 * crate::lab::stats::mean(&c),
            match crate::lab::stats::wilcoxon_less(&c, &d) {
                Some(p) if p < 1e-3 => "< 0.001".to_string(),
                p => format!("= {}", crate::lab::stats::p_text(p)),
            },
        );
    }
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn push_instances_mirror_the_right_classes_and_fill_the_patch() {
        let all = push_instances(3, 5);
        assert_eq!(all.len(), 12);
        let (l, r) = (&all[0], &all[3]);
        assert_eq!(
            (l.class, r.class),
            (PushClass::PushLeft, PushClass::PushRight)
        );
        assert!((l.centre[0] + r.centre[0] - 0.2).abs() < 1e-12);
        assert!((l.boundary + r.boundary - 0.2).abs() < 1e-12);
        assert_eq!(l.size, r.size);
        let base = Scene::load(Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/plate_push.ron"))
            .unwrap();
        let s = push_scene_of(&base, r).unwrap();
        let Some(PlanSpec::Push(p)) = &s.plan else {
            panic!()
        };
        assert_eq!((p.class, p.boundary), (PushClass::PushRight, r.boundary));
        let Fill::Box { min, max } = s.bodies[0].fill else {
            panic!()
        };
        assert!(
            (max.0 - min.0 - r.size[0]).abs() < 1e-12 && (max.2 - min.2 - r.size[1]).abs() < 1e-12
        );
    }
}
