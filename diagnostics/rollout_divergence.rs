//! Where does a skill scene's rollout stop being smooth in Θ? Three rollouts at Θ, Θ + ε·u and
//! Θ + 2ε·u run side by side, step by step. Where the trajectory is differentiable, the second
//! difference `Δ₂ − 2Δ₁` (`Δ_k` the particle displacement between rollout k and rollout 0) is
//! of order ε² and tiny next to `Δ₁`; a contact switch, a yield switch or a rounding that one
//! rollout takes and another does not shows as a step where it jumps to the size of `Δ₁`. The
//! first such step and particle are where to look (this found the chatter of particles in the
//! sharp bottom corner of a cup; see `docs/results/gradients.md`).
//!
//! ```sh
//! cargo run --release --example rollout_divergence -- SCENE [EPS] [DIRECTION] [DX_M|-] [THETA]
//! ```
//!
//! `EPS` defaults to 1e-7; `DIRECTION` is 0–4 for one skill parameter, anything else (the
//! default) for `u = (1, …, 1)/√5`; `DX_M` re-grids the scene as `powderlab study
//! error-vs-time` does (`-` keeps its grid); `THETA` (five comma-separated values) replaces the
//! scene's Θ. With `TRACK=J` in the environment, every step also
//! prints particle `J` of the first body: its `|Δ₁|/ε` and its distance to every collider.
//!
//! Besides the ratio over the whole body, each step prints the largest ratio of one particle to
//! its own displacement (`local`): a switch shows there as O(1) in the particle that switched,
//! even where that particle moves much less than the fastest one. The first step where it
//! passes `SWITCH` is reported with that particle's distance to every collider.

use powderlab::lab::optim::problem::Problem;
use powderlab::lab::study::error_vs_time::{along, parse_theta, regrid};
use powderlab::scene::Scene;

/// `max|Δ₂ − 2Δ₁| / max|Δ₁|` above which a step counts as non-linear in ε: a smooth trajectory
/// gives O(ε·curvature), about 1e-4 at ε = 1e-7 on the default scene, and a switch O(1).
const NONLINEAR: f64 = 1e-2;

/// A particle's `|Δ₂ − 2Δ₁| / (|Δ₁| + LOCAL_FLOOR·max|Δ₁|)` above which it counts as switched:
/// a smooth path gives the ratio above for every particle, a switch about 1 in its own.
const SWITCH: f64 = 0.3;

/// Keeps particles that barely move (`|Δ₁|` near round-off) from dividing by nearly nothing.
const LOCAL_FLOOR: f64 = 1e-3;

