//! Calibrating a powder's physical parameters from observations (seed A's DPSI step):
//! `powderlab calibrate SCENE --observed OBS --fit friction_deg,...`.
//!
//! The observations ([`observation`]) are height maps or point clouds, each at a global step.
//! Each becomes a loss on the positions at its step ([`Loss::HeightField`], [`Loss::Chamfer`]),
//! summed in one backward pass ([`Term::Positions`]), whose material and collider-friction
//! gradients ([`params::FitParam::gradient`]) drive a bounded optimiser in unit coordinates
//! ([`params`]):
//!
//! - [`adam`]: Adam on the adjoint gradient, projected onto the box. Adam's per-coordinate
//!   scaling is the gradient normalisation DPSI uses to tame the scale of `∂L/∂E` against
//!   `∂L/∂φ`;
//! - [`cmaes`]: CMA-ES on the forward loss, the search baseline at equal compute.
//!
//! At the optimum, [`identifiability`] estimates the loss's curvature by central differences of
//! the adjoint gradient and turns it into a standard error per parameter: the Gauss–Newton
//! reading of a least-squares loss `L = (1/n) Σ r²` with independent residuals of variance
//! `σ² ≈ L*` is `Cov(u) ≈ (2 L*/n) H⁻¹`. A parameter whose standard error is a large part of its
//! range is one the observation does not pin down.

pub mod observation;
pub mod params;
pub mod plot;

use crate::adjoint::loss::HeightObservation;
use crate::adjoint::tape::{gradient_with, Loss, Tape, Term};
use crate::math::chamfer;
use crate::math::sdf::Shape;
use crate::optim::report::BACKWARD_COST;
use crate::scene::Scene;
use crate::sim::{SimOptions, Simulation};
use anyhow::Context;
use glam::DVec3;
use observation::{Observation, Observed};
use params::FitParam;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// The soft height's temperature (and its footprint's edge width), in particle spacings: the
/// soft maximum reads high by at most `τ ln(Σk)`, under 0.2 mm at the shipped 2.5 mm spacing
/// and a few grains near the top of a pixel, a fifth of the 1 mm noise of a depth camera.
pub const TAU_PER_SPACING: f64 = 0.1;

/// The soft footprint's edge is this many times narrower than the temperature: a grain `δ`
/// outside a pixel then counts `δ·EDGE_SHARPNESS` lower, more than any slope lifts it.
pub const EDGE_SHARPNESS: f64 = 4.0;

/// A calibration problem: the scene, what is fitted, and the observations as losses.
#[derive(Clone, Debug)]
pub struct Calibration {
    pub scene: Scene,
    pub params: Vec<FitParam>,
    /// Each observation's global step and loss.
    pub terms: Vec<(usize, Loss)>,
    /// Residuals per observation (pixels seen, or observed points): the `n` of the standard
    /// errors.
    pub residuals: usize,
    /// Global steps of a rollout: the last observation's.
    pub steps: usize,
    pub threads: Option<usize>,
    /// Memory budget of a backward pass's tape (bytes).
    pub tape_budget: usize,
    /// The backward pass's cost in forward rollouts (default [`BACKWARD_COST`]; the study
    /// measures it on its own scenes, [`measure_backward_cost`]).
    pub backward_cost: f64,
}

/// One rollout's result.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Eval {
    /// The unit coordinates it ran at.
    pub u: Vec<f64>,
    /// The parameters' values.
    pub values: Vec<f64>,
    pub loss: f64,
    /// `∂L/∂u`, when it ran backward.
    pub grad: Option<Vec<f64>>,
    /// Its compute in forward rollouts: 1, or `1 + BACKWARD_COST` with the backward pass.
    pub cost: f64,
    pub wall_s: f64,
}

