//! Does the adjoint gradient at points near Θ, one at a time or averaged, point along the
//! loss's slope at the scale of an RMSprop step?
//!
//! ```sh
//! cargo run --release --example smoothed_gradient -- SCENE THETA SIGMA N H
//! ```
//!
//! `THETA` is five comma-separated values. Prints the central secants
//! `(L(Θ + H·e_k) − L(Θ − H·e_k))/2H` (what a step of `H` sees), then the adjoint gradient at
//! `N` points `Θ + σ·ξ` (ξ standard normal, fixed seed) with the cosine of each to the secants,
//! and the cosine of their mean (first-order randomised smoothing, Suh et al. 2022). The sizes
//! of the sampled gradients are what `docs/results/skill_optimisation.md` discusses.
use powderlab::lab::optim::problem::Problem;
use powderlab::lab::stats::{cosine, norm};
use powderlab::lab::study::error_vs_time::parse_theta;
use powderlab::scene::Scene;
use powderlab::skills::Theta;
use powderlab::util::SplitMix64;
use rayon::prelude::*;

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().collect();
    if a.len() != 6 {
        anyhow::bail!(
            "usage: smoothed_gradient SCENE THETA SIGMA N H (THETA: 5 values, comma separated)"
        );
    }
    let p = Problem::new(Scene::load(&a[1])?, 1 << 30)?;
    let t0 = parse_theta(&a[2])?;
    let sigma: f64 = a[3].parse()?;
    let n: usize = a[4].parse()?;
    let h: f64 = a[5].parse()?;
    let jobs: Vec<(usize, f64)> = (0..5).flat_map(|k| [(k, h), (k, -h)]).collect();
    let shifted = jobs
        .par_iter()
        .map(|&(k, d)| {
            let mut t = t0;
            t[k] += d;
            Ok(p.evaluate(t, false, false)?.loss)
        })
        .collect::<anyhow::Result<Vec<f64>>>()?;
    let s: [f64; 5] = std::array::from_fn(|k| (shifted[2 * k] - shifted[2 * k + 1]) / (2.0 * h));
    println!(
        "secant (h {h}): {:?}",
        s.map(|x| (x * 100.0).round() / 100.0)
    );
    let mut rng = SplitMix64(99);
    let pts: Vec<Theta> = (0..n)
        .map(|_| {
            Theta(std::array::from_fn(|i| {
                (t0[i] + sigma * rng.normal()).clamp(-1.0, 1.0)
            }))
        })
        .collect();
    let gs = pts
        .par_iter()
        .map(|&t| Ok(p.evaluate(t, true, false)?.grad.unwrap()))
        .collect::<anyhow::Result<Vec<[f64; 5]>>>()?;
    let mut mean = [0.0; 5];
    for (i, g) in gs.iter().enumerate() {
        for k in 0..5 {
            mean[k] += g[k] / n as f64;
        }
        println!(
            "  sample {i}: cos {:+.3} grad {:?}",
            cosine(g, &s),
            g.map(|x| (x * 100.0).round() / 100.0)
        );
    }
    println!(
        "mean: cos {:+.3} {:?}",
        cosine(&mean, &s),
        mean.map(|x| (x * 100.0).round() / 100.0)
    );
    let mut norms: Vec<f64> = gs.iter().map(|g| norm(g)).collect();
    norms.sort_by(f64::total_cmp);
    let positive = gs.iter().filter(|&g| cosine(g, &s) > 0.0).count();
    println!(
        "{positive}/{n} samples with a positive cosine; gradient norms: median {:.2}, largest {:.2}",
        norms[n / 2],
        norms[n - 1]
    );
    Ok(())
}
