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

pub mod curvature;
pub mod fit;
pub mod journal;
pub mod observation;
pub mod params;
pub mod plot;
pub(crate) mod study;
pub mod trust;

pub use curvature::{identifiability, Identifiability, CURVATURE_STEP, PINNED_SHARE};
pub use fit::{adam, cmaes, measure_backward_cost, AdamConfig, CMA_SIGMA0};
pub use journal::Journal;
pub use trust::{trust_region, TrustConfig};

use crate::adjoint::loss::HeightObservation;
use crate::adjoint::tape::{gradient_with, Loss, Tape, Term};
use crate::lab::optim::report::BACKWARD_COST;
use crate::math::chamfer;
use crate::math::heightfield::SoftHeight;
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

/// The rollout of lowest loss in `trace`: the fit a calibration reports.
pub fn lowest(trace: &[Eval]) -> Option<&Eval> {
    trace.iter().min_by(|a, b| a.loss.total_cmp(&b.loss))
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
                    soft: SoftHeight {
                        base: scene.floor_height(),
                        top: 0.5 * h,
                        tau: tau.unwrap_or(TAU_PER_SPACING * h),
                        edge: tau.unwrap_or(TAU_PER_SPACING * h) / EDGE_SHARPNESS,
                    },
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
                Loss::Chamfer(chamfer::ObservedCloud::new(points.clone())),
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
            let (mut loss, n) = observation_loss(scene, o, tau)?;
            if let Some(name) = &o.body {
                let b = scene.bodies.iter().position(|b| &b.name == name).ok_or_else(|| {
                    let names: Vec<&str> = scene.bodies.iter().map(|b| b.name.as_str()).collect();
                    format!(
                        "{}: the scene has no body '{name}' (it has {names:?}); write BODY=FILE with one of them",
                        o.path.display()
                    )
                })?;
                loss = Loss::Only {
                    bodies: vec![b],
                    inner: Box::new(loss),
                };
            }
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

    /// The unit coordinates of parameter values, in the order of `params` (not clamped).
    pub fn to_unit(&self, values: &[f64]) -> Vec<f64> {
        self.params
            .iter()
            .zip(values)
            .map(|(p, &v)| p.to_unit(v))
            .collect()
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
        let mut sim = Simulation::new(&scene, &SimOptions::threads(self.threads))
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
    let xs: Vec<DVec3> = positions(scene, step, threads)?
        .into_iter()
        .flatten()
        .collect();
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
            scene.floor_height(),
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

/// Every body's particle positions at global `step`.
fn positions(
    scene: &Scene,
    step: usize,
    threads: Option<usize>,
) -> anyhow::Result<Vec<Vec<DVec3>>> {
    let mut sim = Simulation::new(scene, &SimOptions::threads(threads))?;
    sim.run(step, |_| {})?;
    Ok(sim.body_states().into_iter().map(|b| b.x).collect())
}

/// What a camera that tells the bodies apart (coloured layers) would see of `scene` at global
/// `step`: one point cloud per body, scene order, every point with Gaussian noise of standard
/// deviation `noise` metres per axis from `seed`. Each is an observation `BODY=FILE`.
pub fn observe_bodies(
    scene: &Scene,
    step: usize,
    noise: f64,
    seed: u64,
    threads: Option<usize>,
) -> anyhow::Result<Vec<Observation>> {
    let mut rng = crate::util::SplitMix64(seed);
    Ok(positions(scene, step, threads)?
        .into_iter()
        .map(|xs| {
            Observation::Cloud(
                xs.into_iter()
                    .map(|p| p + noise * DVec3::new(rng.normal(), rng.normal(), rng.normal()))
                    .collect(),
            )
        })
        .collect())
}
