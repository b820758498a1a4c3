//! The deposit of one planar column collapse as a height profile, and its front by several
//! measures, so that two resolutions can be compared above the grid scale.
//!
//! `cargo run --release --example collapse_profile -- [A=1] [CELLS=20] [FLOOR_MU=0.577] [PHI=22]
//! [CFL=0.5] [PPC=8]`
//!
//! Prints the deposit height h(x)/L₀ in bins 0.05·L₀ wide (from the particles' volume, which is
//! exact whatever the resolution), then the front as the last bin with h ≥ t for several
//! thresholds t (in L₀), the validation's one-cell front, percentiles of x, and the
//! validation's front every 0.5 T_c.

use powderlab::lab::validate::{run_collapse, Collapse, COLLAPSE_SLAB_CELLS};

/// Argument `k` (named `name` in errors), or `default` when it is absent.
fn arg<T: std::str::FromStr>(k: usize, name: &str, default: T) -> anyhow::Result<T> {
    match std::env::args().nth(k) {
        None => Ok(default),
        Some(s) => s.parse().map_err(|_| {
            anyhow::anyhow!(
                "{name} = {s:?} does not parse (CELLS and PPC are whole numbers); usage: collapse_profile [A=1] [CELLS=20] [FLOOR_MU=0.577] \
                 [PHI=22] [CFL=0.5] [PPC=8]"
            )
        }),
    }
}

fn main() -> anyhow::Result<()> {
    let a: f64 = arg(1, "A", 1.0)?;
    let cells: usize = arg(2, "CELLS", 20)?;
    let mut c = Collapse::new(a, cells);
    c.floor_friction = arg(3, "FLOOR_MU", 0.577)?;
    c.friction_deg = arg(4, "PHI", 22.0)?;
    c.cfl = arg(5, "CFL", 0.5)?;
    c.particles_per_cell = arg(6, "PPC", 8)?;
    let r = run_collapse(&c, None, |_| {})?;
    let dx_l0 = 1.0 / cells as f64;
    // Particle volume over L₀³, and the slab's depth over L₀.
    let vp = dx_l0.powi(3) / c.particles_per_cell as f64;
    let depth = COLLAPSE_SLAB_CELLS as f64 * dx_l0;
    let w = 0.05;
    let xs: Vec<f64> = r.deposit.iter().map(|p| p.x).collect();
    let nb = (xs.iter().copied().fold(0.0, f64::max) / w).ceil() as usize + 1;
    let mut h = vec![0.0; nb];
    for &x in &xs {
        h[((x / w).floor().max(0.0) as usize).min(nb - 1)] += vp / (w * depth);
    }
    println!(
        "a {a} cells {cells} ppc {} floor {} phi {} cfl {}: run-out (validation front) {:.3}, {} particles, {:.1} s",
        c.particles_per_cell, c.floor_friction, c.friction_deg, c.cfl, r.runout_ratio, r.particles, r.wall_s
    );
    let line: Vec<String> = h.iter().map(|h| format!("{h:.3}")).collect();
    println!("h/L0 per 0.05 L0 bin: {}", line.join(" "));
    for t in [0.005, 0.01, 0.02, 0.05, 0.1] {
        let b = h.iter().rposition(|&h| h >= t).map_or(0, |b| b + 1);
        println!("front where h >= {t} L0: run-out {:.3}", b as f64 * w - 1.0);
    }
    let tc = (a * c.length / 9.81).sqrt();
    let line: Vec<String> = (1..=12)
        .map(|k| {
            let t = 0.5 * k as f64 * tc;
            let f = r.front_trace.iter().rev().find(|f| f.0 <= t + 1e-12);
            f.map_or("-".into(), |f| format!("{:.3}", f.1 as f64 * dx_l0 - 1.0))
        })
        .collect();
    println!("run-out (front) at 0.5, 1, ..., 6 T_c: {}", line.join(" "));
    let mut s = xs.clone();
    s.sort_by(f64::total_cmp);
    for q in [0.95, 0.99, 0.999] {
        let x = s[((q * (s.len() - 1) as f64).round()) as usize];
        println!("x percentile {q}: run-out {:.3}", x - 1.0);
    }
    Ok(())
}
