//! The physical parameters a calibration fits, each mapped to a unit interval.
//!
//! `--fit` names them:
//! - `PARAM` (`friction_deg`, `youngs_modulus`, `poisson_ratio`, or any differentiable parameter
//!   a material declares): the parameter of the one material that declares it and that a body
//!   uses; with several such materials, name one: `MATERIAL.PARAM`;
//! - `COLLIDER.friction`: a collider's Coulomb friction.
//!
//! The optimisers work on `u ∈ [0, 1]` per parameter: `v = lo + u(hi − lo)`, or for a parameter
//! that spans decades (Young's modulus) `ln v = ln lo + u(ln hi − ln lo)`, so that a step in `u`
//! is a like change in every parameter, and the box is the search's bounds.

use crate::adjoint::tape::Gradients;
use crate::scene::Scene;

/// What a fitted parameter sets.
#[derive(Clone, Debug, PartialEq)]
pub enum Target {
    /// Parameter `index` of material `name`'s `PARAMS`.
    Material { name: String, index: usize },
    /// The friction of collider `index` (scene order).
    ColliderFriction { index: usize },
}

/// A fitted parameter and its bounds.
#[derive(Clone, Debug, PartialEq)]
pub struct FitParam {
    /// How reports name it: `sand.friction_deg`, `floor.friction`.
    pub label: String,
    pub target: Target,
    pub lo: f64,
    pub hi: f64,
    /// Whether `u` maps to `ln v` (decades) instead of `v`.
    pub log: bool,
}

impl FitParam {
    /// The parameter's value in `scene`.
    pub fn value(&self, scene: &Scene) -> f64 {
        match &self.target {
            Target::Material { name, index } => scene.materials[name].param(*index),
            Target::ColliderFriction { index } => scene.colliders[*index].friction,
        }
    }

    /// Sets it in `scene`.
    pub fn apply(&self, scene: &mut Scene, v: f64) {
        match &self.target {
            Target::Material { name, index } => {
                let m = scene.materials[name].with_param(*index, v);
                scene.materials.insert(name.clone(), m);
            }
            Target::ColliderFriction { index } => scene.colliders[*index].friction = v,
        }
    }

    /// `v(u)`.
    pub fn from_unit(&self, u: f64) -> f64 {
        if self.log {
            (self.lo.ln() + u * (self.hi.ln() - self.lo.ln())).exp()
        } else {
            self.lo + u * (self.hi - self.lo)
        }
    }

    /// `u(v)`.
    pub fn to_unit(&self, v: f64) -> f64 {
        if self.log {
            (v.ln() - self.lo.ln()) / (self.hi.ln() - self.lo.ln())
        } else {
            (v - self.lo) / (self.hi - self.lo)
        }
    }

    /// `dv/du` at `u`.
    pub fn dvalue_du(&self, u: f64) -> f64 {
        if self.log {
            self.from_unit(u) * (self.hi.ln() - self.lo.ln())
        } else {
            self.hi - self.lo
        }
    }

    /// `∂L/∂v` from a backward pass of `scene`: the sum over the bodies made of the material.
    pub fn gradient(&self, scene: &Scene, g: &Gradients) -> f64 {
        match &self.target {
            Target::Material { name, index } => scene
                .bodies
                .iter()
                .enumerate()
                .filter(|(_, b)| &b.material == name)
                .map(|(i, _)| g.material[i].0[*index])
                .sum(),
            Target::ColliderFriction { index } => {
                let c = &scene.colliders[*index].name;
                g.friction
                    .iter()
                    .find(|(n, _)| n == c)
                    .map_or(0.0, |(_, d)| *d)
            }
        }
    }
}

/// The default bounds of a parameter at its scene value `v`: (lo, hi, log).
fn default_bounds(param: &str, v: f64) -> (f64, f64, bool) {
    match param {
        "friction_deg" => (10.0, 60.0, false),
        "poisson_ratio" => (0.05, 0.45, false),
        "friction" => (0.0, 1.5, false),
        // A powder's cohesion at the scale of a vial: from none to a heap that stands upright
        // (`validate repose`: 10 Pa stands a 12 mm heap at 60°).
        "cohesion" => (0.0, 20.0, false),
        // Stiffness, and any other positive parameter: a decade and a half either way.
        _ if v > 0.0 => (v / 30.0, v * 30.0, true),
        _ => (v - 1.0, v + 1.0, false),
    }
}

