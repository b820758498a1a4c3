//! Which grains set the direction of `∂L/∂Θ` on a transport scene? The eq. 5 loss is a sum over
//! grains, so its adjoint gradient is the sum of one gradient per group of grains. This splits
//! it by where each grain ends the rollout and sets each part against the central secants
//! `(L(Θ + H·e_k) − L(Θ − H·e_k))/2H` of the whole loss (what an RMSprop step of `H` sees).
//!
//! ```sh
//! cargo run --release --example gradient_by_region -- SCENE H THETA [THETA ...]
//! ```
//!
//! `THETA` is five comma-separated values, `seedK` for the optimiser's Θ_init of seed `K`, or
//! `randK` for the `K`-th (from 0) random Θ of `gradient_at_scale` (the same generator).
//!
//! The groups, at Θ's final state: in the target cup, in the source cup, on the floor outside
//! both cups (spilled; lower than [`FLOOR_BAND_CELLS`] cells above the cups' floor), and the
//! rest (on the spoon, a rim or in the air). Each part is the adjoint gradient of
//! `Σ_{j in group} w_j·x_j` with `w_j = (x_j − t)/‖x_j − t‖` fixed at Θ: at Θ its gradient is that
//! of the group's share of eq. 5. The parts must add up to the whole gradient; the largest
//! relative gap is printed. "all but spilled" is the gradient of a loss that leaves out the
//! spilled grains, one of the remedies `docs/results/skill_optimisation.md` lists.
//!
//! The secant is split the same way, grain by grain (a grain is the same particle in every
//! rollout): the part from grains that end in the same group at `Θ ± H·e_k`, which a pathwise
//! gradient can follow, and the part from grains that end in different groups (one more grain
//! kept on the spoon, one fewer falling back), which no derivative at Θ sees.

use glam::DVec3;
use powderlab::adjoint::loss::Loss;
use powderlab::lab::optim::problem::Problem;
use powderlab::lab::optim::study::directions::secant_thetas;
use powderlab::lab::optim::theta_init;
use powderlab::lab::stats::{cosine, norm};
use powderlab::lab::study::error_vs_time::parse_theta;
use powderlab::math::sdf::Shape;
use powderlab::scene::Scene;
use powderlab::skills::Theta;
use rayon::prelude::*;

/// Height above the cups' cavity floor, in cells, under which a grain outside both cups counts
/// as on the floor: a grain resting on the ground sits within a cell or two of it, while the
/// spoon at the end of a pour is several centimetres (ten cells and more) up.
const FLOOR_BAND_CELLS: f64 = 2.0;

const GROUPS: [&str; 4] = ["target cup", "source cup", "spilled", "spoon/rim/air"];

fn round2(g: &[f64; 5]) -> [f64; 5] {
    g.map(|x| (x * 100.0).round() / 100.0)
}

