//! `study weighing`: milligram doses onto a balance ([`crate::lab::weigh`]) on held-out draws of
//! `vial_weighing.ron`'s powders and targets. Its page is docs/results/weighing.md, with
//! weighing.svg (the balance's reading against time).
//!
//! Each draw's dose is kept in `dir/draw-K.json` as it finishes, and the page is rewritten after
//! every draw, so a killed study resumes where it stopped and its page always says how many of
//! the draws it holds.

use crate::lab::chart;
use crate::lab::policy::dataset::{draw_scene, spec_of};
use crate::lab::stats::{mean, median, quantile_sorted};
use crate::lab::weigh::{self, Dispense, DoseReport};
use crate::scene::randomize::Draw;
use crate::scene::Scene;
use crate::sim::SimOptions;
use plotters::prelude::*;
use serde::{Deserialize, Serialize};
use std::fmt::Write;
use std::path::Path;

/// The held-out stream's seed: no setting of the rule was chosen on its draws.
pub const HELD_OUT_STREAM: u64 = 0x3E16_4001;

/// A dose within this of its target (mg) is a success, the laboratory bar.
pub const SUCCESS_MG: f64 = 2.0;

/// One draw's dose.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Row {
    pub draw: usize,
    pub powder: Draw,
    pub method: String,
    pub dose: DoseReport,
}

/// Runs (or resumes) the rule `d` on held-out draws `first..first + n` of `base`, one after the
/// other (each dose uses the pool of `opts`), in `dir`; `step(draw, step, reading_mg)` after
/// every step of a dose, and `done(rows)` after each draw, with the rows so far in draw order.
/// With `kept_only`, runs none and returns the doses already kept, whichever draws they are (the
/// page's table names them).
#[allow(clippy::too_many_arguments)]
pub fn run(
    base: &Scene,
    d: &Dispense,
    first: usize,
    n: usize,
    opts: &SimOptions,
    dir: &Path,
    kept_only: bool,
    step: &mut dyn FnMut(usize, usize, f64),
    done: &mut dyn FnMut(&[Row]) -> anyhow::Result<()>,
) -> anyhow::Result<Vec<Row>> {
    crate::util::create_output_dir(dir, "--out")?;
    let spec = spec_of(base)?;
    let stamp = serde_json::json!({
        "dispense": d,
        "scene_hash": base.fingerprint(),
        "stream": HELD_OUT_STREAM,
    });
    crate::lab::policy::file::stamped(&dir.join("config.json"), &stamp, "doses", "--out")?;
    let mut rows = Vec::new();
    for k in first..first + n {
        let file = dir.join(format!("draw-{k}.json"));
        if kept_only && !file.is_file() {
            continue;
        }
        let row = crate::lab::policy::file::kept(
            &file,
            |r: &Row| r.draw == k,
            || {
                let draw = draw_scene(spec, base, HELD_OUT_STREAM, k);
                let scene = spec.apply(base, &draw)?;
                let mut progress = |n: usize, mg: f64| step(k, n, mg);
                let dose = weigh::dose(&scene, draw.target_g * 1e3, d, opts, None, &mut progress)?;
                Ok(Row {
                    draw: k,
                    powder: draw,
                    method: "rule".into(),
                    dose,
                })
            },
        )?;
        rows.push(row);
        done(&rows)?;
    }
    Ok(rows)
}

/// The figures of a set of doses.
#[derive(Clone, Debug, PartialEq)]
pub struct Summary {
    pub n: usize,
    pub mean_abs_mg: f64,
    pub median_abs_mg: f64,
    pub p90_abs_mg: f64,
    /// The share within ±[`SUCCESS_MG`].
    pub within: f64,
    pub mean_sim_s: f64,
    pub mean_wall_s: f64,
    pub mean_scoops: f64,
}

