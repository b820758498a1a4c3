//! Every field's range and every cross-reference of a scene, checked after parsing. An error
//! names the field, its value and what is expected; [`Scene::field_error`] adds its position.

use super::*;
use crate::error::{FieldError, SceneError};
use crate::math::sdf::Shape;
use crate::skills::SkillSpec;

// Admissible ranges: what the model can run, not merely what is finite. Each is documented in
// scenes/README.md.

/// Smallest cell (m): a micron, below any powder's grain.
pub const MIN_DX: f64 = 1e-6;
/// Largest cell (m).
pub const MAX_DX: f64 = 10.0;
/// Largest step (s).
pub const MAX_DT: f64 = 10.0;
/// Largest |coordinate| of the domain's corner or a collider (m).
pub const MAX_COORDINATE: f64 = 1e3;
/// Largest |gravity| component (m/s²): a thousand g.
pub const MAX_GRAVITY: f64 = 1e4;
/// Largest |initial velocity| component of a body (m/s).
pub const MAX_SPEED: f64 = 1e3;
/// Largest Coulomb friction coefficient: from about 2 on every contact sticks, so a larger one
/// changes nothing but is likely a slip (degrees for a coefficient).
pub const MAX_FRICTION: f64 = 10.0;
const FRICTION_RANGE: &str = "a Coulomb coefficient in [0, 10] (every contact sticks from about 2)";
/// Most particles per cell (10 per axis); more are refused before the memory check.
pub const MAX_PARTICLES_PER_CELL: usize = 1000;

impl Scene {
    /// Checks every field (what [`Scene::parse`] does after parsing): for scenes edited in code.
    pub fn validate(&self) -> Result<(), SceneError> {
        self.validate_fields().map_err(|e| self.field_error(e))
    }

