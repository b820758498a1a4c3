//! `powderlab study growth`: how the cost of a substep grows with the particle count and with
//! the grid.
//!
//! Two series on variants of the `sand_box` scene (the Taichi reference's scene: a cube of
//! Drucker–Prager sand, 2×2×2 particles per cell on a regular lattice, a moving box tool, unit
//! cube domain with 3 wall cells):
//! - **particles**: the block is 0.4 of the domain wide and the grid is refined with it, from
//!   about 10k to 1M particles. Particles per cell and the block's share of the domain stay
//!   fixed, so a constant time per particle-substep is the ideal.
//! - **grid**: a fixed block of 19 cells (38³ = 54,872 particles, less 56 that the tool starts
//!   in on the coarsest grid) on ever larger grids, 32³ to 160³ nodes. The grid stages sweep
//!   only the active spans (`components::grid::ActiveRows`), so they grow with the rows, not
//!   the nodes; the **grid_dense** series repeats the grid series with dense sweeps, the
//!   measure of what the active-block grid saves.
//!
//! Each configuration runs in a child process of its own (its peak RSS is its own); the substeps
//! per step grow with the resolution so that every variant passes the strict stability check.
//! The first step (one substep's allocations, the warm start of the SVD) is not timed; the next
//! [`TIMED_STEPS`] are.

use crate::lab::chart;
use crate::scene::{BodySpec, Fill, Scene};
use crate::sim::{SimOptions, Simulation};
use crate::util::{peak_rss_bytes, write_atomic};
use anyhow::Context;
use plotters::coord::combinators::IntoLogRange;
use plotters::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Which series a configuration belongs to.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum Series {
    Particles,
    Grid,
    /// The grid series with every grid stage sweeping every node (`Grid::sparse` off): what
    /// the active-block grid saves.
    GridDense,
}

/// One configuration: `cells`³ grid nodes over the unit cube, a block `block_cells` cells wide.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct GrowthConfig {
    pub series: Series,
    pub cells: usize,
    pub block_cells: usize,
    pub threads: Option<usize>,
    /// Global steps timed after the untimed first one.
    pub timed_steps: usize,
}

/// What one configuration measured.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct GrowthResult {
    pub config: GrowthConfig,
    pub particles: usize,
    pub nodes: usize,
    pub threads: usize,
    pub substeps_timed: u64,
    pub wall_s: f64,
    pub seconds_per_substep: f64,
    pub ns_per_particle_substep: f64,
    pub particle_substeps_per_s: f64,
    pub peak_rss_bytes: u64,
    /// [`crate::components::state_fingerprint`] of the final state: a grid configuration and
    /// its dense twin must agree.
    pub state_bits: String,
}

/// `sand_box`'s resolution, at which it takes 20 substeps per step.
const BASE_CELLS: usize = 48;
const BASE_SUBSTEPS: usize = 20;
/// Block width of the grid series: `sand_box`'s block (0.4 m at 48 cells is 19.2 cells; 19
/// keeps the lattice whole).
const GRID_SERIES_BLOCK: usize = 19;

/// Global steps timed per configuration, after the untimed first: the same window of simulated
/// time, `[Δt, 6Δt]`, at every resolution. One step is not enough: the cost of a substep moves
/// with the block's state in the first steps, and not in the same way at every resolution (at
/// 86, 108 and 126 cells the second step ran at 201–203 ns per particle-substep and the next
/// four at 238–253; at 27 cells all five at 252–270).
pub const TIMED_STEPS: usize = 5;

/// The study's configurations. `quick`: two small ones per series, one timed step each (tests).
pub fn plan(quick: bool, threads: Option<usize>) -> Vec<GrowthConfig> {
    let particles: &[usize] = if quick {
        &[16, 20]
    } else {
        &[27, 34, 43, 54, 68, 86, 108, 126]
    };
    let grid: &[usize] = if quick {
        &[24, 32]
    } else {
        &[32, 48, 64, 96, 128, 160]
    };
    let timed_steps = if quick { 1 } else { TIMED_STEPS };
    let block = |n: usize| {
        if quick {
            4
        } else {
            (0.4 * n as f64).round() as usize
        }
    };
    particles
        .iter()
        .map(|&n| GrowthConfig {
            series: Series::Particles,
            cells: n,
            block_cells: block(n),
            threads,
            timed_steps,
        })
        .chain(
            [Series::Grid, Series::GridDense]
                .into_iter()
                .flat_map(|series| {
                    grid.iter().map(move |&n| GrowthConfig {
                        series,
                        cells: n,
                        block_cells: if quick { 4 } else { GRID_SERIES_BLOCK },
                        threads,
                        timed_steps,
                    })
                }),
        )
        .collect()
}