fn theta_arg(s: &str) -> anyhow::Result<Theta> {
    if let Some(k) = s.strip_prefix("seed") {
        return Ok(theta_init(k.parse()?));
    }
    if let Some(k) = s.strip_prefix("rand") {
        let k: usize = k.parse()?;
        return Ok(secant_thetas(k + 1)[k]);
    }
    parse_theta(s)
}

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().collect();
    if a.len() < 4 {
        anyhow::bail!("usage: gradient_by_region SCENE H THETA [THETA ...]");
    }
    let p = Problem::new(Scene::load(&a[1])?, 1 << 30)?;
    let h: f64 = a[2].parse()?;
    let Loss::SumDistance(target) = p.loss() else {
        anyhow::bail!("the scene's loss is not eq. 5 (SumDistance)");
    };
    let task = p.scene().task.as_ref().expect("checked in Problem::new");
    let target_cup = p
        .scene()
        .target_region()
        .ok_or_else(|| anyhow::anyhow!("the target {} is not a cup", task.target))?;
    let source_cup = p
        .scene()
        .colliders
        .iter()
        .find(|c| c.name != task.target && matches!(c.shape, Shape::Cup { .. }))
        .and_then(|c| p.scene().cup_region(&c.name))
        .ok_or_else(|| anyhow::anyhow!("no source cup"))?;
    let floor_y = source_cup
        .pose
        .to_world(DVec3::new(0.0, source_cup.floor, 0.0))
        .y
        + FLOOR_BAND_CELLS * p.scene().simulation.dx;
    // The final positions of each body's grains (grain j of a body is the same particle in
    // every rollout).
    let final_positions = |sim: &mut powderlab::sim::Simulation| -> Vec<Vec<DVec3>> {
        sim.body_states().into_iter().map(|b| b.x).collect()
    };

    for arg in &a[3..] {
        let t0 = theta_arg(arg)?;
        let jobs: Vec<(usize, f64)> = (0..5).flat_map(|k| [(k, h), (k, -h)]).collect();
        // The whole gradient's rollout also gives Θ's final state, which sets the groups.
        let (centre, shifted) = rayon::join(
            || -> anyhow::Result<_> {
                let mut sim = p.simulation(t0, false)?;
                let (_, whole) = p.skill_gradient(&mut sim, p.loss())?;
                let (_, indicator) = p.indicator(&mut sim);
                Ok((whole, final_positions(&mut sim), indicator))
            },
            || {
                jobs.par_iter()
                    .map(|&(k, d)| {
                        let mut t = t0;
                        t[k] += d;
                        let mut sim = p.simulation(t, false)?;
                        let steps = sim.horizon;
                        sim.run(steps, |_| {})?;
                        Ok(final_positions(&mut sim))
                    })
                    .collect::<anyhow::Result<Vec<Vec<Vec<DVec3>>>>>()
            },
        );
        let ((whole, xs, indicator), shifted) = (centre?, shifted?);
        let group = |x: DVec3| {
            if target_cup.inside(x) {
                0
            } else if source_cup.inside(x) {
                1
            } else if x.y < floor_y {
                2
            } else {
                3
            }
        };
        // The secant split by grain: the grains that end in the same group at Θ + h·e_k and
        // Θ − h·e_k (what a pathwise gradient can see) and those that change group.
        let (mut kept, mut switched, mut moved) = ([0.0; 5], [0.0; 5], [0usize; 5]);
        for k in 0..5 {
            let minus = shifted[2 * k + 1].iter().flatten();
            for (xp, xm) in shifted[2 * k].iter().flatten().zip(minus) {
                let d = ((*xp - target).length() - (*xm - target).length()) / (2.0 * h);
                if group(*xp) == group(*xm) {
                    kept[k] += d;
                } else {
                    switched[k] += d;
                    moved[k] += 1;
                }
            }
        }
        let secant: [f64; 5] = std::array::from_fn(|k| kept[k] + switched[k]);
        let mut counts = [0usize; 4];
        xs.iter().flatten().for_each(|x| counts[group(*x)] += 1);
        // Eq. 5's own ∂L/∂x at Θ, (x_j − t)/‖x_j − t‖, kept for one group's grains at a time.
        let (_, dl_dx) = p.loss().eval(&xs);
        let parts = (0..GROUPS.len())
            .into_par_iter()
            .map(|gi| {
                let w: Vec<Vec<DVec3>> = xs
                    .iter()
                    .zip(&dl_dx)
                    .map(|(x, w)| {
                        x.iter()
                            .zip(w)
                            .map(|(&x, &w)| if group(x) == gi { w } else { DVec3::ZERO })
                            .collect()
                    })
                    .collect();
                let mut sim = p.simulation(t0, false)?;
                Ok(p.skill_gradient(&mut sim, &Loss::Linear(w))?.1)
            })
            .collect::<anyhow::Result<Vec<[f64; 5]>>>()?;
        let sum: [f64; 5] = std::array::from_fn(|k| parts.iter().map(|g| g[k]).sum());
        let gap = (0..5)
            .map(|k| (sum[k] - whole[k]).abs())
            .fold(0.0, f64::max)
            / norm(&whole);
        let no_spill: [f64; 5] = std::array::from_fn(|k| whole[k] - parts[2][k]);
        println!(
            "Θ {arg} = {:?}: indicator {indicator:.3}, secant (h {h}) {:?}",
            round2(&t0),
            round2(&secant)
        );
        println!(
            "  whole   cos {:+.3} |g| {:9.2} {:?} (parts add up to it within {gap:.1e} of |g|)",
            cosine(&whole, &secant),
            norm(&whole),
            round2(&whole)
        );
        for (gi, g) in parts.iter().enumerate() {
            println!(
                "  {:<14} {:5} grains  cos {:+.3} |g| {:9.2} {:?}",
                GROUPS[gi],
                counts[gi],
                cosine(g, &secant),
                norm(g),
                round2(g)
            );
        }
        println!(
            "  all but spilled     cos {:+.3} |g| {:9.2} {:?}",
            cosine(&no_spill, &secant),
            norm(&no_spill),
            round2(&no_spill)
        );
        println!(
            "  secant of the grains that keep their group {:?} (whole gradient's cos {:+.3})",
            round2(&kept),
            cosine(&whole, &kept)
        );
        println!(
            "  secant of the grains that change group     {:?} ({moved:?} grains)",
            round2(&switched)
        );
    }
    Ok(())
}