    fn validate_fields(&self) -> Result<(), FieldError> {
        let s = &self.simulation;
        let pos = |f: &str, v: f64, ok: bool, exp: &str| -> Result<(), FieldError> {
            if ok && v.is_finite() {
                Ok(())
            } else {
                Err(FieldError::new(f, crate::error::num(v), exp))
            }
        };
        pos(
            "simulation.dx",
            s.dx,
            (MIN_DX..=MAX_DX).contains(&s.dx),
            &format!("in [{MIN_DX:e}, {MAX_DX}] m"),
        )?;
        pos(
            "simulation.dt",
            s.dt,
            s.dt > 0.0 && s.dt <= MAX_DT,
            &format!("in (0, {MAX_DT}] s"),
        )?;
        pos(
            "simulation.cfl",
            s.cfl,
            s.cfl > 0.0 && s.cfl <= 1.0,
            "in (0, 1]",
        )?;
        pos(
            "simulation.empty_node_ratio",
            s.empty_node_ratio,
            s.empty_node_ratio >= 0.0 && s.empty_node_ratio < 1.0,
            "in [0, 1)",
        )?;
        if s.substeps == 0 || s.substeps > MAX_AUTO_SUBSTEPS {
            return Err(FieldError::new(
                "simulation.substeps",
                s.substeps.to_string(),
                format!("in [1, {MAX_AUTO_SUBSTEPS}] (the most stability: Auto ever takes)"),
            ));
        }
        if s.walls.cells == 0 {
            return Err(FieldError::new(
                "simulation.walls.cells",
                "0",
                ">= 1: the wall layer is what keeps the particles inside the grid",
            ));
        }
        if s.threads > MAX_THREADS {
            return Err(FieldError::new(
                "simulation.threads",
                s.threads.to_string(),
                format!("<= {MAX_THREADS} (0 uses all cores)"),
            ));
        }
        let (nx, ny, nz) = s.cells;
        let min_cells = 2 * s.walls.cells.max(1) + 3;
        for (axis, n) in [("x", nx), ("y", ny), ("z", nz)] {
            if n < min_cells || n > 4096 {
                return Err(FieldError::new(
                    "simulation.cells",
                    format!("{n} along {axis}"),
                    format!("between {min_cells} (twice the wall cells plus 3) and 4096"),
                ));
            }
        }
        for (name, v, max, unit) in [
            ("simulation.domain_min", s.domain_min, MAX_COORDINATE, "m"),
            ("simulation.gravity", s.gravity, MAX_GRAVITY, "m/s²"),
        ] {
            if ![v.0, v.1, v.2].iter().all(|x| x.abs() <= max) {
                return Err(FieldError::new(
                    name,
                    format!("{v:?}"),
                    format!("components in [-{max}, {max}] {unit}"),
                ));
            }
        }
        pos(
            "simulation.walls.friction",
            s.walls.friction,
            (0.0..=MAX_FRICTION).contains(&s.walls.friction),
            FRICTION_RANGE,
        )?;
        for (name, m) in &self.materials {
            m.validate()
                .map_err(|e| e.within(&format!("materials.{name}")))?;
        }
        let mut names = std::collections::HashSet::new();
        for (i, c) in self.colliders.iter().enumerate() {
            let at = format!("colliders[{i}]");
            if !names.insert(c.name.clone()) {
                return Err(FieldError::new(
                    format!("{at}.name"),
                    &c.name,
                    "a unique name",
                ));
            }
            pos(
                &format!("{at}.friction"),
                c.friction,
                (0.0..=MAX_FRICTION).contains(&c.friction),
                FRICTION_RANGE,
            )?;
            let r = c.rotation_deg;
            if ![r.0, r.1, r.2].iter().all(|a| a.abs() <= 360.0) {
                return Err(FieldError::new(
                    format!("{at}.rotation_deg"),
                    format!("{r:?}"),
                    "angles in [-360, 360] degrees",
                ));
            }
            pos(
                &format!("{at}.band_cells"),
                c.band_cells,
                c.band_cells >= 0.0,
                ">= 0 cells",
            )?;
            c.shape
                .validate()
                .map_err(|e| e.within(&format!("{at}.shape")))?;
            let p = c.position;
            if ![p.0, p.1, p.2].iter().all(|x| x.abs() <= MAX_COORDINATE) {
                return Err(FieldError::new(
                    format!("{at}.position"),
                    format!("{p:?}"),
                    format!("coordinates in [-{MAX_COORDINATE}, {MAX_COORDINATE}] m"),
                ));
            }
            match (c.kind, &c.control) {
                (ColliderKindSpec::Container, Some(_)) => {
                    return Err(FieldError::new(
                        format!("{at}.control"),
                        "Some(..)",
                        "no control: containers are static (use kind: Tool)",
                    ))
                }
                (_, Some(ControlSpec::Skill(sk))) => {
                    sk.validate()
                        .map_err(|e| e.within(&format!("{at}.control")))?;
                    skill_horizon(sk, c, s.dt).map_err(|e| e.within(&format!("{at}.control")))?;
                }
                (_, Some(ControlSpec::Constant { steps, .. }))
                    if *steps > crate::skills::MAX_CONTROL_STEPS =>
                {
                    return Err(FieldError::new(
                        format!("{at}.control.steps"),
                        steps.to_string(),
                        format!(
                            "at most {} steps (the per-step controls are held in memory)",
                            crate::skills::MAX_CONTROL_STEPS
                        ),
                    ));
                }
                (_, Some(ControlSpec::Actions(a))) => {
                    if let Some(k) = a.iter().position(|u| !u.iter().all(|x| x.is_finite())) {
                        return Err(FieldError::new(
                            format!("{at}.control"),
                            format!("action {k}"),
                            "finite numbers",
                        ));
                    }
                }
                _ => {}
            }
        }
        for (i, b) in self.bodies.iter().enumerate() {
            let at = format!("bodies[{i}]");
            if !self.materials.contains_key(&b.material) {
                return Err(FieldError::new(
                    format!("{at}.material"),
                    format!("\"{}\"", b.material),
                    format!(
                        "one of the names in `materials`: {:?}",
                        self.materials.keys().collect::<Vec<_>>()
                    ),
                ));
            }
            let ppa = (b.particles_per_cell as f64).cbrt().round() as usize;
            if ppa == 0
                || ppa * ppa * ppa != b.particles_per_cell
                || b.particles_per_cell > MAX_PARTICLES_PER_CELL
            {
                return Err(FieldError::new(
                    format!("{at}.particles_per_cell"),
                    b.particles_per_cell.to_string(),
                    format!("a cube number up to {MAX_PARTICLES_PER_CELL}: 1, 8, 27, 64, …"),
                ));
            }
            if let Lattice::Jittered(j) = b.lattice {
                pos(
                    &format!("{at}.lattice"),
                    j,
                    (0.0..=1.0).contains(&j),
                    "a jitter in [0, 1] of the spacing",
                )?;
            }
            match &b.fill {
                Fill::InsideContainer { container, height } => {
                    let c = self.colliders.iter().find(|c| &c.name == container);
                    if !matches!(c.map(|c| &c.shape), Some(Shape::Cup { .. })) {
                        return Err(FieldError::new(
                            format!("{at}.fill.container"),
                            format!("\"{container}\""),
                            "the name of a Cup collider",
                        ));
                    }
                    pos(
                        &format!("{at}.fill.height"),
                        *height,
                        *height > 0.0,
                        "> 0 m",
                    )?;
                }
                Fill::Box { min, max } => {
                    if !(min.0 < max.0 && min.1 < max.1 && min.2 < max.2) {
                        return Err(FieldError::new(
                            format!("{at}.fill.max"),
                            format!("{max:?}"),
                            format!("greater than min {min:?} on every axis"),
                        ));
                    }
                }
                Fill::Column {
                    length,
                    aspect,
                    depth,
                    ..
                } => {
                    pos(
                        &format!("{at}.fill.length"),
                        *length,
                        *length > 0.0,
                        "> 0 m",
                    )?;
                    pos(&format!("{at}.fill.aspect"), *aspect, *aspect > 0.0, "> 0")?;
                    pos(&format!("{at}.fill.depth"), *depth, *depth > 0.0, "> 0 m")?;
                }
                Fill::Cylinder { radius, height, .. } => {
                    pos(
                        &format!("{at}.fill.radius"),
                        *radius,
                        *radius > 0.0,
                        "> 0 m",
                    )?;
                    pos(
                        &format!("{at}.fill.height"),
                        *height,
                        *height > 0.0,
                        "> 0 m",
                    )?;
                }
            }
            let v = b.velocity;
            if ![v.0, v.1, v.2].iter().all(|x| x.abs() <= MAX_SPEED) {
                return Err(FieldError::new(
                    format!("{at}.velocity"),
                    format!("{v:?}"),
                    format!("components in [-{MAX_SPEED}, {MAX_SPEED}] m/s"),
                ));
            }
        }
        if let Some(t) = &self.task {
            if !self
                .colliders
                .iter()
                .any(|c| c.name == t.target && matches!(c.shape, Shape::Cup { .. }))
            {
                return Err(FieldError::new(
                    "task.target",
                    format!("\"{}\"", t.target),
                    "the name of a Cup collider",
                ));
            }
            let (amount, unit) = match t.target_value {
                TargetValue::Particles(n) => (n, "particles"),
                TargetValue::Grams(g) => (g, "g"),
            };
            pos(
                "task.target_value",
                amount,
                amount >= 0.0,
                &format!(">= 0 {unit}, a finite amount of powder"),
            )?;
        }
        if let Some(b) = &self.balance {
            if !self.colliders.iter().any(|c| {
                c.name == b.container
                    && c.kind == ColliderKindSpec::Container
                    && matches!(c.shape, Shape::Cup { .. })
            }) {
                return Err(FieldError::new(
                    "balance.container",
                    format!("\"{}\"", b.container),
                    "the name of a Cup collider of kind Container (the weighing boat)",
                ));
            }
            pos(
                "balance.resolution_mg",
                b.resolution_mg,
                b.resolution_mg > 0.0,
                "> 0 mg (an analytical balance shows 0.1 mg)",
            )?;
            pos(
                "balance.noise_mg",
                b.noise_mg,
                b.noise_mg >= 0.0,
                ">= 0 mg (0 for a noiseless reading)",
            )?;
            pos(
                "balance.settle_s",
                b.settle_s,
                b.settle_s > 0.0,
                "> 0 s (a time constant; an analytical balance's is about 0.5 s)",
            )?;
        }
        if let Some(LossSpec::Dosing { grams, width }) = self.loss {
            if self.task.is_none() {
                return Err(FieldError::new(
                    "loss",
                    "Dosing(..)",
                    "a scene with a `task` naming the target cup",
                ));
            }
            pos("loss.grams", grams, grams > 0.0, "> 0 g")?;
            if let Some(w) = width {
                pos("loss.width", w, w > 0.0, "> 0 m")?;
            }
        }
        if let Some(r) = &self.record {
            if r.every == 0 {
                return Err(FieldError::new("record.every", "0", ">= 1 step"));
            }
            if let Some(rad) = r.point_radius {
                pos("record.point_radius", rad, rad > 0.0, "> 0 m")?;
            }
        }
        match &self.plan {
            Some(super::plan::PlanSpec::Dosing(d)) => d.validate(self)?,
            Some(super::plan::PlanSpec::Push(p)) => p.validate(self)?,
            None => {}
        }
        if let Some(r) = &self.randomize {
            r.validate(self)?;
        }
        // Behind the range checks above: any other field that is NaN or infinite (a rotation, a
        // loss target, a recording option) would reach the simulation as a silent NaN.
        if let Some((field, v)) = crate::nonfinite::first_nonfinite(self) {
            return Err(FieldError::new(field, v.to_string(), "a finite number"));
        }
        Ok(())
    }
}