/// `base` (the `sand_box` scene) at `cfg`'s resolution and block size. The block is centred in
/// x and z and stands one cell above the floor's wall cells, on whole cells, so the regular
/// lattice puts exactly `(2·block_cells)³` particles in it.
pub fn growth_scene(base: &Scene, cfg: &GrowthConfig) -> anyhow::Result<Scene> {
    let mut s = base.clone();
    let n = cfg.cells;
    let dx = 1.0 / n as f64;
    let walls = s.simulation.walls.cells;
    if cfg.block_cells + 2 * walls + 2 > n {
        anyhow::bail!(
            "a block of {} cells does not fit a {n}-cell grid with {walls} wall cells",
            cfg.block_cells
        );
    }
    s.simulation.cells = (n, n, n);
    s.simulation.dx = dx;
    s.simulation.substeps = (BASE_SUBSTEPS * n).div_ceil(BASE_CELLS);
    let lo_xz = ((n - cfg.block_cells) / 2) as f64 * dx;
    let lo_y = (walls + 1) as f64 * dx;
    let side = cfg.block_cells as f64 * dx;
    let body: &mut BodySpec = s
        .bodies
        .first_mut()
        .ok_or_else(|| anyhow::anyhow!("the growth study's scene has no body"))?;
    body.fill = Fill::Box {
        min: (lo_xz, lo_y, lo_xz),
        max: (lo_xz + side, lo_y + side, lo_xz + side),
    };
    Ok(s)
}

/// The simulation of a configuration, on its threads, with per-stage timers if asked.
pub fn simulation(
    base: &Scene,
    cfg: &GrowthConfig,
    stage_timers: bool,
) -> anyhow::Result<Simulation> {
    Ok(Simulation::new(
        &growth_scene(base, cfg)?,
        &SimOptions {
            threads: cfg.threads,
            stage_timers,
            ..Default::default()
        },
    )?)
}

/// Runs one configuration in this process: one untimed step, then `timed_steps` timed steps.
pub fn run_config(base: &Scene, cfg: &GrowthConfig) -> anyhow::Result<GrowthResult> {
    let mut sim = simulation(base, cfg, false)?;
    sim.world.resource_mut::<crate::components::Grid>().sparse = cfg.series != Series::GridDense;
    let particles = sim.particle_count();
    let n = cfg.cells;
    sim.step()?;
    let before = sim.clock().total_substeps;
    let t = Instant::now();
    for _ in 0..cfg.timed_steps {
        sim.step()?;
    }
    let wall_s = t.elapsed().as_secs_f64();
    let substeps_timed = sim.clock().total_substeps - before;
    let per = wall_s / substeps_timed as f64;
    Ok(GrowthResult {
        config: cfg.clone(),
        particles,
        nodes: n * n * n,
        threads: sim.threads(),
        substeps_timed,
        wall_s,
        seconds_per_substep: per,
        ns_per_particle_substep: per / particles as f64 * 1e9,
        particle_substeps_per_s: particles as f64 / per,
        peak_rss_bytes: peak_rss_bytes(),
        state_bits: format!(
            "{:016x}",
            crate::components::state_fingerprint(&sim.body_states())
        ),
    })
}

/// Largest over smallest throughput of the particle series: the "flat within 20 %"
/// asks for at most 1.2.
pub fn particle_series_spread(results: &[GrowthResult]) -> Option<f64> {
    let rates: Vec<f64> = results
        .iter()
        .filter(|r| r.config.series == Series::Particles)
        .map(|r| r.particle_substeps_per_s)
        .collect();
    let hi = rates.iter().copied().fold(f64::NAN, f64::max);
    let lo = rates.iter().copied().fold(f64::NAN, f64::min);
    (rates.len() >= 2).then_some(hi / lo)
}

