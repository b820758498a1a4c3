//! The loss of a skill scene along one skill parameter, at a fine spacing: how rough the
//! landscape is at the scale of an RMSprop step.
//!
//! ```sh
//! cargo run --release --example loss_line -- SCENE THETA K LO HI N [PPC]
//! ```
//!
//! Evaluates the loss and indicator at `N` evenly spaced values of `θ_K` in `[LO, HI]`, the other
//! parameters at `THETA` (five comma-separated values), with every body's particles per cell
//! set to `PPC` if given. Then sums up the `N − 1` differences between neighbours: the rise
//! from end to end, the total variation, the share of the total variation in the steepest
//! quarter of the intervals, and how many intervals go against the rise.
use powderlab::lab::optim::problem::Problem;
use powderlab::lab::study::error_vs_time::parse_theta;
use powderlab::scene::Scene;
use rayon::prelude::*;

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().collect();
    if a.len() < 7 {
        anyhow::bail!("usage: loss_line SCENE THETA K LO HI N [PPC]");
    }
    let mut scene = Scene::load(&a[1])?;
    if let Some(ppc) = a.get(7) {
        let ppc: usize = ppc.parse()?;
        for b in &mut scene.bodies {
            b.particles_per_cell = ppc;
        }
    }
    let theta = parse_theta(&a[2])?;
    let k: usize = a[3].parse()?;
    anyhow::ensure!(k < 5, "K is a parameter index 0..=4, got {k}");
    let (lo, hi, n): (f64, f64, usize) = (a[4].parse()?, a[5].parse()?, a[6].parse()?);
    anyhow::ensure!(n >= 2, "N must be at least 2");
    let p = Problem::new(scene, 1 << 30)?;
    let xs: Vec<f64> = (0..n)
        .map(|i| lo + (hi - lo) * i as f64 / (n - 1) as f64)
        .collect();
    let outcomes: Vec<_> = xs
        .par_iter()
        .map(|&x| {
            let mut t = theta;
            t[k] = x;
            p.evaluate(t, false, true)
        })
        .collect::<anyhow::Result<_>>()?;
    for (x, o) in xs.iter().zip(&outcomes) {
        println!(
            "θ_{k} {x:.4}: loss {:.4}, indicator {:.3}",
            o.loss, o.indicator
        );
    }
    let d: Vec<f64> = outcomes.windows(2).map(|w| w[1].loss - w[0].loss).collect();
    let rise = outcomes[n - 1].loss - outcomes[0].loss;
    let tv: f64 = d.iter().map(|x| x.abs()).sum();
    let mut steep: Vec<f64> = d.iter().map(|x| x.abs()).collect();
    steep.sort_by(|a, b| b.total_cmp(a));
    let quarter: f64 = steep[..d.len().div_ceil(4)].iter().sum();
    let against = d.iter().filter(|x| x.signum() != rise.signum()).count();
    println!(
        "rise {rise:+.4} (secant slope {:+.3}), total variation {tv:.4}, steepest quarter of the \
         intervals carries {:.0} % of it, {against} of {} intervals against the rise",
        rise / (hi - lo),
        100.0 * quarter / tv,
        d.len()
    );
    Ok(())
}
