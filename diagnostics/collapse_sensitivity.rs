//! How the planar column collapse of `powderlab validate column_collapse` depends on the
//! material's friction angle and the floor's friction: runs the small-a band (or the aspect
//! ratios given) and prints each run-out against Lube et al.'s law, the band's log–log slope,
//! the front's arrest time and the time the kinetic energy falls below 1e-6 of the initial
//! potential energy.
//!
//! `cargo run --release --example collapse_sensitivity -- PHI_DEG [FLOOR_MU=0.577] [CELLS=20]
//! [A,A,...=0.5,1,1.5] [CFL=0.5] [ROOM=2] [STIFFNESS=100]`
//!
//! CELLS is the cells across L₀ of every column, or, written `30h`, the cells every column
//! stands high (`30h` gives 60, 30 and 20 across L₀ at a = 0.5, 1 and 1.5, the small-a band of
//! `validate column_collapse`; see `equal_height_cells`).
//!
//! The CFL number sets the substeps per step (smaller, more substeps) at a fixed grid; ROOM is the
//! domain's length ahead of the column over the law's front (raise it for a slippery floor, whose
//! run-out would otherwise reach the far wall). STIFFNESS is E/(ρ·g·H₀), held fixed across the
//! aspect ratios as the validation does.

use powderlab::lab::validate::{
    equal_height_cells, loglog_slope, lube_runout, run_collapse, Collapse,
};

fn usage() -> ! {
    eprintln!(
        "usage: collapse_sensitivity PHI_DEG [FLOOR_MU=0.577] [CELLS=20 | HEIGHTh] \
         [A,A,...=0.5,1,1.5] [CFL=0.5] [ROOM=2] [STIFFNESS=100]"
    );
    std::process::exit(2)
}

fn arg<T: std::str::FromStr>(k: usize, default: T) -> T {
    match std::env::args().nth(k) {
        None => default,
        Some(s) => s.parse().unwrap_or_else(|_| usage()),
    }
}

fn main() -> anyhow::Result<()> {
    if std::env::args().len() < 2 {
        usage();
    }
    let phi: f64 = arg(1, 22.0);
    let mu: f64 = arg(2, 0.577);
    // Cells across L₀ (`20`), or cells high (`30h`): then a column of aspect a has 30/a across.
    let cells_arg: String = arg(3, "20".to_string());
    let (cells, equal_height) = match cells_arg.strip_suffix('h') {
        Some(h) => (h.parse::<usize>().unwrap_or_else(|_| usage()), true),
        None => (
            cells_arg.parse::<usize>().unwrap_or_else(|_| usage()),
            false,
        ),
    };
    let aspects: Vec<f64> = match std::env::args().nth(4) {
        None => vec![0.5, 1.0, 1.5],
        Some(s) => s
            .split(',')
            .map(|a| a.parse().unwrap_or_else(|_| usage()))
            .collect(),
    };
    let cfl: f64 = arg(5, 0.5);
    let room: f64 = arg(6, 2.0);
    let stiffness: f64 = arg(7, 100.0);
    let mut pts = Vec::new();
    for &a in &aspects {
        let across = if equal_height {
            equal_height_cells(a, 1.0, cells)
        } else {
            cells
        };
        let mut c = Collapse::new(a, across);
        c.friction_deg = phi;
        c.floor_friction = mu;
        c.cfl = cfl;
        c.room = room;
        c.stiffness_ratio = stiffness;
        let r = run_collapse(&c, None, |_| {})?;
        let fmt = |t: Option<f64>| t.map_or("> 6".to_string(), |t| format!("{t:.2}"));
        println!(
            "phi {phi} floor {mu} cells {across} cfl {cfl} E/(rho g H0) {stiffness} a {a}: run-out {:.3} (law {:.3}, ratio {:.2}), \
             front arrest {} T_c, kinetic energy < 1e-6 at {} T_c (else cut off at 6 T_c), \
             {} particles, {} substeps per step, {:.1} s",
            r.runout_ratio,
            lube_runout(a),
            r.runout_ratio / lube_runout(a),
            // `None` only for an empty front trace, not for a run cut off at 6 T_c.
            r.front_arrest_tc.map_or("none".to_string(), |t| format!("{t:.2}")),
            fmt(r.arrest_tc),
            r.particles,
            r.substeps_per_step,
            r.wall_s
        );
        pts.push((a, r.runout_ratio));
    }
    if pts.len() >= 2 {
        println!(
            "phi {phi} floor {mu} cells {cells_arg} cfl {cfl} E/(rho g H0) {stiffness}: log-log slope {:.3}",
            loglog_slope(&pts)
        );
    }
    Ok(())
}