/// Per grid measured both ways: `(cells, dense over active seconds per substep, whether the
/// two final states agree to the bit)`.
pub fn active_grid_gain(results: &[GrowthResult]) -> Vec<(usize, f64, bool)> {
    results
        .iter()
        .filter(|r| r.config.series == Series::Grid)
        .filter_map(|a| {
            results
                .iter()
                .find(|d| d.config.series == Series::GridDense && d.config.cells == a.config.cells)
                .map(|d| {
                    (
                        a.config.cells,
                        d.seconds_per_substep / a.seconds_per_substep,
                        d.state_bits == a.state_bits,
                    )
                })
        })
        .collect()
}

/// Seconds per substep on the largest grid over the smallest, in `series` (the growth with
/// the empty nodes at a fixed particle count).
pub fn grid_series_growth(results: &[GrowthResult], series: Series) -> Option<f64> {
    let pts: Vec<&GrowthResult> = results
        .iter()
        .filter(|r| r.config.series == series)
        .collect();
    let lo = pts.iter().min_by_key(|r| r.nodes)?;
    let hi = pts.iter().max_by_key(|r| r.nodes)?;
    (pts.len() >= 2).then(|| hi.seconds_per_substep / lo.seconds_per_substep)
}

/// Where the study writes.
pub struct GrowthOutputs {
    pub results: PathBuf,
    pub csv: PathBuf,
    pub svg: PathBuf,
}

impl GrowthOutputs {
    pub fn in_dir(dir: &Path) -> GrowthOutputs {
        GrowthOutputs {
            results: dir.join("growth.json"),
            csv: dir.join("growth.csv"),
            svg: dir.join("growth.svg"),
        }
    }
}

pub fn csv(results: &[GrowthResult]) -> String {
    let mut s = String::from(
        "series,cells,particles,nodes,threads,substeps_timed,seconds_per_substep,ns_per_particle_substep,particle_substeps_per_s,peak_rss_mb\n",
    );
    for r in results {
        s.push_str(&format!(
            "{},{},{},{},{},{},{:.6e},{:.2},{:.4e},{:.1}\n",
            match r.config.series {
                Series::Particles => "particles",
                Series::Grid => "grid",
                Series::GridDense => "grid_dense",
            },
            r.config.cells,
            r.particles,
            r.nodes,
            r.threads,
            r.substeps_timed,
            r.seconds_per_substep,
            r.ns_per_particle_substep,
            r.particle_substeps_per_s,
            r.peak_rss_bytes as f64 / 1e6
        ));
    }
    s
}

/// Writes the results, the CSV and the figure, each atomically.
pub fn write_outputs(out: &GrowthOutputs, results: &[GrowthResult]) -> anyhow::Result<()> {
    write_atomic(
        &out.results,
        serde_json::to_string_pretty(results)?.as_bytes(),
    )?;
    write_atomic(&out.csv, csv(results).as_bytes())?;
    svg(&out.svg, results)
}

