//! How far the adjoint gradient `∂L/∂Θ` of a skill scene predicts its loss.
//!
//! ```sh
//! cargo run --release --example gradient_at_scale -- SCENE [H] [SAMPLES]
//! ```
//!
//! Two measurements, both printed:
//! - **Line.** From the scene's Θ, the loss at `Θ ∓ h·ĝ` (ĝ the unit adjoint gradient) for `h`
//!   from 1e-5 to 3.2e-2, with the slope each pair implies, against `‖∂L/∂Θ‖`.
//! - **Secants.** At `SAMPLES` random Θ (in [−0.8, 0.8]⁵, fixed seed), the cosine between the
//!   adjoint gradient and the central secants `(L(Θ + H·e_k) − L(Θ − H·e_k))/2H`, and how many
//!   of the components agree in sign. `H` (default 0.1) is the scale of an RMSprop step at the
//!   paper's learning rate.

use powderlab::lab::optim::problem::Problem;
use powderlab::lab::optim::study::directions::secant_thetas;
use powderlab::lab::stats::{cosine, norm};
use powderlab::scene::Scene;
use powderlab::skills::Theta;
use rayon::prelude::*;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let Some(path) = args.get(1) else {
        anyhow::bail!("usage: gradient_at_scale SCENE [H] [SAMPLES]");
    };
    let h: f64 = args.get(2).map_or(Ok(0.1), |s| s.parse())?;
    let samples: usize = args.get(3).map_or(Ok(6), |s| s.parse())?;
    let p = Problem::new(Scene::load(path)?, 1 << 30)?;

    let t0 = p.scene_theta();
    let o = p.evaluate(t0, true, false)?;
    let g = o.grad.expect("asked for the gradient");
    let n = norm(&g);
    println!(
        "line from the scene's Θ {t0:?}: L = {:.9}, ‖∂L/∂Θ‖ = {n:.4}",
        o.loss
    );
    let steps = [1e-5, 1e-4, 3e-4, 1e-3, 2e-3, 4e-3, 8e-3, 1.6e-2, 3.2e-2];
    let line: Vec<(f64, f64, f64)> = steps
        .par_iter()
        .map(|&s| {
            let at = |sign: f64| -> anyhow::Result<f64> {
                let t = Theta(std::array::from_fn(|i| t0[i] + sign * s * g[i] / n));
                Ok(p.evaluate(t, false, false)?.loss)
            };
            Ok((s, at(-1.0)?, at(1.0)?))
        })
        .collect::<anyhow::Result<_>>()?;
    for (s, down, up) in line {
        println!(
            "  h {s:.0e}: L(Θ − hĝ) − L = {:+.3e}, L(Θ + hĝ) − L = {:+.3e}, central slope {:+.4}",
            down - o.loss,
            up - o.loss,
            (up - down) / (2.0 * s)
        );
    }

    let (mut cos_sum, mut agree) = (0.0, 0);
    println!("secants of half-width {h} at {samples} random Θ:");
    for (i, t0) in secant_thetas(samples).into_iter().enumerate() {
        let jobs: Vec<(usize, f64)> = (0..5).flat_map(|k| [(k, h), (k, -h)]).collect();
        let (centre, shifted) = rayon::join(
            || p.evaluate(t0, true, false),
            || {
                jobs.par_iter()
                    .map(|&(k, d)| {
                        let mut t = t0;
                        t[k] += d;
                        Ok(p.evaluate(t, false, false)?.loss)
                    })
                    .collect::<anyhow::Result<Vec<f64>>>()
            },
        );
        let (centre, shifted) = (centre?, shifted?);
        let g = centre.grad.expect("asked for the gradient");
        let s: [f64; 5] =
            std::array::from_fn(|k| (shifted[2 * k] - shifted[2 * k + 1]) / (2.0 * h));
        let c = cosine(&g, &s);
        cos_sum += c;
        agree += (0..5).filter(|&k| g[k].signum() == s[k].signum()).count();
        println!(
            "  {i}: indicator {:.2}, cos {c:+.3}, adjoint {:?}, secant {:?}",
            centre.indicator,
            g.map(|x| (x * 100.0).round() / 100.0),
            s.map(|x| (x * 100.0).round() / 100.0)
        );
    }
    println!(
        "mean cosine {:+.3}, sign agreement {agree}/{}",
        cos_sum / samples as f64,
        5 * samples
    );
    Ok(())
}
