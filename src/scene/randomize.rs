//! A scene's `randomize` section: the ranges `powderlab policy` draws scenes from (domain
//! randomisation, docs/design.md §13). Every range is optional; a quantity without one keeps
//! the scene's value. Only the policy commands read it; every other command ignores it.
//!
//! A draw ([`Draw`]) holds every randomised quantity's value, the scene's own where it has no
//! range; [`Randomization::apply`] writes it into a copy of the scene.

use super::{ControlSpec, Fill, LossSpec, Scene, TargetValue};
use crate::error::FieldError;
use crate::materials::drucker_prager::DruckerPrager;
use crate::math::sdf::Shape;
use crate::util::SplitMix64;
use serde::{Deserialize, Serialize};

/// Ranges, each `(low, high)`, drawn uniformly (Young's modulus log-uniformly).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Randomization {
    /// The Cup container the powder fills and the skill scoops from. The scene's skill tool
    /// moves with it.
    pub source: String,
    /// The source's fill height (m); the skill's `surface_height` follows it.
    #[serde(default)]
    pub fill_height: Option<(f64, f64)>,
    /// Every Drucker–Prager material's friction angle (degrees).
    #[serde(default)]
    pub friction_deg: Option<(f64, f64)>,
    /// Every Drucker–Prager material's density (kg/m³).
    #[serde(default)]
    pub density: Option<(f64, f64)>,
    /// Every Drucker–Prager material's Young's modulus (Pa), drawn log-uniformly. A stiffer
    /// powder may need more substeps; the stability guard decides.
    #[serde(default)]
    pub youngs_modulus: Option<(f64, f64)>,
    /// The source cup's x position (m).
    #[serde(default)]
    pub source_x: Option<(f64, f64)>,
    /// The target cup's x minus the source cup's (m).
    #[serde(default)]
    pub cup_distance: Option<(f64, f64)>,
    /// The target mass (g) of the task and of the dosing loss.
    #[serde(default)]
    pub target_g: Option<(f64, f64)>,
    /// Draw the packing seed (the particles' jitter) too. Default true.
    #[serde(default = "yes")]
    pub packing_seed: bool,
}

fn yes() -> bool {
    true
}

/// One drawn scene: every quantity's value.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Draw {
    pub fill_height: f64,
    pub friction_deg: f64,
    pub density: f64,
    pub youngs_modulus: f64,
    pub source_x: f64,
    pub cup_distance: f64,
    pub target_g: f64,
    pub packing_seed: u64,
}

impl Draw {
    /// The names of [`Draw::values`], in order.
    pub const NAMES: [&'static str; 7] = [
        "fill_height",
        "friction_deg",
        "density",
        "youngs_modulus",
        "source_x",
        "cup_distance",
        "target_g",
    ];

    /// The continuous quantities, in the order of [`Draw::NAMES`].
    pub fn values(&self) -> [f64; 7] {
        [
            self.fill_height,
            self.friction_deg,
            self.density,
            self.youngs_modulus,
            self.source_x,
            self.cup_distance,
            self.target_g,
        ]
    }

    fn set(&mut self, i: usize, v: f64) {
        match i {
            0 => self.fill_height = v,
            1 => self.friction_deg = v,
            2 => self.density = v,
            3 => self.youngs_modulus = v,
            4 => self.source_x = v,
            5 => self.cup_distance = v,
            _ => self.target_g = v,
        }
    }
}

impl Randomization {
    /// The ranges in the order of [`Draw::NAMES`].
    fn ranges(&self) -> [Option<(f64, f64)>; 7] {
        [
            self.fill_height,
            self.friction_deg,
            self.density,
            self.youngs_modulus,
            self.source_x,
            self.cup_distance,
            self.target_g,
        ]
    }