/// The height an empty pixel shows: the highest upward-facing plane container, else the domain
/// walls' inner face.
pub fn floor_height(scene: &Scene) -> f64 {
    let walls = scene.domain().0.y + scene.simulation.walls.cells as f64 * scene.simulation.dx;
    scene
        .colliders
        .iter()
        .filter(|c| c.kind == crate::scene::ColliderKindSpec::Container)
        .filter_map(|c| match c.shape {
            Shape::Plane { normal } if DVec3::from(normal).normalize_or_zero().y > 0.999 => {
                Some(c.position.1)
            }
            _ => None,
        })
        .fold(walls, f64::max)
}

/// The finest particle spacing of the scene's bodies.
fn spacing(scene: &Scene) -> f64 {
    scene
        .bodies
        .iter()
        .map(|b| scene.particle_spacing(b))
        .fold(scene.simulation.dx, f64::min)
}

/// The loss of one observation against `scene`'s particles, and its residual count. Refuses an
/// observation that lies wholly outside the scene's domain (a file in other units, or of
/// another scene).
pub fn observation_loss(
    scene: &Scene,
    obs: &Observed,
    tau: Option<f64>,
) -> Result<(Loss, usize), String> {
    let (lo, hi) = scene.domain();
    let shown = obs.path.display();
    let h = spacing(scene);
    match &obs.what {
        Observation::Heights { grid, heights } => {
            let inside = (0..grid.len()).filter(|&c| {
                let (i, j) = (c % grid.nx, c / grid.nx);
                let (x, z) = (
                    grid.origin[0] + i as f64 * grid.pixel,
                    grid.origin[1] + j as f64 * grid.pixel,
                );
                heights[c].is_finite()
                    && (lo.x..=hi.x).contains(&x)
                    && (lo.z..=hi.z).contains(&z)
                    && (lo.y..=hi.y).contains(&heights[c])
            });
            let n = inside.count();
            if n == 0 {
                return Err(format!(
                    "{shown}: no seen pixel lies inside the scene's domain {lo:.4} to {hi:.4} (m); is the map in metres, and of this scene?"
                ));
            }
            let seen = heights.iter().filter(|v| v.is_finite()).count();
            Ok((
                Loss::HeightField(HeightObservation {
                    grid: *grid,
                    observed: heights.clone(),
                    base: floor_height(scene),
                    top: 0.5 * h,
                    tau: tau.unwrap_or(TAU_PER_SPACING * h),
                    edge: tau.unwrap_or(TAU_PER_SPACING * h) / EDGE_SHARPNESS,
                }),
                seen,
            ))
        }
        Observation::Cloud(points) => {
            let margin = DVec3::splat(scene.simulation.dx);
            let inside = points
                .iter()
                .filter(|p| p.cmpge(lo - margin).all() && p.cmple(hi + margin).all())
                .count();
            if inside * 2 < points.len() {
                return Err(format!(
                    "{shown}: {} of {} points lie outside the scene's domain {lo:.4} to {hi:.4} (m); is the cloud in metres, in the scene's frame?",
                    points.len() - inside,
                    points.len()
                ));
            }
            Ok((
                Loss::Chamfer(chamfer::Observed::new(points.clone())),
                points.len(),
            ))
        }
    }
}

impl Calibration {
    /// The problem of fitting `params` of `scene` to `observed`.
    pub fn new(
        scene: &Scene,
        params: Vec<FitParam>,
        observed: &[Observed],
        tau: Option<f64>,
    ) -> Result<Calibration, String> {
        if observed.is_empty() {
            return Err("--observed: give at least one observation file".into());
        }
        let horizon = scene.simulation.steps.unwrap_or(0);
        let mut terms = Vec::new();
        let mut residuals = 0;
        for o in observed {
            let step = o.step.unwrap_or(horizon);
            if step == 0 && o.step.is_none() {
                return Err(format!(
                    "{}: the scene sets no steps, so say which global step it shows: {}@STEP",
                    o.path.display(),
                    o.path.display()
                ));
            }
            let (loss, n) = observation_loss(scene, o, tau)?;
            residuals += n;
            terms.push((step, loss));
        }
        let steps = terms.iter().map(|t| t.0).max().unwrap_or(horizon);
        Ok(Calibration {
            scene: scene.clone(),
            params,
            terms,
            residuals,
            steps,
            threads: None,
            tape_budget: 1 << 30,
            backward_cost: BACKWARD_COST,
        })
    }

