//! `study pour`: can a spoon's load be metered by tilting it against a load cell
//! ([`crate::lab::policy::pour`])? Its page is docs/results/pour.md, with pour.svg.
//!
//! On the policy page's held-out draws of `policy_dosing.ron` (dx = 5 mm) and of the same draws
//! of `policy_dosing_fine.ron` (dx = 2.5 mm), the spoon scoops at the family's deepest setting
//! ([`crate::lab::policy::knob::family`] at +1: the most powder to pour from), is carried over the
//! target cup, and pours under the gravimetric loop toward the draw's target. Each draw's result
//! is kept in `dir/<resolution>/scene-J.json`, so a killed study resumes. Two variants at dx = 5
//! mm: one turns the spoon back faster than the skill's angular speed, one taps it.
//!
//! The open-loop reference is the distilled policy of `study policy` on the same draws at dx = 5
//! mm, read from `dir/../policy/eval` when that study has run in the same `--out`.

use crate::lab::chart;
use crate::lab::policy::dataset::{self, draw_scene, problem_of, spec_of};
use crate::lab::policy::eval::{Trial, HELD_OUT_STREAM};
use crate::lab::policy::pour::{self, Gravimetric};
use crate::lab::stats::median;
use crate::lab::stats::{mean, p_text, sd, wilcoxon_less};
use crate::scene::Scene;
use plotters::prelude::*;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::fmt::Write;
use std::path::Path;

/// One draw's gravimetric pour.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Row {
    pub scene: usize,
    pub dx: f64,
    pub target_g: f64,
    /// The load cell's reading when the pour began (g).
    pub held_g: f64,
    /// The tilt at which the spoon turned back (degrees), if it did before the limit.
    pub turn_deg: Option<f64>,
    /// The mass that had left the spoon when it turned back (g).
    pub poured_at_turn_g: Option<f64>,
    pub delivered_g: f64,
    pub wall_s: f64,
    pub particle_substeps: f64,
    /// Per pour step: the tilt (degrees) and the mass that had left the spoon (g).
    pub trace: Vec<(f64, f64)>,
}

impl Row {
    /// `delivered − target` (g).
    pub fn error_g(&self) -> f64 {
        self.delivered_g - self.target_g
    }
    /// What still reached the cup after the spoon turned back (g).
    pub fn after_turn_g(&self) -> Option<f64> {
        self.poured_at_turn_g.map(|p| self.delivered_g - p)
    }
    /// The largest mass that left the spoon in one pour step (g): how bursty the outflow is.
    pub fn largest_step_g(&self) -> f64 {
        self.trace
            .windows(2)
            .map(|w| w[1].1 - w[0].1)
            .fold(0.0, f64::max)
    }
}

/// The study's settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Settings {
    /// Held-out draws at dx = 5 mm.
    pub scenes: usize,
    /// The first of them again at dx = 2.5 mm.
    pub fine_scenes: usize,
    pub pour: Gravimetric,
    /// The variant at dx = 5 mm that turns back this fast (degrees/s).
    pub faster_turn_back_deg: f64,
    /// The tapped variant at dx = 5 mm: its pour settings (a tap size, a slow creep).
    pub tapped: Gravimetric,
    /// The policy study's dataset seed (the held-out stream is derived from it).
    pub seed: u64,
    /// The first held-out draw (`EvalConfig::first_draw`): the pours run draws
    /// `first_draw..first_draw + scenes`.
    #[serde(default)]
    pub first_draw: usize,
}