/// Parses `--fit` (comma-separated names, see the module docs) and `--bounds NAME=LO:HI`
/// overrides against `scene`. Errors are one line naming the flag and the value.
pub fn parse(scene: &Scene, fit: &[String], bounds: &[String]) -> Result<Vec<FitParam>, String> {
    if fit.is_empty() {
        return Err("--fit: name at least one parameter, e.g. --fit friction_deg".into());
    }
    let used: Vec<&String> = scene
        .materials
        .keys()
        .filter(|m| scene.bodies.iter().any(|b| &b.material == *m))
        .collect();
    let mut out: Vec<FitParam> = Vec::new();
    for name in fit {
        let (owner, param) = match name.split_once('.') {
            Some((o, p)) => (Some(o), p),
            None => (None, name.as_str()),
        };
        let p = if param == "friction" && owner.is_some() {
            let c = owner.unwrap_or_default();
            let index = scene
                .colliders
                .iter()
                .position(|x| x.name == c)
                .ok_or_else(|| {
                    let names: Vec<&str> =
                        scene.colliders.iter().map(|x| x.name.as_str()).collect();
                    format!("--fit {name}: the scene has no collider '{c}' (it has {names:?})")
                })?;
            FitParam {
                label: name.clone(),
                target: Target::ColliderFriction { index },
                lo: 0.0,
                hi: 0.0,
                log: false,
            }
        } else {
            let candidates: Vec<&String> = used
                .iter()
                .copied()
                .filter(|m| owner.is_none_or(|o| o == m.as_str()))
                .filter(|m| scene.materials[*m].params().iter().any(|q| q.name == param))
                .collect();
            let m = match candidates.as_slice() {
                [m] => (*m).clone(),
                [] => {
                    let what = owner.map_or("no material a body uses".to_string(), |o| {
                        format!("material '{o}' (used by a body)")
                    });
                    return Err(format!(
                        "--fit {name}: {what} has a differentiable parameter '{param}'; use one of friction_deg, youngs_modulus, poisson_ratio, or COLLIDER.friction"
                    ));
                }
                many => {
                    return Err(format!(
                        "--fit {name}: materials {many:?} all have it; name one, e.g. {}.{param}",
                        many[0]
                    ))
                }
            };
            let index = scene.materials[&m]
                .params()
                .iter()
                .position(|q| q.name == param)
                .expect("filtered on it");
            FitParam {
                label: format!("{m}.{param}"),
                target: Target::Material { name: m, index },
                lo: 0.0,
                hi: 0.0,
                log: false,
            }
        };
        if out.iter().any(|q| q.target == p.target) {
            return Err(format!("--fit {name}: named twice"));
        }
        out.push(p);
    }
    for p in &mut out {
        let short = p.label.rsplit('.').next().unwrap_or_default();
        let (lo, hi, log) = default_bounds(short, p.value(scene));
        (p.lo, p.hi, p.log) = (lo, hi, log);
    }
    for b in bounds {
        let bad =
            || format!("--bounds {b}: expected NAME=LO:HI with LO < HI, e.g. friction_deg=15:50");
        let (name, range) = b.split_once('=').ok_or_else(bad)?;
        let (lo, hi) = range.split_once(':').ok_or_else(bad)?;
        let (lo, hi): (f64, f64) = (
            lo.trim().parse().map_err(|_| bad())?,
            hi.trim().parse().map_err(|_| bad())?,
        );
        if !(lo.is_finite() && hi.is_finite() && lo < hi) {
            return Err(bad());
        }
        let p = out
            .iter_mut()
            .find(|p| p.label == name || p.label.ends_with(&format!(".{name}")))
            .ok_or_else(|| format!("--bounds {b}: '{name}' is not one of the --fit parameters"))?;
        if p.log && lo <= 0.0 {
            return Err(format!(
                "--bounds {b}: {} is searched in decades, so its bounds must be positive",
                p.label
            ));
        }
        (p.lo, p.hi) = (lo, hi);
    }
    Ok(out)
}