pub fn summary(rows: &[Row]) -> Summary {
    let mut abs: Vec<f64> = rows.iter().map(|r| r.dose.error_mg.abs()).collect();
    abs.sort_by(f64::total_cmp);
    let of =
        |f: &dyn Fn(&DoseReport) -> f64| mean(&rows.iter().map(|r| f(&r.dose)).collect::<Vec<_>>());
    Summary {
        n: rows.len(),
        mean_abs_mg: mean(&abs),
        median_abs_mg: median(&abs),
        p90_abs_mg: if abs.is_empty() {
            f64::NAN
        } else {
            quantile_sorted(&abs, 0.9)
        },
        within: abs.iter().filter(|e| **e <= SUCCESS_MG).count() as f64 / abs.len().max(1) as f64,
        mean_sim_s: of(&|d| d.sim_s),
        mean_wall_s: of(&|d| d.wall_s),
        mean_scoops: of(&|d| d.scoops as f64),
    }
}

/// The doses that missed by more than [`SUCCESS_MG`], by what the rule ran into.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Misses {
    /// Short, with every scoop used.
    pub out_of_scoops: usize,
    /// Over the target.
    pub over: usize,
    /// Short, with scoops left.
    pub short: usize,
}

impl Misses {
    pub fn of(rows: &[Row], d: &Dispense) -> Misses {
        let mut m = Misses::default();
        for r in rows.iter().filter(|r| r.dose.error_mg.abs() > SUCCESS_MG) {
            match (r.dose.error_mg > 0.0, r.dose.scoops >= d.max_scoops) {
                (true, _) => m.over += 1,
                (false, true) => m.out_of_scoops += 1,
                (false, false) => m.short += 1,
            }
        }
        m
    }

    pub fn total(&self) -> usize {
        self.out_of_scoops + self.over + self.short
    }
}