/// Runs (or resumes) the pours `g` of `base` for held-out draws `first..first + n` of the
/// policy study's seed `seed`, in `dir`.
pub fn run(
    base: &Scene,
    g: &Gravimetric,
    seed: u64,
    first: usize,
    n: usize,
    dir: &Path,
    progress: &(dyn Fn(usize) + Sync),
) -> anyhow::Result<Vec<Row>> {
    crate::util::create_output_dir(dir, "--out")?;
    let spec = spec_of(base)?;
    let stamp = serde_json::json!({
        "pour": g,
        "seed": seed,
        "scene_hash": base.fingerprint(),
    });
    crate::lab::policy::file::stamped(&dir.join("pour-config.json"), &stamp, "pours", "--out")?;
    let done = std::sync::atomic::AtomicUsize::new(0);
    (first..first + n)
        .into_par_iter()
        .map(|j| {
            let row = crate::lab::policy::file::kept(
                &dir.join(format!("scene-{j}.json")),
                |_| true,
                || {
                    let d = draw_scene(spec, base, seed.wrapping_add(HELD_OUT_STREAM), j);
                    let (problem, _) = problem_of(base, &d)?;
                    let theta = crate::lab::policy::knob::family(&problem, &d, 1.0);
                    let (o, t) = pour::rollout(&problem, theta, d.target_g, g)?;
                    Ok(Row {
                        scene: j,
                        dx: base.simulation.dx,
                        target_g: d.target_g,
                        held_g: t.held_g,
                        turn_deg: t.stopped_at.map(|k| t.steps[k].0),
                        poured_at_turn_g: t.stopped_at.map(|k| t.steps[k].1),
                        delivered_g: o.transported,
                        wall_s: o.wall_s,
                        particle_substeps: dataset::cost(&o),
                        trace: t.steps,
                    })
                },
            )?;
            progress(done.fetch_add(1, std::sync::atomic::Ordering::SeqCst) + 1);
            Ok(row)
        })
        .collect()
}

/// The distilled policy's trials on held-out draws `first..first + n`, from the policy study in
/// `policy_dir` (`None` when it has not run them all there).
pub fn policy_trials(policy_dir: &Path, first: usize, n: usize) -> Option<Vec<Trial>> {
    let layout = crate::lab::policy::features::layout();
    let p = crate::lab::policy::net::Policy::load(
        &policy_dir.join("policy.safetensors"),
        &layout,
        crate::lab::policy::net::OUTPUTS,
    )
    .ok()?;
    let fp = p.fingerprint().ok()?;
    let eval = crate::lab::policy::eval::dir_name(first);
    (first..first + n)
        .map(|j| policy_dir.join(format!("{eval}/scene-{j}/policy-{fp}.json")))
        .map(|f| serde_json::from_str(&std::fs::read_to_string(f).ok()?).ok())
        .collect()
}

/// The mean over `rows` of the largest mass to leave the spoon in one pour step (g).
fn burst<'a>(rows: impl IntoIterator<Item = &'a Row>) -> f64 {
    mean(
        &rows
            .into_iter()
            .map(Row::largest_step_g)
            .collect::<Vec<_>>(),
    )
}

