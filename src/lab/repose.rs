//! The angle of repose by a lifted-cylinder heap test (`powderlab repose`).
//!
//! A scene for the test (`scenes/repose_cylinder.ron`) fills a tube standing on a rough floor
//! with powder and lifts the tube away at a steady speed; the powder slumps into a heap and
//! comes to rest. The lifted cylinder rather than a funnel: it needs no hopper flow, which at
//! the scale of a vial would itself depend on the grid's resolution through the orifice, and
//! its heap's size is fixed by the tube, so every powder is measured on the same amount.
//!
//! The angle is measured as a laboratory measures it from photographs: the heap's silhouette is
//! taken from [`VIEWS`] side views around it (every 180°/`VIEWS`), a line is fitted to each of
//! the two flanks of each silhouette between 10 % and 80 % of the heap's height
//! ([`crate::lab::validate::pile::fit_flank`], the pile check's fit), and the angle of repose is
//! the mean of the 2·`VIEWS` flank angles. Each seed is another packing of the same powder
//! (the lattice's jitter), so the spread over seeds is the test's repeatability.

use crate::lab::validate::pile::fit_flank;
use crate::scene::{Lattice, Scene};
use crate::sim::{SimOptions, Simulation};
use anyhow::{bail, Result};
use glam::DVec3;
use serde::Serialize;
use std::time::Instant;

/// Side views of the heap, every 180°/`VIEWS` around its axis; each gives two flanks.
pub const VIEWS: usize = 4;
/// The heap is at rest when no grain moves faster than this at the end (m/s): 1 mm/s, a grain
/// moving a tenth of a millimetre while a camera takes its picture.
pub const REST_SPEED: f64 = 1e-3;
/// A fit stops once the simulated angle is this close to the target (degrees): below the
/// packings' spread of the test itself (0.1–0.2°, `docs/results/validation.md`).
pub const FIT_TOL_DEG: f64 = 0.1;

/// One heap: the test run once on one packing.
#[derive(Clone, Debug, Serialize)]
pub struct Heap {
    /// The lattice's jitter seed.
    pub seed: u64,
    /// The angle of repose: the mean of the flank angles (degrees).
    pub angle_deg: f64,
    /// Each view's two flanks (degrees), view by view.
    pub flanks_deg: Vec<f64>,
    /// The heap's height above the floor (m).
    pub height_m: f64,
    /// The radius within which 99 % of the grains lie (m).
    pub radius_m: f64,
    /// The fastest grain at the end (m/s), and whether that is at rest ([`REST_SPEED`]).
    pub max_speed: f64,
    pub at_rest: bool,
    pub particles: usize,
    pub particle_substeps: f64,
    pub wall_s: f64,
}

/// The test over several packings.
#[derive(Clone, Debug, Serialize)]
pub struct Repose {
    /// The mean of the heaps' angles (degrees).
    pub angle_deg: f64,
    /// The sample standard deviation of the heaps' angles (degrees; `None` for one heap).
    pub sd_deg: Option<f64>,
    /// The powder's friction angle and cohesion, as the scene gives them.
    pub friction_deg: Option<f64>,
    pub cohesion_pa: Option<f64>,
    /// Every body's lattice is regular: all seeds give the same packing.
    pub same_packing: bool,
    pub heaps: Vec<Heap>,
}