/// The page, from the rows so far of `planned` draws starting at `first`.
pub fn page(rows: &[Row], d: &Dispense, first: usize, planned: usize, threads: &str) -> String {
    let mut s = String::new();
    let s_ = summary(rows);
    let _ = writeln!(s, "# Weighing milligram doses onto a balance\n");
    let _ = writeln!(
        s,
        "Regenerate: `powderlab study weighing --threads 2 --draws {planned}` (it keeps each \
         dose in `study/weighing/` and resumes from there; `--page-only` rewrites this page from \
         the doses kept).  \n\
         Machine: AMD EPYC with AVX-512, 2 vCPUs, 23 GiB, a KVM guest; this run's doses on \
         {threads} (the table gives each dose's own). \
         The wall times below are of doses run beside other work on the same two vCPUs, so \
         they are longer than a dose alone takes (about 8 min on two threads, \
         `powderlab weigh`).\n"
    );
    let _ = writeln!(
        s,
        "`scenes/vial_weighing.ron`: a vial of 20 mm inner diameter holding 15–18 mm of powder at \
         dx = 1 mm and 8 grains per cell (36–44k grains), a micro-spatula with a bowl 5 mm across, \
         and a weighing boat on an analytical balance (0.1 mg readability, 0.1 mg noise, a 0.5 s \
         settling lag). Each draw changes the powder (friction angle 25–45°, bulk density \
         500–1,500 kg/m³, fill height, packing) and the target (5–50 mg); a grain then weighs \
         0.06–0.19 mg. The controller sees the balance's reading and the spatula's pose only; \
         the dose is what rests in the boat once everything has settled.\n"
    );
    let _ = writeln!(
        s,
        "**Draws.** Held-out draws {first}–{} of their own stream (`weigh::study::HELD_OUT_STREAM`). \
         Nothing was chosen on them: the rule's settings below were chosen on the scene's own \
         powder (35°, 1,500 kg/m³, one 20 mg dose), which is not a draw of this stream. \
         **{} of the {planned} draws {} done**{}.\n",
        first + planned.max(1) - 1,
        rows.len(),
        if rows.len() == 1 { "is" } else { "are" },
        if rows.len() < planned {
            "; the figures below are of those only, and the study resumes to finish the rest"
        } else {
            ""
        }
    );
    let _ = writeln!(s, "## Result (method: the rule on the balance's reading)\n");
    let _ = writeln!(
        s,
        "| doses | mean \\|error\\| | median | 90th percentile | within ±2 mg | scoops | simulated s per dose | wall s per dose |\n|---|---|---|---|---|---|---|---|"
    );
    let _ = writeln!(
        s,
        "| {} | {:.2} mg | {:.2} mg | {:.2} mg | {:.0} % | {:.1} | {:.1} | {:.0} |\n",
        s_.n,
        s_.mean_abs_mg,
        s_.median_abs_mg,
        s_.p90_abs_mg,
        100.0 * s_.within,
        s_.mean_scoops,
        s_.mean_sim_s,
        s_.mean_wall_s
    );
    let met = s_.n > 0 && s_.mean_abs_mg <= SUCCESS_MG && s_.within >= 0.8;
    let _ = writeln!(
        s,
        "Target (mean |error| ≤ 2 mg and ≥ 80 % within ±2 mg on the {planned} held-out draws): \
         **{}**.\n",
        if s_.n < planned {
            format!(
                "not judged yet; {} on the {} doses so far",
                if met { "met" } else { "missed" },
                s_.n
            )
        } else if met {
            "met".to_string()
        } else {
            "missed".to_string()
        }
    );
    let misses = Misses::of(rows, d);
    if misses.total() > 0 {
        let _ = writeln!(
            s,
            "What the {} beyond ±2 mg {}: {} short after all {} scoops (the \
             spatula's capacity: a scoop of a light powder holds a few milligrams), {} over the \
             target (powder that still left after the spatula turned back, more than the lead \
             allowed for), {} short with scoops to spare (the rule judged the reading done, or \
             the reading lagged the load).\n",
            if misses.total() == 1 {
                "one miss".to_string()
            } else {
                format!("{} misses", misses.total())
            },
            if misses.total() == 1 {
                "comes from"
            } else {
                "come from"
            },
            misses.out_of_scoops,
            d.max_scoops,
            misses.over,
            misses.short
        );
    }
    let _ = writeln!(s, "![the balance's reading against time](weighing.svg)\n");
    let _ = writeln!(s, "## Every dose\n");
    let _ = writeln!(
        s,
        "| draw | friction | density | fill | grain | target | delivered | error | scoops | taps | simulated | wall | threads |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|"
    );
    for r in rows {
        let (p, d) = (&r.powder, &r.dose);
        let _ = writeln!(
            s,
            "| {} | {:.1}° | {:.0} kg/m³ | {:.1} mm | {:.3} mg | {:.1} mg | {:.2} mg | {:+.2} mg | {} | {} | {:.1} s | {:.0} s | {} |",
            r.draw,
            p.friction_deg,
            p.density,
            p.fill_height * 1e3,
            d.grain_mg,
            d.target_mg,
            d.delivered_mg,
            d.error_mg,
            d.scoops,
            d.taps,
            d.sim_s,
            d.wall_s,
            d.threads
                .map_or_else(|| "not recorded".into(), |t| t.to_string())
        );
    }
    let _ = writeln!(s, "\n## The rule's settings\n");
    let _ = writeln!(
        s,
        "Fast to {}°, then {}°/s with taps of {} mm every {} steps, up to {}°; turn back when \
         reading + {} s × rate ≥ target − {} mg; wait {} s; done within {} mg below the target; \
         up to {} scoops.\n",
        d.start_deg,
        d.tilt_deg_s,
        d.tap_mm,
        d.tap_every,
        d.max_deg,
        d.lead_s,
        d.lead_mg,
        d.wait_s,
        d.tolerance_mg,
        d.max_scoops
    );
    s
}