    /// The scene's own values (what a quantity without a range keeps).
    pub fn base(&self, scene: &Scene) -> Draw {
        let dp = scene
            .materials
            .values()
            .find_map(|m| m.get::<DruckerPrager>());
        let x_of = |name: &str| {
            scene
                .colliders
                .iter()
                .find(|c| c.name == name)
                .map_or(0.0, |c| c.position.0)
        };
        let source_x = x_of(&self.source);
        let target = scene.task.as_ref().map_or("", |t| t.target.as_str());
        Draw {
            fill_height: self.source_fill(scene).unwrap_or(0.0),
            friction_deg: dp.map_or(30.0, |d| d.friction_deg),
            density: dp.map_or(1500.0, |d| d.density),
            youngs_modulus: dp.map_or(5e3, |d| d.youngs_modulus),
            source_x,
            cup_distance: x_of(target) - source_x,
            target_g: match scene.task.as_ref().map(|t| t.target_value) {
                Some(TargetValue::Grams(g)) => g,
                _ => 0.0,
            },
            packing_seed: scene.simulation.seed,
        }
    }

    fn source_fill(&self, scene: &Scene) -> Option<f64> {
        scene.bodies.iter().find_map(|b| match &b.fill {
            Fill::InsideContainer { container, height } if *container == self.source => {
                Some(*height)
            }
            _ => None,
        })
    }

    /// Draws a scene from `rng`.
    pub fn draw(&self, scene: &Scene, rng: &mut SplitMix64) -> Draw {
        let mut d = self.base(scene);
        for (i, r) in self.ranges().iter().enumerate() {
            // Every range consumes its number, so that a range added later does not shift the
            // draws of the others.
            let u = rng.uniform();
            if let Some((lo, hi)) = *r {
                d.set(i, lerp(i, lo, hi, u));
            }
        }
        let seed = rng.next_u64();
        if self.packing_seed {
            d.packing_seed = seed;
        }
        d
    }

    /// `d` moved by a normal step of `scale` times each range's width (in the range's own
    /// measure: log for Young's modulus), kept inside the ranges, with a new packing seed:
    /// seed B's perturbation for the cheap augmentation of a dataset.
    pub fn perturb(&self, d: &Draw, scale: f64, rng: &mut SplitMix64) -> Draw {
        let mut p = d.clone();
        let values = d.values();
        for (i, r) in self.ranges().iter().enumerate() {
            let z = rng.normal();
            if let Some((lo, hi)) = *r {
                let (a, b, v) = if i == 3 {
                    (lo.ln(), hi.ln(), values[i].ln())
                } else {
                    (lo, hi, values[i])
                };
                let moved = (v + scale * (b - a) * z).clamp(a.min(b), a.max(b));
                p.set(i, if i == 3 { moved.exp() } else { moved });
            }
        }
        let seed = rng.next_u64();
        if self.packing_seed {
            p.packing_seed = seed;
        }
        p
    }

    /// `scene` set to the draw: the source's fill height (and the skill's surface height with
    /// it), every Drucker–Prager material, the cups' x positions (the skill tool moves with
    /// the source), the target mass of the task and of a dosing loss, and the packing seed.
    pub fn apply(&self, scene: &Scene, d: &Draw) -> anyhow::Result<Scene> {
        let mut s = scene.clone();
        let base = self.base(scene);
        let raised = d.fill_height - base.fill_height;
        let shift = d.source_x - base.source_x;
        for b in &mut s.bodies {
            if let Fill::InsideContainer { container, height } = &mut b.fill {
                if *container == self.source {
                    *height = d.fill_height;
                }
            }
        }
        let target = s
            .task
            .as_ref()
            .map(|t| t.target.clone())
            .unwrap_or_default();
        for c in &mut s.colliders {
            if let Some(ControlSpec::Skill(sk)) = &mut c.control {
                sk.surface_height += raised;
                c.position.0 += shift;
            } else if c.name == self.source {
                c.position.0 = d.source_x;
            } else if c.name == target {
                c.position.0 = d.source_x + d.cup_distance;
            }
        }
        for m in s.materials.values_mut() {
            if let Some(dp) = m.get_mut::<DruckerPrager>() {
                dp.friction_deg = d.friction_deg;
                dp.density = d.density;
                dp.youngs_modulus = d.youngs_modulus;
            }
        }
        if let Some(t) = &mut s.task {
            t.target_value = TargetValue::Grams(d.target_g);
        }
        if let Some(LossSpec::Dosing { grams, .. }) = &mut s.loss {
            *grams = d.target_g;
        }
        s.simulation.seed = d.packing_seed;
        s.validate()?;
        Ok(s)
    }