    /// The scene with the parameters at `u`.
    pub fn scene_at(&self, u: &[f64]) -> Scene {
        let mut s = self.scene.clone();
        for (p, &ui) in self.params.iter().zip(u) {
            p.apply(&mut s, p.from_unit(ui));
        }
        s
    }

    /// The unit coordinates of the scene's own values (clamped to the box).
    pub fn start(&self) -> Vec<f64> {
        self.params
            .iter()
            .map(|p| p.to_unit(p.value(&self.scene)).clamp(0.0, 1.0))
            .collect()
    }

    /// One rollout at `u`: the summed loss of the observations, with `∂L/∂u` if `grad`.
    pub fn evaluate(&self, u: &[f64], grad: bool) -> anyhow::Result<Eval> {
        let t0 = Instant::now();
        let scene = self.scene_at(u);
        let values: Vec<f64> = self.params.iter().map(|p| p.value(&scene)).collect();
        let mut sim = Simulation::new(
            &scene,
            &SimOptions {
                threads: self.threads,
                ..Default::default()
            },
        )
        .with_context(|| format!("the scene at {}", self.describe(&values)))?;
        let (loss, g) = if grad {
            let zero = Loss::Linear(
                sim.body_states()
                    .iter()
                    .map(|b| vec![DVec3::ZERO; b.x.len()])
                    .collect(),
            );
            let terms: Vec<Term> = self
                .terms
                .iter()
                .map(|(step, loss)| Term::Positions {
                    step: *step,
                    loss: loss.clone(),
                })
                .collect();
            let g = gradient_with(
                &mut sim,
                self.steps,
                &zero,
                &terms,
                Tape::Budget(self.tape_budget),
            )
            .with_context(|| format!("backward pass at {}", self.describe(&values)))?;
            let du: Vec<f64> = self
                .params
                .iter()
                .zip(u)
                .map(|(p, &ui)| p.gradient(&scene, &g) * p.dvalue_du(ui))
                .collect();
            (g.loss, Some(du))
        } else {
            let mut l = 0.0;
            for s in 0..=self.steps {
                for (step, loss) in &self.terms {
                    if *step == s {
                        let xs: Vec<Vec<DVec3>> =
                            sim.body_states().into_iter().map(|b| b.x).collect();
                        l += loss.eval(&xs).0;
                    }
                }
                if s < self.steps {
                    sim.step()
                        .with_context(|| format!("rollout at {}", self.describe(&values)))?;
                }
            }
            (l, None)
        };
        Ok(Eval {
            u: u.to_vec(),
            values,
            loss,
            cost: if grad { 1.0 + self.backward_cost } else { 1.0 },
            grad: g,
            wall_s: t0.elapsed().as_secs_f64(),
        })
    }