/// The page; `turn_back_deg` is the skill's angular speed, at which the spoon turns back.
#[allow(clippy::too_many_arguments)]
pub fn report(
    coarse: &[Row],
    fine: &[Row],
    faster: &[Row],
    tapped: &[Row],
    policy: Option<&[Trial]>,
    s: &Settings,
    command: &str,
    machine: &str,
    minutes: f64,
    turn_back_deg: f64,
) -> String {
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# The gravimetric pour: metering a spoon's load against a load cell\n"
    );
    let _ = writeln!(md, "Regenerate: `{command}` (about {minutes:.0} min on this machine; it keeps each pour under `--out` and resumes after a kill).  ");
    let _ = writeln!(md, "Machine: {machine}.\n");
    let _ = writeln!(md, "**Why.** The distilled policy of [policy.md](policy.md) doses open loop: it chooses how deep to scoop, and the spoon empties what it took. What it takes depends on the grains' packing, which no policy sees, so even the per-scene optimiser's own Θ misses on a repacked powder (the policy page's *repacked* column says by how much). A lab robot meters against a balance instead. This study asks whether the spoon can: after the carry it tilts at the skill's angular speed up to {1}° and at {0}°/s past it, a load cell at the wrist reads what the bowl still holds, and the spoon turns back at the skill's angular speed as soon as the mass that has left it, plus {2} steps of its current outflow, reaches the dose (`powderlab::lab::policy::pour`). The spoon scoops at the family's deepest setting, so it holds the most there is to pour from; a dose above what it holds is poured whole. One rollout, no network.\n",
        s.pour.speed_deg, s.pour.fast_to_deg, s.pour.lead_steps);
    let stream = crate::lab::policy::eval::stream_text(s.first_draw, s.scenes);
    let _ = writeln!(md, "**Draws.** The policy page's held-out draws: {} of `scenes/policy_dosing.ron` (dx = 5 mm) and the first {} again from `scenes/policy_dosing_fine.ron`, the same scenes at dx = 2.5 mm (2³ = 8× the particles at the same particles per cell). {stream}\n", coarse.len(), fine.len());
    let _ = writeln!(md, "| pour | draws | dose error (g), mean ± sd | median | within 0.1 g | after the turn (g), mean | rollout (s) | particle-substeps |");
    let _ = writeln!(md, "|---|---|---|---|---|---|---|---|");
    let faster_name = format!(
        "gravimetric, dx = 5 mm, turning back at {}°/s",
        s.faster_turn_back_deg
    );
    let tapped_name = format!(
        "tapped, dx = 5 mm: {} mm taps past {}°, creeping at {}°/s",
        s.tapped.tap_mm.unwrap_or(0.0),
        s.tapped.fast_to_deg,
        s.tapped.speed_deg
    );
    for (name, rows) in [
        ("gravimetric, dx = 5 mm", coarse),
        (faster_name.as_str(), faster),
        (tapped_name.as_str(), tapped),
        ("gravimetric, dx = 2.5 mm", fine),
    ] {
        if rows.is_empty() {
            continue;
        }
        let e: Vec<f64> = rows.iter().map(|r| r.error_g().abs()).collect();
        let after: Vec<f64> = rows.iter().filter_map(Row::after_turn_g).collect();
        let _ = writeln!(
            md,
            "| {name} | {} | {:.3} ± {:.3} | {:.3} | {}/{} | {} | {:.1} | {:.3} G |",
            rows.len(),
            mean(&e),
            sd(&e),
            median(&e),
            e.iter().filter(|x| **x <= 0.1).count(),
            rows.len(),
            if after.is_empty() {
                "–".to_string()
            } else {
                format!("{:.3} ({} turns)", mean(&after), after.len())
            },
            mean(&rows.iter().map(|r| r.wall_s).collect::<Vec<_>>()),
            mean(&rows.iter().map(|r| r.particle_substeps).collect::<Vec<_>>()) / 1e9,
        );
    }
    let policy_err: Option<Vec<f64>> = policy
        .filter(|p| p.len() >= coarse.len() && !coarse.is_empty())
        .map(|p| {
            p[..coarse.len()]
                .iter()
                .map(|t| t.indicator.abs())
                .collect()
        });
    if let (Some(pe), Some(p)) = (&policy_err, policy) {
        let _ = writeln!(
            md,
            "| open loop: the distilled policy, dx = 5 mm | {} | {:.3} ± {:.3} | {:.3} | {}/{} | – | {:.1} | {:.3} G |",
            pe.len(),
            mean(pe),
            sd(pe),
            median(pe),
            pe.iter().filter(|x| **x <= 0.1).count(),
            pe.len(),
            mean(&p[..pe.len()].iter().map(|t| t.wall_s).collect::<Vec<_>>()),
            mean(&p[..pe.len()].iter().map(|t| t.particle_substeps).collect::<Vec<_>>()) / 1e9,
        );
    }
    let _ = writeln!(md);
    if let Some(pe) = &policy_err {
        let ge: Vec<f64> = coarse.iter().map(|r| r.error_g().abs()).collect();
        let _ = writeln!(md, "Paired on the {} draws at dx = 5 mm (one-sided Wilcoxon signed-rank): the gravimetric pour is more accurate than the open-loop policy, p = {}; less accurate, p = {}.\n", ge.len(), p_text(wilcoxon_less(&ge, pe)), p_text(wilcoxon_less(pe, &ge)));
    }
    if let Some(pe) = &policy_err {
        let ge: Vec<f64> = coarse.iter().map(|r| r.error_g().abs()).collect();
        let after: Vec<f64> = coarse.iter().filter_map(Row::after_turn_g).collect();
        let less: Vec<f64> = fine
            .iter()
            .filter_map(|f| {
                coarse
                    .iter()
                    .find(|c| c.scene == f.scene)
                    .map(|c| c.held_g - f.held_g)
            })
            .collect();
        let turned: Vec<&Row> = fine.iter().filter(|r| r.turn_deg.is_some()).collect();
        let alpha = crate::lab::stats::ALPHA;
        let better = wilcoxon_less(&ge, pe).is_some_and(|p| p < alpha);
        let worse = wilcoxon_less(pe, &ge).is_some_and(|p| p < alpha);
        let _ = writeln!(md, "**Verdict.** {} At dx = 5 mm the loop misses by {:.3} g against the open-loop policy's {:.3} g. The largest mass to leave the bowl in one step averages {:.3} g over the draws (the doses average {:.3} g), and after the spoon turns back {:.3} g still leaves on average over the {} pours that turned, against a lead of {} steps of the outflow before the turn.\n",
            if better { "The gravimetric pour doses better than the open-loop policy." } else if worse { "**The gravimetric pour does not meter the dose**: it is worse than the open-loop policy at the 5 % level." } else { "**The gravimetric pour is not shown better than the open-loop policy**, nor worse, at the 5 % level." },
            mean(&ge), mean(pe), burst(coarse), mean(&coarse.iter().map(|r| r.target_g).collect::<Vec<_>>()), mean(&after), after.len(), s.pour.lead_steps);
        if !fine.is_empty() {
            let coarse_same = fine
                .iter()
                .filter_map(|f| coarse.iter().find(|c| c.scene == f.scene));
            let (bf, bc) = (burst(fine), burst(coarse_same));
            let _ = writeln!(md, "At dx = 2.5 mm, at {:.0}× the compute, the largest one-step outflow averages {:.3} g against {:.3} g at 5 mm on the same draws ({}). There the deepest scoop holds {:.2} g less than at 5 mm on average (up to {:.2} g), and on {} of the {} draws it holds less than the dose. On the {} draws on which the spoon turned back, {} g more left after the turn and the dose was missed by {}.\n",
                mean(&fine.iter().map(|r| r.particle_substeps).collect::<Vec<_>>()) / mean(&coarse.iter().map(|r| r.particle_substeps).collect::<Vec<_>>()),
                bf, bc,
                if bf < bc { format!("{:.1}× smaller steps", bc / bf) } else { "no smoother".to_string() },
                mean(&less),
                less.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                fine.iter().filter(|r| r.held_g < r.target_g).count(),
                fine.len(),
                turned.len(),
                turned.iter().map(|r| format!("{:.3}", r.after_turn_g().unwrap_or(f64::NAN))).collect::<Vec<_>>().join(" and "),
                turned.iter().map(|r| format!("{:+.3} g", r.error_g())).collect::<Vec<_>>().join(" and "));
        }
        if faster.len() == coarse.len() && !faster.is_empty() {
            let fe: Vec<f64> = faster.iter().map(|r| r.error_g().abs()).collect();
            let fa: Vec<f64> = faster.iter().filter_map(Row::after_turn_g).collect();
            let p = wilcoxon_less(&fe, &ge);
            let helps = p.is_some_and(|p| p < alpha);
            let beats = wilcoxon_less(&fe, pe).is_some_and(|p| p < alpha);
            let _ = writeln!(md, "Turning back {:.0}× faster, at {}°/s instead of the skill's {turn_back_deg}°/s, {}: {:.3} g against {:.3} g on the same draws (p = {} that it is lower), {:.1}× the open-loop policy's error, with {:.3} g still leaving after the turn.\n",
                s.faster_turn_back_deg / turn_back_deg, s.faster_turn_back_deg,
                match (helps, beats) {
                    (true, true) => "helps, and beats the open-loop policy at the 5 % level",
                    (true, false) => "helps, but is not shown better than the open-loop policy",
                    (false, true) => "is not shown to help the plain loop, but beats the open-loop policy",
                    (false, false) => "is not shown to help",
                },
                mean(&fe), mean(&ge), p_text(p), mean(&fe) / mean(pe), mean(&fa));
        }
        if tapped.len() == coarse.len() && !tapped.is_empty() {
            let te: Vec<f64> = tapped.iter().map(|r| r.error_g().abs()).collect();
            let ta: Vec<f64> = tapped.iter().filter_map(Row::after_turn_g).collect();
            let p = wilcoxon_less(&te, &ge);
            let beats = wilcoxon_less(&te, pe).is_some_and(|p| p < alpha);
            let (bt, bc) = (burst(tapped), burst(coarse));
            let _ = writeln!(md, "Tapping the spoon instead ({} mm down and up on alternate steps past {}°, the tilt creeping at {}°/s, up to {}°) {} (the largest one-step outflow averages {bt:.3} g against the plain loop's {bc:.3} g), and {}: {:.3} g against the plain loop's {:.3} g (p = {} that it is lower), {:.1}× the open-loop policy's error (p = {} that it is lower), with {:.3} g still leaving after the taps stop and the spoon turns back.\n",
                s.tapped.tap_mm.unwrap_or(0.0), s.tapped.fast_to_deg, s.tapped.speed_deg, s.tapped.max_deg,
                if bt < bc { "makes the outflow more gradual" } else { "does not make the outflow more gradual" },
                if beats { "beats the open-loop policy at the 5 % level" } else { "is not shown better than the open-loop policy" },
                mean(&te), mean(&ge), p_text(p), mean(&te) / mean(pe), p_text(wilcoxon_less(&te, pe)), mean(&ta));
        }
        if !better {
            let _ = writeln!(md, "What might meter it (not built or tested here): an actuator whose outflow stops when it stops, such as a screw feeder, or feedback between scoops, such as a second, small scoop that tops up what the balance reads.\n");
        }
    }
    if let Some((c, f)) = shown(coarse, fine) {
        let _ = writeln!(
            md,
            "![Mass that has left the spoon against its tilt](pour.svg)\n"
        );
        let mut cap = format!("*The mass that has left the spoon against its tilt on draw {}, at both resolutions, with the dose ({:.3} g): the first draw on which the spoon turned back at both.", c.scene, c.target_g);
        for (r, name) in [(c, "5 mm"), (f, "2.5 mm")] {
            let onset = r
                .trace
                .iter()
                .find(|p| p.1 >= ONSET_G)
                .map_or(f64::NAN, |p| p.0);
            let burst = r.largest_step_g();
            let _ = write!(cap, " At dx = {name} the first {ONSET_G} g has left by {onset:.1}°, the largest step's outflow is {burst:.3} g, the spoon turns back at {:.1}° with {:.3} g out, and {:.3} g more leaves after.", r.turn_deg.unwrap_or(f64::NAN), r.poured_at_turn_g.unwrap_or(f64::NAN), r.after_turn_g().unwrap_or(f64::NAN));
        }
        let _ = writeln!(md, "{cap}*\n");
    }
    if !fine.is_empty() {
        let _ = writeln!(
            md,
            "**Each draw at dx = 2.5 mm** (the same draw at dx = 5 mm in brackets):\n"
        );
        let _ = writeln!(md, "| draw | target (g) | in the spoon (g) | turned back at | left when it turned (g) | delivered (g) | error (g) |");
        let _ = writeln!(md, "|---|---|---|---|---|---|---|");
        for r in fine {
            let c = coarse.iter().find(|c| c.scene == r.scene);
            let opt =
                |v: Option<f64>, unit: &str| v.map_or("–".into(), |v| format!("{v:.3}{unit}"));
            let _ = writeln!(
                md,
                "| {} | {:.3} | {:.3} ({}) | {} ({}) | {} | {:.3} ({}) | {:+.3} ({}) |",
                r.scene,
                r.target_g,
                r.held_g,
                opt(c.map(|c| c.held_g), ""),
                r.turn_deg.map_or("–".into(), |a| format!("{a:.1}°")),
                c.and_then(|c| c.turn_deg)
                    .map_or("–".into(), |a| format!("{a:.1}°")),
                opt(r.poured_at_turn_g, ""),
                r.delivered_g,
                opt(c.map(|c| c.delivered_g), ""),
                r.error_g(),
                c.map_or("–".into(), |c| format!("{:+.3}", c.error_g())),
            );
        }
        let _ = writeln!(md);
    }
    md
}