/// A plotted configuration: (particles or grid nodes, ms per substep, ns per particle-substep).
type Point = (f64, f64, f64);
/// A plotted quantity: its legend label, its colour and its value at a point.
type Quantity = (&'static str, RGBColor, fn(&Point) -> f64);

/// Two log–log panels: time per substep against the particle count (particle series) and
/// against the grid nodes (grid series), each with the time per particle-substep beside it.
fn svg(path: &Path, results: &[GrowthResult]) -> anyhow::Result<()> {
    chart::write_svg(path, (1100, 480), |root| {
        let root = root.titled(
            "powderlab: time per substep (sand_box variants, 2×2×2 particles per cell)",
            ("sans-serif", 20),
        )?;
        let panels = root.split_evenly((1, 2));
        // The legend goes where each panel's lines leave room: the particle series' time per
        // substep rises to the upper right, the grid series' lines start low on the left.
        for (area, (series, xlabel, corner)) in panels.iter().zip([
            (
                Series::Particles,
                "particles (grid refined with the block)",
                SeriesLabelPosition::LowerRight,
            ),
            (
                Series::Grid,
                "grid nodes (54,872 particles)",
                SeriesLabelPosition::UpperLeft,
            ),
        ]) {
            let points = |series: Series| -> Vec<Point> {
                results
                    .iter()
                    .filter(|r| r.config.series == series)
                    .map(|r| {
                        let x = match series {
                            Series::Particles => r.particles as f64,
                            Series::Grid | Series::GridDense => r.nodes as f64,
                        };
                        (x, r.seconds_per_substep * 1e3, r.ns_per_particle_substep)
                    })
                    .collect()
            };
            let pts = points(series);
            let dense = if series == Series::Grid {
                points(Series::GridDense)
            } else {
                Vec::new()
            };
            if pts.is_empty() {
                continue;
            }
            let (x0, x1) = pts
                .iter()
                .fold((f64::MAX, 0.0f64), |a, p| (a.0.min(p.0), a.1.max(p.0)));
            let ys = pts.iter().chain(&dense).flat_map(|p| [p.1, p.2]);
            let (y0, y1) = ys.fold((f64::MAX, 0.0f64), |a, y| (a.0.min(y), a.1.max(y)));
            let mut chart = ChartBuilder::on(area)
                .margin(12)
                .x_label_area_size(40)
                .y_label_area_size(60)
                .build_cartesian_2d(
                    (x0 / 1.5..x1 * 1.5).log_scale(),
                    (y0 / 2.0..y1 * 2.0).log_scale(),
                )?;
            chart
                .configure_mesh()
                .x_desc(xlabel)
                .y_desc("ms per substep / ns per particle-substep")
                .x_label_formatter(&|v| format!("{v:.0e}"))
                .y_label_formatter(&|v| format!("{v:.3}"))
                .draw()?;
            let quantities: [Quantity; 2] = [
                ("ms per substep", RGBColor(31, 119, 180), |p| p.1),
                ("ns per particle-substep", RGBColor(255, 127, 14), |p| p.2),
            ];
            for (label, colour, y) in quantities {
                chart
                    .draw_series(LineSeries::new(
                        pts.iter().map(|p| (p.0, y(p))),
                        colour.stroke_width(2),
                    ))?
                    .label(label)
                    .legend(chart::key(colour));
                chart.draw_series(
                    pts.iter()
                        .map(|p| Circle::new((p.0, y(p)), 3, colour.filled())),
                )?;
            }
            if !dense.is_empty() {
                let grey = RGBColor(120, 120, 120);
                chart
                    .draw_series(LineSeries::new(
                        dense.iter().map(|p| (p.0, p.1)),
                        grey.stroke_width(2),
                    ))?
                    .label("ms per substep, dense grid sweeps")
                    .legend(chart::key(grey));
                chart.draw_series(
                    dense
                        .iter()
                        .map(|p| Circle::new((p.0, p.1), 3, grey.filled())),
                )?;
            }
            chart::legend(&mut chart, corner, None)?;
        }
        Ok(())
    })
}

/// Time per substep against the particle count and the grid (growth.{json,csv,svg}).
pub struct Growth;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub common: crate::lab::study::args::Common,
    #[command(flatten)]
    pub run: crate::lab::study::args::Run,
    /// Run one configuration (JSON) and print its result (in a process of its own).
    #[arg(long, hide = true)]
    pub config: Option<String>,
}
crate::study_settings!(Args);

/// The scene every configuration varies.
const BASE_SCENE: &str = "scenes/sand_box.ron";

impl crate::lab::study::Study for Growth {
    const NAME: &'static str = "growth";
    const ABOUT: &'static str =
        "Time per substep against the particle count and the grid (growth.{json,csv,svg})";
    type Args = Args;
    type Outcome = Vec<GrowthResult>;

    fn child(a: &Args) -> Option<anyhow::Result<()>> {
        let c = a.config.as_ref()?;
        Some((|| {
            let base = Scene::load(BASE_SCENE)?;
            let cfg: GrowthConfig = serde_json::from_str(c).context("--config")?;
            println!("{}", serde_json::to_string(&run_config(&base, &cfg)?)?);
            Ok(())
        })())
    }