/// weighing.svg: the balance's reading of every dose so far against time, each over its target.
pub fn plot(rows: &[Row], path: &Path) -> anyhow::Result<()> {
    let tmax = rows.iter().map(|r| r.dose.sim_s).fold(1.0, f64::max);
    let ymax = rows
        .iter()
        .map(|r| r.dose.target_mg.max(r.dose.delivered_mg))
        .fold(1.0, f64::max)
        * 1.15;
    chart::write_svg(path, (760, 420), |root| {
        let mut c = ChartBuilder::on(root)
            .caption(
                "the balance's reading while the rule doses",
                ("sans-serif", 16),
            )
            .margin(10)
            .x_label_area_size(36)
            .y_label_area_size(50)
            .build_cartesian_2d(0.0..tmax, -1.0..ymax)?;
        c.configure_mesh()
            .x_desc("simulated time (s)")
            .y_desc("reading (mg)")
            .light_line_style(WHITE)
            .draw()?;
        for (i, r) in rows.iter().enumerate() {
            let colour = Palette99::pick(i).to_rgba();
            let dt = r.dose.sim_s / r.dose.trace.len().max(1) as f64;
            c.draw_series(LineSeries::new(
                r.dose
                    .trace
                    .iter()
                    .enumerate()
                    .map(|(k, t)| ((k + 1) as f64 * dt, t.0)),
                colour.stroke_width(1),
            ))?
            .label(format!("draw {}: {:.1} mg", r.draw, r.dose.target_mg))
            .legend(chart::key(colour.stroke_width(2)));
            c.draw_series(LineSeries::new(
                [(0.0, r.dose.target_mg), (tmax, r.dose.target_mg)],
                colour.mix(0.5).stroke_width(1),
            ))?;
        }
        if !rows.is_empty() {
            chart::legend(
                &mut c,
                SeriesLabelPosition::UpperLeft,
                Some(("sans-serif", 11)),
            )?;
        }
        Ok(())
    })
}

/// Milligram doses onto a balance on held-out powders (weighing.md).
pub struct WeighingStudy;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub common: crate::lab::study::args::Common,
    #[command(flatten)]
    pub page: crate::lab::study::args::Page,
    /// The weighing scene (default scenes/vial_weighing.ron).
    #[arg(long, default_value = "scenes/vial_weighing.ron")]
    pub scene: std::path::PathBuf,
    /// Held-out draws to dose.
    #[arg(long, default_value_t = 20)]
    pub draws: usize,
    /// The first held-out draw.
    #[arg(long, default_value_t = 0)]
    pub first_draw: usize,
    /// Worker threads per dose (default: the scene's setting; 0 = all cores).
    #[arg(long, value_parser = crate::scene::threads_arg)]
    pub threads: Option<usize>,
    /// Run no dose: rewrite the page from the doses already kept.
    #[arg(long)]
    pub page_only: bool,
}
crate::study_settings!(Args);

impl Args {
    /// The page's words for the thread count of the doses run now.
    fn threads(&self, base: &Scene) -> String {
        match self.threads {
            Some(1) => "one thread".to_string(),
            Some(0) => "all cores".to_string(),
            Some(n) => format!("{n} threads"),
            None => format!("{} threads (the scene's setting)", base.simulation.threads),
        }
    }
}

impl crate::lab::study::Study for WeighingStudy {
    const NAME: &'static str = "weighing";
    const ABOUT: &'static str = "Milligram doses onto a balance on held-out powders (weighing.md)";
    type Args = Args;
    type Outcome = Vec<Row>;