/// A particle's `|Δ₂ − 2Δ₁|` (m) below which it is round-off, not a switch: positions near 0.1 m
/// carry 1.4e-17 m per rounding, and one step's thousands of operations leave second differences
/// of 1e-16 to 1e-15 m where nothing switches (the first steps of the default scene at ε = 1e-9).
const ROUND_OFF: f64 = 1e-13;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let Some(path) = args.get(1) else {
        anyhow::bail!("usage: rollout_divergence SCENE [EPS] [DIRECTION] [DX_M|-] [THETA]");
    };
    let eps: f64 = args.get(2).map_or(Ok(1e-7), |s| s.parse())?;
    let dir: usize = args.get(3).map_or(Ok(usize::MAX), |s| s.parse())?;
    let scene = regrid(Scene::load(path)?, args.get(4).map(String::as_str))?;
    let track: Option<usize> = std::env::var("TRACK").ok().map(|s| s.parse()).transpose()?;
    let p = Problem::new(scene, 0)?;
    let t0 = match args.get(5) {
        None => p.scene_theta(),
        Some(t) => parse_theta(t)?,
    };
    let u: [f64; 5] = if dir < 5 {
        let mut u = [0.0; 5];
        u[dir] = 1.0;
        u
    } else {
        [1.0 / 5f64.sqrt(); 5]
    };
    let mut sims = (0..3)
        .map(|k| p.simulation(along(t0, &u, k as f64 * eps), false))
        .collect::<Result<Vec<_>, _>>()?;
    let horizons: Vec<usize> = sims.iter().map(|s| s.horizon).collect();
    if horizons.iter().any(|&h| h != horizons[0]) {
        println!(
            "the horizons differ ({horizons:?}): a phase's rounded step count changes within 2ε"
        );
    }
    let steps = *horizons.iter().min().expect("three rollouts");
    println!("Θ = {t0:?}, ε = {eps:e}, u = {u:?}, {steps} steps");
    println!(
        "{:>5} {:>12} {:>14} {:>10} {:>9} {:>10} {:>9}",
        "step", "max|Δ1|", "max|Δ2-2Δ1|", "ratio", "particle", "local", "particle"
    );
    let (mut first, mut worst_ratio) = (None, 0.0f64);
    let mut first_switch = None;
    let mut parts: Vec<((usize, usize), f64, f64)> = Vec::new();
    // The particle that moves most between rollouts 0 and 1 at the last step: what dominates
    // the gradient of a loss on the final positions.
    let mut last_most = ((0, 0), 0.0, glam::DVec3::ZERO);
    for s in 0..steps {
        for sim in sims.iter_mut() {
            sim.step()?;
        }
        let st: Vec<_> = sims.iter_mut().map(|s| s.body_states()).collect();
        // One pass for every particle's |Δ₁| and |Δ₂ − 2Δ₁|; the local ratios need max|Δ₁|
        // first, so they are read from `parts` afterwards.
        parts.clear();
        let (mut d1max, mut nl, mut worst) = (0.0f64, 0.0f64, (0, 0));
        for (b, s0) in st[0].iter().enumerate() {
            let (x0, x1, x2) = (&s0.x, &st[1][b].x, &st[2][b].x);
            for j in 0..x0.len() {
                let d1 = x1[j] - x0[j];
                d1max = d1max.max(d1.length());
                let n = ((x2[j] - x0[j]) - 2.0 * d1).length();
                if n > nl {
                    (nl, worst) = (n, (b, j));
                }
                parts.push(((b, j), d1.length(), n));
            }
        }
        if let Some(j) = track {
            let x = st[0][0].x[j];
            let d1 = (st[1][0].x[j] - x).length();
            println!(
                "track {s:5}: particle {j} at {x:.5?}, |Δ1|/ε = {:.3e} ({})",
                d1 / eps,
                distances(&mut sims[0], x)
            );
        }
        if s + 1 == steps {
            if let Some(&(at, d1, _)) = parts.iter().max_by(|a, b| a.1.total_cmp(&b.1)) {
                last_most = (at, d1, st[0][at.0].x[at.1]);
            }
        }
        let ratio = if d1max > 0.0 { nl / d1max } else { 0.0 };
        worst_ratio = worst_ratio.max(ratio);
        let (mut local, mut local_at) = (0.0f64, (0, 0));
        if d1max > 0.0 {
            for &(at, d1, n) in &parts {
                let r = n / (d1 + LOCAL_FLOOR * d1max);
                if n > ROUND_OFF && r > local {
                    (local, local_at) = (r, at);
                }
            }
        }
        println!(
            "{s:5} {d1max:12.3e} {nl:14.3e} {ratio:10.2e} {:>4}/{} {local:10.2e} {:>4}/{}",
            worst.0, worst.1, local_at.0, local_at.1
        );
        if local > SWITCH && first_switch.is_none() {
            let x = st[0][local_at.0].x[local_at.1];
            first_switch = Some((s, local_at, x, local, distances(&mut sims[0], x)));
        }
        if ratio > NONLINEAR && first.is_none() {
            let x = st[0][worst.0].x[worst.1];
            first = Some((s, worst, x, distances(&mut sims[0], x)));
        }
    }
    match first {
        Some((s, (b, j), x, near)) => println!(
            "first non-linear step: {s} (body {b}, particle {j} at {x:?} in rollout 0; {near}); largest ratio {worst_ratio:.2e}"
        ),
        None => println!("linear in ε over the whole horizon (largest ratio {worst_ratio:.2e} ≤ {NONLINEAR:e})"),
    }
    let ((b, j), d1, x) = last_most;
    println!(
        "most displaced at the end: body {b}, particle {j} at {x:?} in rollout 0, |Δ1|/ε = {:.3e} m per unit Θ ({})",
        d1 / eps,
        distances(&mut sims[0], x)
    );
    match first_switch {
        Some((s, (b, j), x, r, near)) => println!(
            "first particle to switch: step {s}, body {b}, particle {j} at {x:?} in rollout 0 (local ratio {r:.2e}; {near})"
        ),
        None => println!("no particle's local ratio passes {SWITCH}"),
    }
    Ok(())
}

/// The signed distance from `x` to every collider of `sim` at its current pose, as text.
fn distances(sim: &mut powderlab::sim::Simulation, x: glam::DVec3) -> String {
    sim.collider_poses()
        .into_iter()
        .map(|(name, _, shape, pose)| format!("{name} {:+.3e} m", shape.sdf(pose.to_local(x)).0))
        .collect::<Vec<_>>()
        .join(", ")
}