    /// `label = value, ...` of parameter values.
    pub fn describe(&self, values: &[f64]) -> String {
        self.params
            .iter()
            .zip(values)
            .map(|(p, v)| format!("{} = {v:.5}", p.label))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// The rollouts of a calibration run, appended one JSON line each to a file as they finish, so
/// that a killed run resumes where it stopped: a rollout already in the file (same method, index
/// and pass, and bitwise the same `u`) is read back instead of run.
pub struct Journal {
    file: Option<std::fs::File>,
    done: std::collections::HashMap<(String, usize, bool), Eval>,
    /// Rollouts read back instead of run.
    pub replayed: usize,
}

#[derive(Serialize, Deserialize)]
struct Line {
    method: String,
    index: usize,
    eval: Eval,
}

impl Journal {
    /// A journal that keeps nothing (tests, studies that keep their own).
    pub fn none() -> Journal {
        Journal {
            file: None,
            done: Default::default(),
            replayed: 0,
        }
    }

    /// Opens (or creates) the journal at `path`, reading what it holds. A torn last line (a
    /// kill mid-write) is dropped.
    pub fn open(path: &std::path::Path) -> anyhow::Result<Journal> {
        let mut done = std::collections::HashMap::new();
        if let Ok(text) = std::fs::read_to_string(path) {
            for l in text.lines() {
                if let Ok(line) = serde_json::from_str::<Line>(l) {
                    let grad = line.eval.grad.is_some();
                    done.insert((line.method, line.index, grad), line.eval);
                }
            }
        }
        let file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .with_context(|| format!("cannot open the journal {}", path.display()))?;
        Ok(Journal {
            file: Some(file),
            done,
            replayed: 0,
        })
    }

    /// The rollout `index` of `method` at `u`: read back, or run and appended.
    pub fn eval(
        &mut self,
        cal: &Calibration,
        method: &str,
        index: usize,
        u: &[f64],
        grad: bool,
    ) -> anyhow::Result<Eval> {
        if let Some(e) = self.lookup(method, index, u, grad) {
            return Ok(e);
        }
        let e = cal.evaluate(u, grad)?;
        self.record(method, index, &e)?;
        Ok(e)
    }

    /// The journal's rollout `index` of `method`, if it ran at bitwise this `u` and pass.
    pub fn lookup(&mut self, method: &str, index: usize, u: &[f64], grad: bool) -> Option<Eval> {
        let e = self.done.get(&(method.to_string(), index, grad))?;
        let same =
            e.u.len() == u.len() && e.u.iter().zip(u).all(|(a, b)| a.to_bits() == b.to_bits());
        if same {
            self.replayed += 1;
            Some(e.clone())
        } else {
            None
        }
    }

    /// Appends a finished rollout.
    pub fn record(&mut self, method: &str, index: usize, e: &Eval) -> anyhow::Result<()> {
        if let Some(f) = &mut self.file {
            use std::io::Write;
            let line = Line {
                method: method.into(),
                index,
                eval: e.clone(),
            };
            writeln!(f, "{}", serde_json::to_string(&line)?)?;
            f.flush()?;
        }
        self.done
            .insert((method.to_string(), index, e.grad.is_some()), e.clone());
        Ok(())
    }
}

/// What a camera would see of `scene` at global `step`: a height map over the domain's
/// interior with pixels of `pixel` metres (the `.csv` kind), or every particle (the `.ply`
/// kind), each value with Gaussian noise of standard deviation `noise` metres from `seed`.
pub fn observe(
    scene: &Scene,
    step: usize,
    heights: bool,
    pixel: f64,
    noise: f64,
    seed: u64,
    threads: Option<usize>,
) -> anyhow::Result<Observation> {
    let mut sim = Simulation::new(
        scene,
        &SimOptions {
            threads,
            ..Default::default()
        },
    )?;
    sim.run(step, |_| {})?;
    let xs: Vec<DVec3> = sim.body_states().into_iter().flat_map(|b| b.x).collect();
    let mut rng = crate::util::SplitMix64(seed);
    if heights {
        let (lo, hi) = scene.domain();
        let inner = scene.simulation.walls.cells as f64 * scene.simulation.dx;
        let (x0, x1) = (lo.x + inner, hi.x - inner);
        let (z0, z1) = (lo.z + inner, hi.z - inner);
        let grid = crate::math::heightfield::HeightGrid {
            origin: [x0 + 0.5 * pixel, z0 + 0.5 * pixel],
            pixel,
            nx: (((x1 - x0) / pixel).floor() as usize).max(1),
            nz: (((z1 - z0) / pixel).floor() as usize).max(1),
        };
        let h = crate::math::heightfield::hard_heights(
            &grid,
            &xs,
            floor_height(scene),
            0.5 * spacing(scene),
        );
        let heights = h.into_iter().map(|v| v + noise * rng.normal()).collect();
        Ok(Observation::Heights { grid, heights })
    } else {
        let pts = xs
            .into_iter()
            .map(|p| p + noise * DVec3::new(rng.normal(), rng.normal(), rng.normal()))
            .collect();
        Ok(Observation::Cloud(pts))
    }
}

/// Adam's settings.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
pub struct AdamConfig {
    /// Step size in unit coordinates: the first steps move each parameter by about this share
    /// of its range.
    pub lr: f64,
    pub beta1: f64,
    pub beta2: f64,
}

impl Default for AdamConfig {
    fn default() -> Self {
        AdamConfig {
            lr: 0.08,
            beta1: 0.8,
            beta2: 0.99,
        }
    }
}

/// The backward pass's cost in forward rollouts on `cal` at `u`: the median of `reps` timed
/// forward and gradient rollouts, `t_grad/t_forward − 1`.
pub fn measure_backward_cost(cal: &Calibration, u: &[f64], reps: usize) -> anyhow::Result<f64> {
    let mut f = Vec::new();
    let mut g = Vec::new();
    for _ in 0..reps.max(1) {
        f.push(cal.evaluate(u, false)?.wall_s);
        g.push(cal.evaluate(u, true)?.wall_s);
    }
    let med = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    Ok((med(&mut g) / med(&mut f) - 1.0).max(0.0))
}

/// Adam on the adjoint gradient from `u0`, projected onto `[0, 1]` per coordinate, until the
/// next gradient rollout would pass `budget` forward rollouts' compute (at least one runs).
/// `eval` runs (or replays) one rollout; its `cost` is what the budget counts.
pub fn adam(
    u0: &[f64],
    budget: f64,
    cfg: AdamConfig,
    mut eval: impl FnMut(usize, &[f64], bool) -> anyhow::Result<Eval>,
) -> anyhow::Result<Vec<Eval>> {
    let d = u0.len();
    let (mut u, mut m, mut v) = (u0.to_vec(), vec![0.0; d], vec![0.0; d]);
    let mut out: Vec<Eval> = Vec::new();
    let mut spent = 0.0;
    for t in 1.. {
        // The next rollout costs what the last one did.
        if let Some(last) = out.last() {
            if spent + last.cost > budget + 1e-9 {
                break;
            }
        }
        let e = eval(out.len(), &u, true)?;
        spent += e.cost;
        let g = e.grad.clone().unwrap_or_else(|| vec![0.0; d]);
        out.push(e);
        for i in 0..d {
            m[i] = cfg.beta1 * m[i] + (1.0 - cfg.beta1) * g[i];
            v[i] = cfg.beta2 * v[i] + (1.0 - cfg.beta2) * g[i] * g[i];
            let mh = m[i] / (1.0 - cfg.beta1.powi(t));
            let vh = v[i] / (1.0 - cfg.beta2.powi(t));
            if vh > 0.0 {
                u[i] = (u[i] - cfg.lr * mh / vh.sqrt()).clamp(0.0, 1.0);
            }
        }
    }
    Ok(out)
}

/// Maps `x ∈ R` into `[0, 1]` by reflection at the faces.
fn reflect01(x: f64) -> f64 {
    0.5 * (crate::optim::cma::reflect(2.0 * x - 1.0) + 1.0)
}

/// CMA-ES's initial step size in unit coordinates: a quarter of the box.
pub const CMA_SIGMA0: f64 = 0.25;

/// CMA-ES (the `cmaes` crate, its default population) on the forward loss, `budget` forward
/// rollouts: the first at `u0` (as Adam's first is), then the sampler's points around `u0`,
/// reflected into the box.
pub fn cmaes(
    u0: &[f64],
    budget: usize,
    seed: u64,
    eval: impl FnMut(usize, &[f64], bool) -> anyhow::Result<Eval>,
) -> anyhow::Result<Vec<Eval>> {
    use std::sync::Mutex;
    let out: Mutex<Vec<Eval>> = Mutex::new(Vec::new());
    let failure: Mutex<Option<anyhow::Error>> = Mutex::new(None);
    let eval = Mutex::new(eval);
    out.lock()
        .expect("lock")
        .push((eval.lock().expect("lock"))(0, u0, false)?);
    let f = |x: &cmaes::DVector<f64>| -> f64 {
        let mut o = out.lock().expect("lock");
        let i = o.len();
        if i >= budget || failure.lock().expect("lock").is_some() {
            return f64::MAX;
        }
        let u: Vec<f64> = x.iter().map(|v| reflect01(*v)).collect();
        match (eval.lock().expect("lock"))(i, &u, false) {
            Ok(e) => {
                let l = e.loss;
                o.push(e);
                l
            }
            Err(e) => {
                failure.lock().expect("lock").get_or_insert(e);
                f64::NAN
            }
        }
    };
    let mut st = cmaes::CMAESOptions::new(u0.to_vec(), CMA_SIGMA0)
        .seed(seed)
        .build(f)
        .map_err(|e| anyhow::anyhow!("CMA-ES options: {e:?}"))?;
    while out.lock().expect("lock").len() < budget {
        let _ = st.next();
        if let Some(e) = failure.lock().expect("lock").take() {
            return Err(e);
        }
    }
    drop(st);
    Ok(out.into_inner().expect("lock"))
}

/// The curvature at the optimum and what it says of each parameter.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Identifiability {
    /// `∂²L/∂u²` by central differences of the adjoint gradient, symmetrised.
    pub hessian: Vec<Vec<f64>>,
    /// Its eigenvalues, largest first, and unit eigenvectors (rows).
    pub eigenvalues: Vec<f64>,
    pub eigenvectors: Vec<Vec<f64>>,
    /// Standard error per parameter in its own units (`Cov(u) ≈ (2L*/n) H⁻¹`, mapped by
    /// `dv/du`); infinite where the curvature is not positive.
    pub std_error: Vec<f64>,
    /// The standard error as a share of the parameter's search range.
    pub relative: Vec<f64>,
    /// The unit-coordinate step of the differences.
    pub step: f64,
}

/// The unit-coordinate step of the curvature's central differences: 2 % of each range, wide
/// enough to average the gradient's jitter between nearby rollouts, small against the range.
pub const CURVATURE_STEP: f64 = 0.02;

/// A parameter is *pinned down* by the observation when its standard error is under this share
/// of its search range (a fifth of the 10 %-wide band a lab would call calibrated).
pub const PINNED_SHARE: f64 = 0.02;

/// The curvature at `u` by central differences of the gradient (`2k` gradient rollouts).
pub fn identifiability(
    cal: &Calibration,
    u: &[f64],
    loss: f64,
    step: f64,
    mut eval: impl FnMut(&[f64]) -> anyhow::Result<Eval>,
) -> anyhow::Result<Identifiability> {
    let d = u.len();
    let mut h = vec![vec![0.0; d]; d];
    for i in 0..d {
        // Keep both points in the box: shift the pair inward at a face.
        let c = u[i].clamp(step, 1.0 - step);
        let mut up = u.to_vec();
        up[i] = c + step;
        let mut dn = u.to_vec();
        dn[i] = c - step;
        let gp = eval(&up)?.grad.unwrap_or_else(|| vec![0.0; d]);
        let gm = eval(&dn)?.grad.unwrap_or_else(|| vec![0.0; d]);
        for j in 0..d {
            h[i][j] = (gp[j] - gm[j]) / (2.0 * step);
        }
    }
    let h: Vec<Vec<f64>> = (0..d)
        .map(|i| (0..d).map(|j| 0.5 * (h[i][j] + h[j][i])).collect())
        .collect();
    let (eigenvalues, eigenvectors) = symmetric_eigen(&h);
    let scale = 2.0 * loss.max(0.0) / cal.residuals.max(1) as f64;
    let mut std_error = vec![f64::INFINITY; d];
    if eigenvalues.iter().all(|&l| l > 0.0) {
        for i in 0..d {
            // (H⁻¹)_ii = Σ_k v_ki² / λ_k.
            let inv: f64 = eigenvalues
                .iter()
                .zip(&eigenvectors)
                .map(|(l, v)| v[i] * v[i] / l)
                .sum();
            std_error[i] = (scale * inv).sqrt() * cal.params[i].dvalue_du(u[i]).abs();
        }
    }
    let relative = std_error
        .iter()
        .zip(&cal.params)
        .map(|(s, p)| s / (p.hi - p.lo))
        .collect();
    Ok(Identifiability {
        hessian: h,
        eigenvalues,
        eigenvectors,
        std_error,
        relative,
        step,
    })
}

/// Eigenvalues (largest first) and unit eigenvectors (rows) of a small symmetric matrix, by
/// cyclic Jacobi rotations. Hand-written: the project has no linear-algebra crate, and a
/// calibration fits a handful of parameters.
pub fn symmetric_eigen(a: &[Vec<f64>]) -> (Vec<f64>, Vec<Vec<f64>>) {
    let n = a.len();
    let mut a: Vec<Vec<f64>> = a.to_vec();
    let mut v: Vec<Vec<f64>> = (0..n)
        .map(|i| (0..n).map(|j| if i == j { 1.0 } else { 0.0 }).collect())
        .collect();
    for _sweep in 0..100 {
        let off: f64 = (0..n)
            .flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i][j] * a[i][j])
            .sum();
        let diag: f64 = (0..n).map(|i| a[i][i] * a[i][i]).sum();
        if off <= 1e-30 * diag.max(1e-300) {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                if a[p][q] == 0.0 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for row in a.iter_mut() {
                    let (akp, akq) = (row[p], row[q]);
                    row[p] = c * akp - s * akq;
                    row[q] = s * akp + c * akq;
                }
                let (rp, rq) = (a[p].clone(), a[q].clone());
                a[p] = rp.iter().zip(&rq).map(|(x, y)| c * x - s * y).collect();
                a[q] = rp.iter().zip(&rq).map(|(x, y)| s * x + c * y).collect();
                for row in v.iter_mut() {
                    let (vp, vq) = (row[p], row[q]);
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
    }
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&i, &j| a[j][j].total_cmp(&a[i][i]));
    let values = order.iter().map(|&i| a[i][i]).collect();
    // Column i of v is the eigenvector of a[i][i].
    let vectors = order
        .iter()
        .map(|&i| (0..n).map(|k| v[k][i]).collect())
        .collect();
    (values, vectors)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jacobi_eigen_reconstructs_a_symmetric_matrix() {
        let a = vec![
            vec![4.0, 1.0, -2.0],
            vec![1.0, 2.0, 0.5],
            vec![-2.0, 0.5, 3.0],
        ];
        let (l, v) = symmetric_eigen(&a);
        assert!(l[0] >= l[1] && l[1] >= l[2]);
        for i in 0..3 {
            for j in 0..3 {
                let r: f64 = (0..3).map(|k| l[k] * v[k][i] * v[k][j]).sum();
                assert!((r - a[i][j]).abs() < 1e-12, "{i},{j}: {r} vs {}", a[i][j]);
            }
        }
    }

    #[test]
    fn reflection_keeps_samples_in_the_unit_box() {
        for x in [-0.7, -0.1, 0.0, 0.3, 1.0, 1.2, 2.9] {
            let y = reflect01(x);
            assert!((0.0..=1.0).contains(&y), "{x} -> {y}");
        }
        assert_eq!(reflect01(0.3), 0.3);
        assert!((reflect01(1.2) - 0.8).abs() < 1e-12);
    }
}
