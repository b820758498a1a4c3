//! One silo discharge through a slot, or a round orifice with `round`, printed as the validation
//! page's row: `cargo run --release --example silo_probe -- [round] D_CELLS FILL_CELLS [dp|mui]
//! [GRAIN_MM]`.
//! Prints its progress on stderr, then the discharged fraction every 0.1 s, the rate and the
//! constant.

use powderlab::lab::validate::silo::{run_silo, Silo};
use powderlab::lab::validate::Rheology;

fn main() -> anyhow::Result<()> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: silo_probe [round] D_CELLS FILL_CELLS [dp|mui] [GRAIN_MM]";
    let round = args.first().is_some_and(|a| a == "round");
    if round {
        args.remove(0);
    }
    let slot: usize = args
        .first()
        .and_then(|a| a.parse().ok())
        .ok_or_else(|| anyhow::anyhow!(usage))?;
    let fill: usize = args
        .get(1)
        .and_then(|a| a.parse().ok())
        .ok_or_else(|| anyhow::anyhow!(usage))?;
    let mut s = if round {
        Silo::round(slot, fill)
    } else {
        Silo::new(slot, fill)
    };
    match args.get(2).map(String::as_str) {
        None | Some("dp") => {}
        Some("mui") => {
            let grain_mm: f64 = args.get(3).and_then(|a| a.parse().ok()).unwrap_or(1.0);
            s.rheology = Rheology::mu_i_matching(s.friction_deg, grain_mm * 1e-3);
        }
        Some(other) => anyhow::bail!("rheology '{other}': expected dp or mui; {usage}"),
    }
    // Progress on stderr every 5 % (of the window's end, or of the time limit if the silo jams).
    let start = std::time::Instant::now();
    let mut shown = 0.0;
    let r = run_silo(&s, None, |p| {
        if p >= shown + 0.05 {
            shown = p;
            eprintln!(
                "{:3.0} %  {:.0} s",
                100.0 * p,
                start.elapsed().as_secs_f64()
            );
        }
    })?;
    let mut next = 0.0;
    for &(t, f) in &r.trace {
        if t + 1e-9 >= next {
            println!("t = {t:.3} s  discharged {f:.4}");
            next += 0.1;
        }
    }
    println!(
        "| {} | {} | {} | {} | {:.4} | {:.3} | {} | {:.0} s |",
        r.opening_cells,
        r.fill_cells,
        args.get(2).map_or("dp", String::as_str),
        r.particles,
        r.rate.unwrap_or(f64::NAN),
        r.beverloo_c.unwrap_or(f64::NAN),
        r.substeps,
        r.wall_s
    );
    Ok(())
}
