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
    /// Strokes of the scene's spatula until `success_fraction` of the powder lies on the
    /// `plate` beyond `boundary` on the class's side (seed B's four something-something
    /// classes).
    Push(PushPlan),
}

/// Seed B's four classes: the side the powder goes to, and whether the robot pushes it away
/// (the spatula's handle leans back, against the stroke) or pulls it toward itself (the
/// handle leans ahead, along the stroke). Either way the blade lands on the far side of the
/// powder from the region and strokes toward it.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
pub enum PushClass {
    PushLeft,
    PushRight,
    PullLeft,
    PullRight,
}

impl PushClass {
    pub const ALL: [PushClass; 4] = [
        PushClass::PushLeft,
        PushClass::PushRight,
        PushClass::PullLeft,
        PushClass::PullRight,
    ];
    /// The region's side along x: −1 for left (toward −x), +1 for right.
    pub fn side(self) -> f64 {
        match self {
            PushClass::PushLeft | PushClass::PullLeft => -1.0,
            _ => 1.0,
        }
    }
    pub fn pulls(self) -> bool {
        matches!(self, PushClass::PullLeft | PushClass::PullRight)
    }
    pub fn name(self) -> &'static str {
        match self {
            PushClass::PushLeft => "push left",
            PushClass::PushRight => "push right",
            PushClass::PullLeft => "pull left",
            PushClass::PullRight => "pull right",
        }
    }
}

/// Pushing or pulling powder into a region with a spatula: A* over optimised strokes.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PushPlan {
    /// The plate the powder lies on (a Box container); the region is its part beyond
    /// `boundary`.
    pub plate: String,
    pub class: PushClass,
    /// The region's edge along x (m): the region is the plate's part at smaller x (left) or
    /// larger x (right).
    pub boundary: f64,
    /// The share of the powder's mass that must lie in the region. Default 0.9.
    #[serde(default = "default_success_fraction")]
    pub success_fraction: f64,
    /// A stroke that does not reach success must move at least this share into the region to
    /// count. Default 0.05.
    #[serde(default = "default_min_gain")]
    pub min_gain: f64,
    /// Forward rollouts the optimiser spends on one stroke. Default 6.
    #[serde(default = "default_stroke_budget")]
    pub stroke_budget: usize,
    /// Nodes A* expands at most. Default 4.
    #[serde(default = "default_push_expansions")]
    pub max_expansions: usize,
    /// Strokes a plan may take at most. Default 4.
    #[serde(default = "default_max_strokes")]
    pub max_strokes: usize,
    /// Contacts `ContactLoc` proposes (bands of the powder still outside, across the stroke).
    /// Default 2.
    #[serde(default = "default_contacts")]
    pub contacts: usize,
    /// The handle's lean from the vertical (degrees). Default 20.
    #[serde(default = "default_lean")]
    pub lean_deg: f64,
    /// The spatula's speed (m/s). Default 0.1.
    #[serde(default = "default_speed")]
    pub speed: f64,
    /// Cost of moving the contact, in strokes. Default 0.1.
    #[serde(default = "default_move_cost")]
    pub move_cost: f64,
    /// The chance that a node's contact is also relocated after a successful stroke. Default
    /// 0.1.
    #[serde(default = "default_explore")]
    pub explore: f64,
    /// Each stroke's optimiser (`OptWrench`). Default `Cma`.
    #[serde(default)]
    pub optimiser: StrokeOptimiser,
    /// Where strokes aim (`ContactLoc`). Default `Median`.
    #[serde(default)]
    pub aim: Aim,
    /// A*'s heuristic. Default `Unit`.
    #[serde(default)]
    pub heuristic: Heuristic,
}

/// Where a push plan's strokes aim across the stroke.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, PartialEq, Eq)]
pub enum Aim {
    /// The median z of the powder outside; `ContactLoc` offers the medians of `contacts`
    /// equal-count bands.
    #[default]
    Median,
    /// Bands no wider than the blade across the powder outside, the one holding the most mass
    /// weighted by its distance from the region first; `ContactLoc` offers the others (at
    /// least `contacts` bands), so a patch wider than the blade takes side-by-side strokes.
    Bands,
}

/// A push plan's A* heuristic.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, PartialEq, Eq)]
pub enum Heuristic {
    /// 1 until success (admissible: every stroke costs 1).
    #[default]
    Unit,
    /// The share still needed over the largest share one stroke's swept band holds: ranks
    /// nodes by what is left to move. Admissible only while a stroke moves no grain from
    /// outside its band.
    Strokes,
}