    pub(super) fn validate(&self, scene: &Scene) -> Result<(), FieldError> {
        let at = |f: &str| format!("randomize.{f}");
        let is_cup = scene.colliders.iter().any(|c| {
            c.name == self.source
                && c.kind == super::ColliderKindSpec::Container
                && matches!(c.shape, Shape::Cup { .. })
        });
        if !is_cup || self.source_fill(scene).is_none() {
            return Err(FieldError::new(
                at("source"),
                format!("\"{}\"", self.source),
                "the name of a Cup container that a body fills (InsideContainer)",
            ));
        }
        if !matches!(
            scene.task.as_ref().map(|t| t.target_value),
            Some(TargetValue::Grams(_))
        ) {
            return Err(FieldError::new(
                "task",
                "not a mass",
                "Some((target: \"cup\", target_value: Grams(g))): a randomised scene doses a mass",
            ));
        }
        if crate::rollout::skill_tool(scene).is_err() {
            return Err(FieldError::new(
                "colliders",
                "no single tool with a Skill control",
                "one tool with a Skill control: the randomised scene is a skill's",
            ));
        }
        let limits: [(&str, f64, f64, &str); 7] = [
            ("fill_height", 0.0, f64::INFINITY, "> 0 m"),
            ("friction_deg", 0.0, 80.0, "in (0, 80) degrees"),
            ("density", 0.0, f64::INFINITY, "> 0 kg/m³"),
            ("youngs_modulus", 0.0, f64::INFINITY, "> 0 Pa"),
            (
                "source_x",
                f64::NEG_INFINITY,
                f64::INFINITY,
                "a finite x (m)",
            ),
            ("cup_distance", 0.0, f64::INFINITY, "> 0 m"),
            ("target_g", 0.0, f64::INFINITY, "> 0 g"),
        ];
        for (r, (name, lo, hi, what)) in self.ranges().iter().zip(limits) {
            let Some((a, b)) = *r else { continue };
            let ok = |v: f64| v.is_finite() && v > lo && v < hi;
            if !(ok(a) && ok(b)) {
                return Err(FieldError::new(
                    at(name),
                    format!("({a}, {b})"),
                    format!("both ends {what}"),
                ));
            }
            if a > b {
                return Err(FieldError::new(
                    at(name),
                    format!("({a}, {b})"),
                    "(low, high) with low <= high",
                ));
            }
        }
        // The farthest target cup must stay inside the domain's walls.
        let target = scene.task.as_ref().map_or("", |t| t.target.as_str());
        let Some(cup) = scene.colliders.iter().find(|c| c.name == target) else {
            return Ok(());
        };
        let radius = match cup.shape {
            Shape::Cup { outer_radius, .. } => outer_radius,
            _ => 0.0,
        };
        let base = self.base(scene);
        let far = self.source_x.map_or(base.source_x, |r| r.1)
            + self.cup_distance.map_or(base.cup_distance, |r| r.1)
            + radius;
        let sim = &scene.simulation;
        let inner = sim.domain_min.0 + (sim.cells.0 - sim.walls.cells) as f64 * sim.dx;
        if far > inner {
            return Err(FieldError::new(
                at("cup_distance"),
                self.cup_distance
                    .map_or("none".into(), |(a, b)| format!("({a}, {b})")),
                format!(
                    "ranges that keep the target cup's rim inside the walls: the farthest rim \
                     is at x = {far:.4} m, the walls begin at x = {inner:.4} m"
                ),
            ));
        }
        Ok(())
    }
}

/// Uniform between `lo` and `hi` at `u` ∈ [0, 1), log-uniform for Young's modulus (index 3).
fn lerp(i: usize, lo: f64, hi: f64, u: f64) -> f64 {
    if i == 3 {
        (lo.ln() + (hi.ln() - lo.ln()) * u).exp()
    } else {
        lo + (hi - lo) * u
    }
}