    fn run(a: &Args, ctx: crate::lab::study::Ctx) -> anyhow::Result<Vec<GrowthResult>> {
        let base = Scene::load(BASE_SCENE)?;
        let plan = plan(a.run.quick, a.run.threads.or(Some(2)));
        for cfg in &plan {
            growth_scene(&base, cfg)?;
        }
        let exe = std::env::current_exe().context("cannot find this executable")?;
        crate::util::create_output_dir(&a.common.out, "--out")?;
        let outputs = GrowthOutputs::in_dir(&a.common.out);
        let pb = ctx.bar(plan.len() as u64);
        let mut results = Vec::new();
        for cfg in &plan {
            pb.set_message(format!("{:?} {} cells", cfg.series, cfg.cells));
            let r: GrowthResult = crate::lab::study::run_in_child(&exe, Self::NAME, cfg)
                .with_context(|| format!("growth configuration {cfg:?} failed"))?;
            results.push(r);
            // Everything measured so far is on disk, whenever the study is stopped.
            write_outputs(&outputs, &results)?;
            pb.inc(1);
        }
        pb.finish_and_clear();
        Ok(results)
    }

    fn page(
        a: &Args,
        results: Vec<GrowthResult>,
        _ctx: crate::lab::study::Ctx,
    ) -> anyhow::Result<crate::lab::study::Report> {
        use std::fmt::Write;
        let outputs = GrowthOutputs::in_dir(&a.common.out);
        let spread = particle_series_spread(&results);
        let gain = active_grid_gain(&results);
        let (grown, grown_dense) = (
            grid_series_growth(&results, Series::Grid),
            grid_series_growth(&results, Series::GridDense),
        );
        let mut text = csv(&results);
        if let Some(s) = spread {
            let _ = writeln!(
                text,
                "particle series: fastest/slowest throughput {s:.3} (flat within 20 % is ≤ 1.2: {})",
                if s <= 1.2 { "PASS" } else { "FAIL" }
            );
        }
        if let (Some(g), Some(d)) = (grown, grown_dense) {
            let _ = writeln!(
                text,
                "grid series: largest over smallest grid's time per substep {g:.2} (dense sweeps {d:.2})"
            );
        }
        for (cells, r, same) in &gain {
            let _ = writeln!(
                text,
                "{cells}³ grid: dense sweeps take {r:.2}× the active grid's time; final states {}",
                if *same { "equal to the bit" } else { "DIFFER" }
            );
        }
        Ok(crate::lab::study::Report {
            text,
            wrote: format!(
                "{} configurations: {}, {} and {}",
                results.len(),
                outputs.csv.display(),
                outputs.svg.display(),
                outputs.results.display()
            ),
            dir: a.common.out.clone(),
            json: serde_json::json!({
                "results": results,
                "particle_series_max_over_min_throughput": spread,
                "grid_series_largest_over_smallest": grown,
                "grid_dense_series_largest_over_smallest": grown_dense,
                "active_grid_gain": gain
                    .iter()
                    .map(|(c, r, same)| serde_json::json!({"cells": c, "dense_over_active": r, "same_bits": same}))
                    .collect::<Vec<_>>(),
                "csv": outputs.csv,
                "svg": outputs.svg,
            }),
            failed: false,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The variants put (2·block)³ particles on the lattice, less those the box tool starts
    /// in (the grid series' 32-cell block is 0.59 m wide and reaches the tool), and keep the
    /// strict stability check's substep count growing with the resolution.
    #[test]
    fn scenes_hold_the_planned_particles() {
        let base =
            Scene::load(concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/sand_box.ron")).unwrap();
        for cfg in plan(false, Some(1)).into_iter().filter(|c| c.cells <= 48) {
            let s = growth_scene(&base, &cfg).unwrap();
            assert_eq!(
                s.simulation.substeps,
                (BASE_SUBSTEPS * cfg.cells).div_ceil(BASE_CELLS)
            );
            let mut sim = Simulation::new(&s, &SimOptions::default()).unwrap();
            let lattice = (2 * cfg.block_cells).pow(3);
            let n = sim.particle_count();
            match cfg.series {
                Series::Particles => assert_eq!(n, lattice, "{cfg:?}"),
                Series::Grid | Series::GridDense => {
                    assert!(n <= lattice && n * 1000 >= lattice * 998, "{cfg:?}: {n}")
                }
            }
        }
    }
}