/// The angle of repose of the heap `xs` resting on the floor at height `floor`, by
/// [`VIEWS`] side views; `bin` is the silhouette's bin width (the particle spacing). Returns the
/// mean angle, each flank's angle, and the heap's height and radius.
pub fn measure(xs: &[DVec3], floor: f64, bin: f64) -> Result<(f64, Vec<f64>, f64, f64)> {
    if xs.is_empty() {
        bail!("no powder to measure a heap of");
    }
    let n = xs.len() as f64;
    let (cx, cz) = xs
        .iter()
        .fold((0.0, 0.0), |a, p| (a.0 + p.x / n, a.1 + p.z / n));
    let mut flanks = Vec::with_capacity(2 * VIEWS);
    for v in 0..VIEWS {
        let psi = std::f64::consts::PI * v as f64 / VIEWS as f64;
        let (c, s) = (psi.cos(), psi.sin());
        for side in [1.0, -1.0] {
            let profile: Vec<DVec3> = xs
                .iter()
                .map(|p| (side * ((p.x - cx) * c + (p.z - cz) * s), p.y - floor))
                .filter(|&(t, _)| t >= 0.0)
                .map(|(t, h)| DVec3::new(t, h, 0.0))
                .collect();
            match fit_flank(&profile, bin) {
                Some(f) => flanks.push(f.angle_deg),
                None => bail!(
                    "the heap's flank seen from {:.0}° has too few surface points to fit a line: \
                     the powder did not form a heap (is the scene a heap test, with the tube lifted \
                     away?)",
                    psi.to_degrees() + if side < 0.0 { 180.0 } else { 0.0 }
                ),
            }
        }
    }
    let height = xs.iter().map(|p| p.y - floor).fold(0.0, f64::max);
    let mut r: Vec<f64> = xs.iter().map(|p| (p.x - cx).hypot(p.z - cz)).collect();
    r.sort_by(f64::total_cmp);
    let radius = r[((0.99 * (r.len() - 1) as f64).round()) as usize];
    let angle = flanks.iter().sum::<f64>() / flanks.len() as f64;
    Ok((angle, flanks, height, radius))
}

/// Runs the heap test of `scene` once, on the packing of jitter seed `seed`, to its horizon.
pub fn heap(scene: &Scene, seed: u64, opts: &SimOptions) -> Result<Heap> {
    let mut scene = scene.clone();
    scene.simulation.seed = seed;
    let mut sim = Simulation::new(&scene, opts)?;
    let steps = sim.horizon;
    let work = sim.work(steps).particle_substeps();
    let t0 = Instant::now();
    sim.run(steps, |_| {})?;
    let wall_s = t0.elapsed().as_secs_f64();
    let bodies = sim.body_states();
    let xs: Vec<DVec3> = bodies.iter().flat_map(|b| b.x.iter().copied()).collect();
    let max_speed = bodies
        .iter()
        .flat_map(|b| b.v.iter())
        .map(|v| v.length())
        .fold(0.0, f64::max);
    let spacing = scene
        .bodies
        .iter()
        .map(|b| scene.particle_spacing(b))
        .fold(scene.simulation.dx, f64::min);
    let (angle_deg, flanks_deg, height_m, radius_m) = measure(&xs, scene.floor_height(), spacing)?;
    Ok(Heap {
        seed,
        angle_deg,
        flanks_deg,
        height_m,
        radius_m,
        max_speed,
        at_rest: max_speed <= REST_SPEED,
        particles: xs.len(),
        particle_substeps: work,
        wall_s,
    })
}

/// The value of the powder parameter `name` in `scene` (`None` where no material declares it).
fn parameter(scene: &Scene, name: &str) -> Option<f64> {
    crate::lab::calibrate::params::parse(scene, &[name.to_string()], &[])
        .ok()
        .map(|p| p[0].value(scene))
}

/// Runs the heap test of `scene` on each seed of `seeds`; `progress(k)` after each heap.
pub fn repose(
    scene: &Scene,
    seeds: &[u64],
    opts: &SimOptions,
    progress: &mut dyn FnMut(usize),
) -> Result<Repose> {
    if seeds.is_empty() {
        bail!("--seeds: at least one packing is needed");
    }
    let mut heaps = Vec::with_capacity(seeds.len());
    for (k, &s) in seeds.iter().enumerate() {
        heaps.push(heap(scene, s, opts)?);
        progress(k + 1);
    }
    let angles: Vec<f64> = heaps.iter().map(|h| h.angle_deg).collect();
    Ok(Repose {
        angle_deg: crate::lab::stats::mean(&angles),
        sd_deg: (angles.len() > 1).then(|| crate::lab::stats::mean_sd(&angles).1),
        friction_deg: parameter(scene, "friction_deg"),
        cohesion_pa: parameter(scene, "cohesion"),
        same_packing: scene
            .bodies
            .iter()
            .all(|b| matches!(b.lattice, Lattice::Regular)),
        heaps,
    })
}