/// The outflow that marks the pour's start in the figure's caption (g): two grains at dx = 5
/// mm, past the few loose grains that roll off the heap early.
const ONSET_G: f64 = 0.05;

/// The draw the figure shows: the first on which the spoon turned back at both resolutions.
pub fn shown<'a>(coarse: &'a [Row], fine: &'a [Row]) -> Option<(&'a Row, &'a Row)> {
    fine.iter().filter(|f| f.turn_deg.is_some()).find_map(|f| {
        coarse
            .iter()
            .find(|c| c.scene == f.scene && c.turn_deg.is_some())
            .map(|c| (c, f))
    })
}

/// pour.svg: the mass that has left the spoon against its tilt, per pour step, for one draw at
/// each resolution ([`shown`]), with the dose.
pub fn figure(path: &Path, coarse: Option<&Row>, fine: Option<&Row>) -> anyhow::Result<()> {
    chart::write_svg(path, (700, 420), |root| {
        let rows: Vec<&Row> = [coarse, fine].into_iter().flatten().collect();
        let ymax = rows
            .iter()
            .flat_map(|r| r.trace.iter().map(|p| p.1).chain([r.target_g]))
            .fold(0.0f64, f64::max)
            * 1.1;
        let xmax = rows
            .iter()
            .flat_map(|r| r.trace.iter().map(|p| p.0))
            .fold(1.0f64, f64::max);
        let mut c = ChartBuilder::on(root)
            .caption(
                format!(
                    "gravimetric pour, draw {}",
                    coarse.or(fine).map_or(0, |r| r.scene)
                ),
                ("sans-serif", 16),
            )
            .margin(10)
            .x_label_area_size(36)
            .y_label_area_size(50)
            .build_cartesian_2d(0.0..xmax, 0.0..ymax.max(0.1))?;
        c.configure_mesh()
            .x_desc("tilt (degrees), rising then turning back")
            .y_desc("mass that has left the spoon (g)")
            .light_line_style(WHITE)
            .draw()?;
        for (r, colour, name) in [(coarse, RED, "dx = 5 mm"), (fine, BLUE, "dx = 2.5 mm")] {
            let Some(r) = r else { continue };
            c.draw_series(LineSeries::new(
                r.trace.iter().copied(),
                colour.stroke_width(2),
            ))?
            .label(name)
            .legend(chart::key(colour.stroke_width(2)));
        }
        if let Some(r) = coarse.or(fine) {
            c.draw_series(LineSeries::new(
                [(0.0, r.target_g), (xmax, r.target_g)],
                BLACK.stroke_width(1),
            ))?
            .label("the dose")
            .legend(chart::key(BLACK));
        }
        chart::legend(&mut c, SeriesLabelPosition::UpperLeft, None)?;
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::skills::Theta;

    fn row(scene: usize, error_g: f64, burst_g: f64) -> Row {
        Row {
            scene,
            dx: 0.005,
            target_g: 1.0,
            held_g: 2.0,
            turn_deg: Some(80.0),
            poured_at_turn_g: Some(0.9),
            delivered_g: 1.0 + error_g,
            wall_s: 1.0,
            particle_substeps: 1e6,
            trace: vec![(60.0, 0.0), (70.0, burst_g), (80.0, burst_g + 0.01)],
        }
    }

    fn trial(error_g: f64) -> Trial {
        Trial {
            method: "policy".into(),
            theta: Theta([0.0; 5]),
            loss: 0.0,
            indicator: error_g,
            rollouts: 1.0,
            particle_substeps: 1e6,
            wall_s: 1.0,
        }
    }

    fn page(loop_err: f64, policy_err: f64, tapped_burst: f64) -> String {
        let coarse: Vec<Row> = (0..10)
            .map(|j| row(j, loop_err * (1.0 + 0.1 * j as f64), 0.2))
            .collect();
        let tapped: Vec<Row> = (0..10)
            .map(|j| row(j, loop_err * (1.0 + 0.1 * j as f64), tapped_burst))
            .collect();
        let policy: Vec<Trial> = (0..10)
            .map(|j| trial(policy_err * (1.0 + 0.05 * j as f64)))
            .collect();
        let s = Settings {
            scenes: 10,
            fine_scenes: 0,
            pour: Default::default(),
            faster_turn_back_deg: 720.0,
            tapped: Default::default(),
            seed: 0,
            first_draw: 0,
        };
        report(
            &coarse,
            &[],
            &[],
            &tapped,
            Some(&policy),
            &s,
            "cmd",
            "machine",
            1.0,
            360.0,
        )
    }

    /// The verdicts are the data's: the loop better or worse than the policy, and the taps
    /// gradual or not, flip with the figures instead of being fixed text.
    #[test]
    fn the_verdicts_follow_the_data() {
        let better = page(0.05, 0.2, 0.05);
        assert!(
            better.contains("The gravimetric pour doses better"),
            "{better}"
        );
        assert!(
            better.contains("makes the outflow more gradual"),
            "{better}"
        );
        assert!(!better.contains("What might meter it"), "{better}");
        let worse = page(0.2, 0.05, 0.3);
        assert!(
            worse.contains("it is worse than the open-loop policy"),
            "{worse}"
        );
        assert!(
            worse.contains("does not make the outflow more gradual"),
            "{worse}"
        );
        assert!(worse.contains("What might meter it"), "{worse}");
    }
}