/// How `OptWrench` optimises a stroke.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, PartialEq, Eq)]
pub enum StrokeOptimiser {
    /// CMA-ES on the soft share outside, from the scripted stroke.
    #[default]
    Cma,
    /// Line searches along the push loss's gradient by the adjoint, from the scripted stroke.
    Gradient,
}

impl StrokeOptimiser {
    pub const ALL: [StrokeOptimiser; 2] = [StrokeOptimiser::Cma, StrokeOptimiser::Gradient];
    pub fn name(self) -> &'static str {
        match self {
            StrokeOptimiser::Cma => "cma",
            StrokeOptimiser::Gradient => "gradient",
        }
    }
}

fn default_success_fraction() -> f64 {
    0.9
}
fn default_min_gain() -> f64 {
    0.05
}
fn default_stroke_budget() -> usize {
    6
}

impl PushPlan {
    /// The stroke budget a plan has when the scene gives none.
    pub fn default_budget() -> usize {
        default_stroke_budget()
    }
}
fn default_push_expansions() -> usize {
    4
}
fn default_max_strokes() -> usize {
    4
}
fn default_contacts() -> usize {
    2
}
fn default_lean() -> f64 {
    20.0
}
fn default_speed() -> f64 {
    0.1
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

impl PushPlan {
    /// The plate's box: its centre and half extents (world frame; the plate is not rotated).
    pub fn plate_box(&self, scene: &Scene) -> Option<(glam::DVec3, glam::DVec3)> {
        scene
            .colliders
            .iter()
            .find(|c| c.name == self.plate)
            .and_then(|c| match c.shape {
                Shape::Box { half_extents } if c.rotation_deg == (0.0, 0.0, 0.0) => Some((
                    glam::DVec3::from(c.position),
                    glam::DVec3::from(half_extents),
                )),
                _ => None,
            })
    }

    pub(super) fn validate(&self, scene: &Scene) -> Result<(), FieldError> {
        let at = |f: &str| format!("plan.{f}");
        let Some((c, h)) = self.plate_box(scene) else {
            return Err(FieldError::new(
                at("plate"),
                format!("\"{}\"", self.plate),
                "the name of an unrotated Box container the powder lies on",
            ));
        };
        let tools: Vec<_> = scene
            .colliders
            .iter()
            .filter(|c| matches!(c.shape, Shape::Spatula { .. }))
            .collect();
        if tools.len() != 1 || tools[0].kind != ColliderKindSpec::Tool {
            return Err(FieldError::new(
                "colliders",
                format!("{} spatulas", tools.len()),
                "exactly one Tool with a Spatula shape: the plan strokes it",
            ));
        }
        if !(self.boundary > c.x - h.x && self.boundary < c.x + h.x) {
            return Err(FieldError::new(
                at("boundary"),
                self.boundary.to_string(),
                format!(
                    "inside the plate's extent along x, ({}, {}) m",
                    c.x - h.x,
                    c.x + h.x
                ),
            ));
        }
        for (f, v) in [
            ("success_fraction", self.success_fraction),
            ("min_gain", self.min_gain),
            ("explore", self.explore),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(FieldError::new(at(f), v.to_string(), "in [0, 1]"));
            }
        }
        for (f, v) in [("lean_deg", self.lean_deg), ("move_cost", self.move_cost)] {
            if !(v.is_finite() && (0.0..80.0).contains(&v)) {
                return Err(FieldError::new(at(f), v.to_string(), "in [0, 80)"));
            }
        }
        if !(self.speed.is_finite() && self.speed > 0.0 && self.speed <= 10.0) {
            return Err(FieldError::new(
                at("speed"),
                self.speed.to_string(),
                "in (0, 10] m/s",
            ));
        }
        for (f, v) in [
            ("stroke_budget", self.stroke_budget),
            ("max_expansions", self.max_expansions),
            ("max_strokes", self.max_strokes),
            ("contacts", self.contacts),
        ] {
            if !(1..=MAX_PLAN_BUDGET).contains(&v) {
                return Err(FieldError::new(
                    at(f),
                    v.to_string(),
                    format!("a whole number from 1 to {MAX_PLAN_BUDGET}"),
                ));
            }
        }
        Ok(())
    }
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