/// An observed angle of repose and its measurement's standard deviation (degrees).
#[derive(Clone, Copy, Debug)]
pub struct Observed {
    pub angle_deg: f64,
    pub sd_deg: f64,
}

/// A parameter fitted to an observed angle of repose ([`fit`]).
#[derive(Clone, Debug, Serialize)]
pub struct Fitted {
    /// The parameter, as reports name it (`powder.cohesion`).
    pub parameter: String,
    pub value: f64,
    /// Its posterior standard deviation (Laplace, see [`fit`]).
    pub sd: f64,
    /// The observation: the angle and its measurement's standard deviation (degrees).
    pub target_deg: f64,
    pub target_sd_deg: f64,
    /// The spread of the simulated angle over the packings of one evaluation (degrees), when
    /// there are two or more.
    pub packing_sd_deg: Option<f64>,
    /// The simulated angle's slope in the parameter at the root (degrees per unit).
    pub slope_deg: f64,
    /// Every evaluation: the parameter's value and the simulated angle (mean over packings).
    pub evaluations: Vec<(f64, f64)>,
}

/// Fits parameter `p` of `scene` (searched within its bounds `p.lo..p.hi`) so that the heap
/// test's angle, the mean over the packings `seeds`, is the observed angle. The angle rises with the
/// friction angle and with the cohesion, so a root of `angle − target` is bracketed by the
/// bounds and closed by the Illinois regula falsi ([`crate::lab::optim::line::Illinois`]) in at
/// most `max_evals` evaluations (the bounds' two included), stopping within
/// [`FIT_TOL_DEG`] of the target.
///
/// The value is the secant's root of the tightest bracket, and its spread is the Laplace
/// approximation of the posterior with a flat prior and a Gaussian likelihood on the angle,
/// linearised at the root: `sd = σ / |dA/dp|`, where `σ² = target_sd² + packing_sd²/n` (the
/// observation's error and the simulated angle's over its `n` packings).
pub fn fit(
    scene: &Scene,
    p: &crate::lab::calibrate::params::FitParam,
    observed: Observed,
    seeds: &[u64],
    opts: &SimOptions,
    max_evals: usize,
    progress: &mut dyn FnMut(f64, f64),
) -> Result<Fitted> {
    use crate::lab::optim::line::Illinois;
    let (target_deg, target_sd_deg) = (observed.angle_deg, observed.sd_deg);
    if !(target_deg > 0.0 && target_deg < 90.0) {
        bail!("--angle-deg {target_deg}: expected an angle of repose between 0 and 90 degrees");
    }
    if !(target_sd_deg.is_finite() && target_sd_deg >= 0.0) {
        bail!("--angle-sd {target_sd_deg}: expected a standard deviation of at least 0");
    }
    if max_evals < 3 {
        bail!("--evals {max_evals}: the bracket's two ends and at least one more");
    }
    let mut evaluations = Vec::new();
    let mut packing_sd = Vec::new();
    let mut angle = |v: f64, evaluations: &mut Vec<(f64, f64)>| -> Result<f64> {
        let mut s = scene.clone();
        p.apply(&mut s, v);
        s.validate()
            .map_err(|e| anyhow::anyhow!("{} = {v}: the scene is refused: {e}", p.label))?;
        let r = repose(&s, seeds, opts, &mut |_| {})?;
        packing_sd.extend(r.sd_deg);
        evaluations.push((v, r.angle_deg));
        progress(v, r.angle_deg);
        Ok(r.angle_deg)
    };
    let (lo, hi) = (p.lo, p.hi);
    let (a_lo, a_hi) = (angle(lo, &mut evaluations)?, angle(hi, &mut evaluations)?);
    if !(a_lo <= target_deg && target_deg <= a_hi) {
        bail!(
            "--angle-deg {target_deg}: outside the {a_lo:.1}°–{a_hi:.1}° that {} from {lo} to {hi} \
             gives; widen --bounds {}=LO:HI",
            p.label,
            p.label.rsplit('.').next().unwrap_or_default()
        );
    }
    let mut ends = Illinois {
        a: lo,
        fa: a_lo - target_deg,
        b: hi,
        fb: a_hi - target_deg,
    };
    while evaluations.len() < max_evals && ends.fb.abs() > FIT_TOL_DEG {
        let x = ends.next();
        let fx = angle(x, &mut evaluations)? - target_deg;
        ends.update(x, fx);
    }
    // The tightest bracket among the evaluations: the nearest below and above the target.
    let below = evaluations
        .iter()
        .filter(|e| e.1 <= target_deg)
        .max_by(|x, y| x.0.total_cmp(&y.0))
        .copied()
        .expect("the lower bound is below");
    let above = evaluations
        .iter()
        .filter(|e| e.1 > target_deg)
        .min_by(|x, y| x.0.total_cmp(&y.0))
        .copied()
        .unwrap_or(below);
    let slope = if above.0 > below.0 {
        (above.1 - below.1) / (above.0 - below.0)
    } else {
        f64::NAN
    };
    let value = if slope.is_finite() && slope > 0.0 {
        below.0 + (target_deg - below.1) / slope
    } else {
        below.0
    };
    let packing_sd_deg = (!packing_sd.is_empty())
        .then(|| (packing_sd.iter().map(|s| s * s).sum::<f64>() / packing_sd.len() as f64).sqrt());
    let sigma =
        (target_sd_deg.powi(2) + packing_sd_deg.map_or(0.0, |s| s * s / seeds.len() as f64)).sqrt();
    Ok(Fitted {
        parameter: p.label.clone(),
        value,
        sd: sigma / slope,
        target_deg,
        target_sd_deg,
        packing_sd_deg,
        slope_deg: slope,
        evaluations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A cone of half-angle `90° − angle` (flank `angle` from the horizontal), height `h`,
    /// sampled on a lattice of spacing `d`.
    fn cone(angle_deg: f64, h: f64, d: f64) -> Vec<DVec3> {
        let t = angle_deg.to_radians().tan();
        let r0 = h / t;
        let n = (r0 / d).ceil() as i64;
        let mut xs = Vec::new();
        for i in -n..=n {
            for k in -n..=n {
                let (x, z) = (i as f64 * d, k as f64 * d);
                let top = h - x.hypot(z) * t;
                let mut y = 0.5 * d;
                while y < top {
                    xs.push(DVec3::new(x + 1.0, y + 0.2, z - 2.0));
                    y += d;
                }
            }
        }
        xs
    }

    #[test]
    fn a_cone_measures_its_own_angle() {
        for angle in [25.0, 35.0, 50.0] {
            let xs = cone(angle, 0.02, 0.0005);
            let (a, flanks, h, _) = measure(&xs, 0.2, 0.0005).unwrap();
            assert_eq!(flanks.len(), 2 * VIEWS);
            // The lattice's steps make the silhouette a staircase: within a degree.
            assert!(
                (a - angle).abs() < 1.0,
                "{angle}°: measured {a}° ({flanks:?})"
            );
            assert!((h - 0.02).abs() < 0.001, "height {h}");
        }
    }

    #[test]
    fn a_flat_layer_is_not_a_heap() {
        let mut xs = Vec::new();
        for i in 0..40 {
            for k in 0..40 {
                xs.push(DVec3::new(i as f64 * 0.001, 0.0005, k as f64 * 0.001));
            }
        }
        assert!(measure(&xs, 0.0, 0.001).is_err());
    }
}