    /// The rule's doses on held-out draws, with the page rewritten after every draw.
    fn run(a: &Args, ctx: crate::lab::study::Ctx) -> anyhow::Result<Vec<Row>> {
        let base = Scene::load(&a.scene)?;
        let d = Dispense::default();
        // Resting powder is set aside while nothing comes near it (`sim::rest`).
        let opts = SimOptions {
            rest: Some(crate::sim::rest::RestRule::default()),
            ..SimOptions::threads(a.threads)
        };
        let dir = a
            .common
            .out
            .join(crate::lab::streams::folder("weighing", a.first_draw));
        crate::util::create_output_dir(&a.page.results, "--results")?;
        let threads = a.threads(&base);
        let pb = ctx.bar(a.draws as u64);
        let rows = run(
            &base,
            &d,
            a.first_draw,
            a.draws,
            &opts,
            &dir,
            a.page_only,
            &mut |k, step, mg| {
                if step.is_multiple_of(10) {
                    pb.set_message(format!("draw {k}: step {step}, balance {mg:.1} mg"));
                }
            },
            &mut |rows| {
                pb.set_position(rows.len() as u64);
                plot(rows, &a.page.results.join("weighing.svg"))?;
                crate::util::write_atomic(
                    &a.page.results.join("weighing.md"),
                    page(rows, &d, a.first_draw, a.draws, &threads).as_bytes(),
                )?;
                Ok(())
            },
        )?;
        pb.finish_and_clear();
        Ok(rows)
    }

    /// The page was written after every draw; this says what it holds.
    fn page(
        a: &Args,
        rows: Vec<Row>,
        _: crate::lab::study::Ctx,
    ) -> anyhow::Result<crate::lab::study::Report> {
        let s = summary(&rows);
        Ok(crate::lab::study::Report {
            text: format!(
                "{} doses: mean |error| {:.2} mg, {:.0} % within ±2 mg\n",
                s.n,
                s.mean_abs_mg,
                100.0 * s.within,
            ),
            wrote: "weighing.md and weighing.svg".into(),
            dir: a.page.results.clone(),
            json: serde_json::json!({"doses": s.n, "mean_abs_mg": s.mean_abs_mg, "within_2mg": s.within}),
            failed: false,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(draw: usize, target: f64, delivered: f64, scoops: usize) -> Row {
        Row {
            draw,
            powder: Draw {
                fill_height: 0.015,
                friction_deg: 30.0,
                density: 1000.0,
                youngs_modulus: 5e3,
                source_x: 0.016,
                cup_distance: 0.036,
                target_g: target * 1e-3,
                packing_seed: 0,
            },
            method: "rule".into(),
            dose: DoseReport {
                target_mg: target,
                delivered_mg: delivered,
                error_mg: delivered - target,
                reading_mg: delivered,
                scoops,
                taps: 0,
                sim_s: 10.0,
                wall_s: 100.0,
                threads: Some(1),
                steps: 1000,
                particle_substeps: 1e9,
                rest: true,
                grain_mg: 0.1,
                trace: vec![],
            },
        }
    }

    #[test]
    fn the_summary_and_the_misses_follow_the_doses() {
        let d = Dispense::default();
        let rows = [
            row(0, 10.0, 10.5, 1),
            row(1, 20.0, 23.0, 2),
            row(2, 50.0, 30.0, d.max_scoops),
            row(3, 30.0, 26.0, 2),
            row(4, 5.0, 4.0, 1),
        ];
        let s = summary(&rows);
        assert_eq!(s.n, 5);
        assert!((s.mean_abs_mg - (0.5 + 3.0 + 20.0 + 4.0 + 1.0) / 5.0).abs() < 1e-12);
        assert_eq!(s.median_abs_mg, 3.0);
        assert!((s.within - 0.4).abs() < 1e-12);
        let m = Misses::of(&rows, &d);
        assert_eq!((m.over, m.out_of_scoops, m.short), (1, 1, 1));
        let page = page(&rows, &d, 0, 20, "one thread");
        assert!(page.contains("**5 of the 20 draws are done**"), "{page}");
        assert!(
            page.contains("not judged yet; missed on the 5 doses so far"),
            "{page}"
        );
    }
}