/// Refuses a skill whose motion would take more than [`MAX_CONTROL_STEPS`] steps for some Θ,
/// naming the field that sets its longest phase.
fn skill_horizon(sk: &SkillSpec, c: &ColliderSpec, dt: f64) -> Result<(), FieldError> {
    use crate::skills::{StepsSetBy, MAX_CONTROL_STEPS, PHASES};
    let bound = sk.step_bound(dt, Scene::tool_bottom(c));
    let total: f64 = bound.iter().map(|b| b.0).sum();
    if total <= MAX_CONTROL_STEPS as f64 {
        return Ok(());
    }
    let (phase, &(n, by)) = bound
        .iter()
        .enumerate()
        .max_by(|a, b| a.1 .0.total_cmp(&b.1 .0))
        .expect("six phases");
    let (field, value, fix) = match by {
        StepsSetBy::LinearSpeed => (
            "linear_speed",
            format!("{} m/s", sk.linear_speed),
            "raise linear_speed or simulation.dt",
        ),
        StepsSetBy::AngularSpeed => (
            "angular_speed_deg",
            format!("{} deg/s", sk.angular_speed_deg),
            "raise angular_speed_deg or simulation.dt",
        ),
        StepsSetBy::SettleSteps => (
            "settle_steps",
            sk.settle_steps.to_string(),
            "lower settle_steps",
        ),
    };
    Err(FieldError::new(
        field,
        value,
        format!(
            "a skill of at most {MAX_CONTROL_STEPS} steps: with simulation.dt = {dt} s it takes up to {total:.3e}, the {} phase {n:.3e} of them; {fix}",
            PHASES[phase]
        ),
    ))
}
