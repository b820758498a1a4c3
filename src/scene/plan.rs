//! A scene's `plan` section: what `powderlab plan` searches for (docs/design.md §12). Only a
//! scene that is planned has one; every other command ignores it.

use super::{ColliderKindSpec, Scene, TargetValue};
use crate::error::FieldError;
use crate::math::sdf::Shape;
use serde::{Deserialize, Serialize};

/// What to plan.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub enum PlanSpec {
    /// Several scoops from `source` until the task's target cup holds the task's target mass
    /// (in grams) within `tolerance_g`.
    Dosing(DosingPlan),
}

/// Multi-scoop dosing: A* over scoops, each optimised from the powder the last one left.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DosingPlan {
    /// The cup the spoon scoops from (a Cup container). The scene's spoon starts above it; an
    /// entry point moves the spoon's start by the point's offset from the cup's axis.
    pub source: String,
    /// The dose counts as delivered within this many grams of the target. Default 0.1.
    #[serde(default = "default_tolerance")]
    pub tolerance_g: f64,
    /// The most one scoop can deliver (g): the heuristic divides the remaining mass by it, so
    /// it must not be smaller than any scoop's load for A*'s plan to be a shortest one.
    pub spoon_capacity_g: f64,
    /// A scoop that is not the last succeeds when it delivers at least this much without
    /// passing the target. Default 0.5 g.
    #[serde(default = "default_min_progress")]
    pub min_progress_g: f64,
    /// Forward rollouts the optimiser spends on one scoop (`OptWrench`). Default 10.
    #[serde(default = "default_scoop_budget")]
    pub scoop_budget: usize,
    /// Nodes A* expands at most. Default 8.
    #[serde(default = "default_expansions")]
    pub max_expansions: usize,
    /// Scoops a plan may take at most (greedy and scripted stop there too). Default 6.
    #[serde(default = "default_max_scoops")]
    pub max_scoops: usize,
    /// Entry points `ContactLoc` proposes. Default 3.
    #[serde(default = "default_entries")]
    pub entries: usize,
    /// Distance an entry point keeps from the source cup's inner wall (m). Default 0.02.
    #[serde(default = "default_clearance")]
    pub clearance: f64,
    /// Distance between two proposed entry points (m). Default 0.004.
    #[serde(default = "default_spacing")]
    pub spacing: f64,
    /// Cost of moving the spoon to another entry, in scoops. Default 0.1.
    #[serde(default = "default_move_cost")]
    pub move_cost: f64,
    /// The chance that a node's entry is also relocated after a successful scoop (seed B's
    /// random contact transition). Default 0.1.
    #[serde(default = "default_explore")]
    pub explore: f64,
}

fn default_tolerance() -> f64 {
    0.1
}
fn default_min_progress() -> f64 {
    0.5
}
fn default_scoop_budget() -> usize {
    10
}
fn default_expansions() -> usize {
    8
}
fn default_max_scoops() -> usize {
    6
}
fn default_entries() -> usize {
    3
}
fn default_clearance() -> f64 {
    0.02
}
fn default_spacing() -> f64 {
    0.004
}
fn default_move_cost() -> f64 {
    0.1
}
fn default_explore() -> f64 {
    0.1
}

/// Most rollouts one scoop's optimiser may spend, and nodes a search may expand: beyond them a
/// plan runs for days.
pub const MAX_PLAN_BUDGET: usize = 10_000;

impl DosingPlan {
    /// The source cup's inner radius (m).
    pub fn source_radius(&self, scene: &Scene) -> Option<f64> {
        scene
            .colliders
            .iter()
            .find(|c| c.name == self.source)
            .and_then(|c| match c.shape {
                Shape::Cup {
                    outer_radius,
                    wall_thickness,
                    ..
                } => Some(outer_radius - wall_thickness),
                _ => None,
            })
    }

    pub(super) fn validate(&self, scene: &Scene) -> Result<(), FieldError> {
        let at = |f: &str| format!("plan.{f}");
        let source = scene.colliders.iter().find(|c| c.name == self.source);
        let is_cup = source.is_some_and(|c| {
            c.kind == ColliderKindSpec::Container && matches!(c.shape, Shape::Cup { .. })
        });
        if !is_cup {
            return Err(FieldError::new(
                at("source"),
                format!("\"{}\"", self.source),
                "the name of a Cup container to scoop from",
            ));
        }
        match scene.task.as_ref().map(|t| (t.target_value, &t.target)) {
            Some((TargetValue::Grams(_), target)) if *target != self.source => {}
            Some((TargetValue::Grams(_), _)) => {
                return Err(FieldError::new(
                    at("source"),
                    format!("\"{}\"", self.source),
                    "a cup other than the task's target",
                ))
            }
            _ => {
                return Err(FieldError::new(
                    "task",
                    format!("{:?}", scene.task.as_ref().map(|t| t.target_value)),
                    "Some((target: \"cup\", target_value: Grams(g))): a dosing plan needs a \
                     target mass",
                ))
            }
        }
        let positive = |f: &str, v: f64| -> Result<(), FieldError> {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(FieldError::new(at(f), v.to_string(), "> 0"))
            }
        };
        positive("tolerance_g", self.tolerance_g)?;
        positive("spoon_capacity_g", self.spoon_capacity_g)?;
        positive("spacing", self.spacing)?;
        if !(self.min_progress_g.is_finite() && self.min_progress_g >= 0.0) {
            return Err(FieldError::new(
                at("min_progress_g"),
                self.min_progress_g.to_string(),
                ">= 0 g",
            ));
        }
        if !(self.move_cost.is_finite() && self.move_cost >= 0.0) {
            return Err(FieldError::new(
                at("move_cost"),
                self.move_cost.to_string(),
                ">= 0 scoops",
            ));
        }
        if !(0.0..=1.0).contains(&self.explore) {
            return Err(FieldError::new(
                at("explore"),
                self.explore.to_string(),
                "a chance in [0, 1]",
            ));
        }
        for (f, v) in [
            ("scoop_budget", self.scoop_budget),
            ("max_expansions", self.max_expansions),
            ("max_scoops", self.max_scoops),
            ("entries", self.entries),
        ] {
            if !(1..=MAX_PLAN_BUDGET).contains(&v) {
                return Err(FieldError::new(
                    at(f),
                    v.to_string(),
                    format!("a whole number from 1 to {MAX_PLAN_BUDGET}"),
                ));
            }
        }
        let radius = self.source_radius(scene).expect("checked above");
        if !(self.clearance.is_finite() && (0.0..radius).contains(&self.clearance)) {
            return Err(FieldError::new(
                at("clearance"),
                self.clearance.to_string(),
                format!(
                    "in [0, {radius}) m: the source cup's inner radius bounds the entry points"
                ),
            ));
        }
        Ok(())
    }
}
