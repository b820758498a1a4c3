//! The push half of `study planning`: seed B's four classes over randomised layouts on
//! `scenes/plate_push.ron`, A* against greedy and scripted (docs/results/planning.md).

use super::planning::kept_or;
use crate::lab::plan::push::{Push, PushResult};
use crate::lab::plan::Method;
use crate::lab::stats::sign_test;
use crate::scene::plan::{PlanSpec, PushClass};
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

/// One push instance's plans, one per method.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PushRow {
    pub instance: PushInstance,
    pub plans: Vec<PushResult>,
}

/// Plans every push instance with every method into `dir`, keeping what is there.
pub fn run_push(
    base: &Scene,
    dir: &Path,
    instances: &[PushInstance],
    methods: &[Method],
    progress: &dyn Fn(usize, Method),
) -> anyhow::Result<Vec<PushRow>> {
    let mut rows = Vec::new();
    for (k, inst) in instances.iter().enumerate() {
        let scene = push_scene_of(base, inst)?;
        let class = inst.class.name().replace(' ', "-");
        let out = dir.join(format!("{class}-{}", inst.index));
        let mut plans = Vec::new();
        for &m in methods {
            progress(k, m);
            plans.push(kept_or::<Push>(&out, &scene, m, inst.index as u64)?);
        }
        rows.push(PushRow {
            instance: inst.clone(),
            plans,
        });
    }
    Ok(rows)
}

/// The push section of the page: seed B's figure 3 for powder.
pub fn push_report(rows: &[PushRow]) -> String {
    let mut md = String::new();
    let Some(first) = rows.first() else {
        return md;
    };
    let methods: Vec<Method> = first.plans.iter().map(|p| p.method).collect();
    let frac = first.plans[0].success_fraction;
    let per_class = rows
        .iter()
        .filter(|r| r.instance.class == PushClass::PushLeft)
        .count();
    let wall: f64 = rows.iter().flat_map(|r| &r.plans).map(|p| p.wall_s).sum();
    let _ = writeln!(md, "\n## Pushing and pulling powder (seed B's figure 3)\n");
    let _ = writeln!(
        md,
        "The push plans' recorded wall times sum to {wall:.0} s (a resumed plan records its \
         last run's time only).\n"
    );
    let _ = writeln!(
        md,
        "Scene: `scenes/plate_push.ron`: a patch of powder {PATCH_HEIGHT_MM} mm high on a plate, \
         a spatula with a blade 40 mm wide. {per_class} layouts, each set in the four classes \
         (the right classes mirrored about the plate's middle): the patch's centre x in \
         [{:.0}, {:.0}] mm and z in [{:.0}, {:.0}] mm, its size {:.0}–{:.0} mm along the stroke \
         and {:.0}–{:.0} mm across it (wider than the blade from 40 mm on), the region's \
         boundary {:.0}–{:.0} mm from \
         the plate's left edge for the left classes. Success is at least {:.0} % of the mass \
         in the region. Each stroke's optimiser is CMA-ES from the scripted stroke; scripted \
         is that straight stroke through the middle of the powder still outside, repeated.\n",
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
        PATCH_HEIGHT_MM = PATCH_HEIGHT * 1e3,
    );
    let mut head = String::from("| class |");
    let mut rule = String::from("|---|");
    for m in &methods {
        let _ = write!(
            head,
            " {} success | {} mass in region, mean | {} strokes, mean | {} rollouts, mean |",
            m.name(),
            m.name(),
            m.name(),
            m.name()
        );
        rule.push_str("---|---|---|---|");
    }
    let _ = writeln!(md, "{head}\n{rule}");
    for class in PushClass::ALL {
        let rs: Vec<&PushRow> = rows.iter().filter(|r| r.instance.class == class).collect();
        let n = rs.len();
        let mut line = format!("| {} |", class.name());
        for m in 0..methods.len() {
            let ok = rs.iter().filter(|r| r.plans[m].success).count();
            let mean = |f: &dyn Fn(&PushResult) -> f64| {
                rs.iter().map(|r| f(&r.plans[m])).sum::<f64>() / n as f64
            };
            let _ = write!(
                line,
                " {ok}/{n} ({:.0} %) | {:.1} % | {:.1} | {:.1} |",
                100.0 * ok as f64 / n as f64,
                100.0 * mean(&|p| p.in_region),
                mean(&|p| p.strokes.len() as f64),
                mean(&|p| p.rollouts as f64),
            );
        }
        let _ = writeln!(md, "{line}");
    }
    if let (Some(a), Some(b)) = (
        methods.iter().position(|m| *m == Method::Astar),
        methods.iter().position(|m| *m == Method::Scripted),
    ) {
        let sa: Vec<bool> = rows.iter().map(|r| r.plans[a].success).collect();
        let sb: Vec<bool> = rows.iter().map(|r| r.plans[b].success).collect();
        let _ = writeln!(
            md,
            "\nOver all {} instances: exact sign test p = {} that A\\* succeeds more often than \
             scripted (paired instances).",
            rows.len(),
            sign_test(&sa, &sb).map_or("– (no discordant pair)".into(), |p| format!("{p:.4}"))
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
