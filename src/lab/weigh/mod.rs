//! Weighing: milligram doses from a vial onto a balance with a micro-spatula, closed on the
//! balance's reading (`powderlab weigh`, docs/results/weighing.md).
//!
//! **The rule** ([`Dispense`], method `rule`). The spatula scoops, lifts and carries as the
//! scene's skill does (its first four phases), over the weighing boat. It then tilts about the
//! skill's pour axis, fast to [`Dispense::start_deg`] and slowly past it, tapping: the spatula
//! drops by [`Dispense::tap_mm`] in one step and rises back the next, every
//! [`Dispense::tap_every`] steps. It turns back upright once
//!
//! ```text
//! reading + lead_s · rate ≥ target − lead_mg,    rate = the reading's slope over the last 0.2 s
//! ```
//!
//! (the powder still in flight or on the lip while it turns back, and the balance's lag), waits
//! [`Dispense::wait_s`] for the reading to settle, and judges: within
//! [`Dispense::tolerance_mg`] below the target, or above it, the dose is done (an overshoot is
//! an error; nothing is taken back). Short of it, it tilts again, fast to a few degrees below
//! where the powder first moved the reading; a spatula tilted to [`Dispense::max_deg`] that no
//! longer moves the reading is empty, and it goes back for a top-up scoop, up to
//! [`Dispense::max_scoops`] in all. A top-up returns upright through the air to the start pose
//! moved by the next of [`TOPUP_OFFSETS_MM`] along the transport direction (fresh powder beside
//! the last scoop's hole) and repeats the skill's scoop and carry from there.
//!
//! **What the controller sees**: the balance's reading and the spatula's pose, never the
//! particles. The delivered mass it is judged by is the boat's content once everything has
//! settled ([`crate::systems::balance::load_g`], the truth behind the reading).

pub(crate) mod study;

use crate::math::pose::{quat_to_rotation_vector, Pose};
use crate::record::Recorder;
use crate::scene::{ControlSpec, Scene};
use crate::sim::{SimOptions, Simulation};
use crate::skills::SkillSpec;
use anyhow::{bail, ensure, Context, Result};
use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Where each scoop starts, along the skill's transport direction from its start pose (mm).
pub const TOPUP_OFFSETS_MM: [f64; 5] = [0.0, -4.0, 4.0, -2.0, 2.0];

/// After the rule's last wait, how long the grains still falling get to land before the boat's
/// content is taken as the dose (s): the fall from the spatula to the boat takes about 0.1 s.
pub const FINAL_SETTLE_S: f64 = 0.5;

/// Steps between the recorded frames of the particles (the balance's reading is recorded every
/// step): a 1,500-step dose of 36k grains at every step is 690 MB.
pub const RECORD_EVERY: usize = 5;

/// The most simulated time a dose may take (s): the rule then turns back and stops, and the
/// dose is what has reached the boat. Every resume waits [`Dispense::wait_s`] for the reading,
/// and nothing else bounds how often the rule resumes on a spatula that still holds powder; a
/// real robot's dose takes one to a few minutes.
pub const MAX_DOSE_S: f64 = 300.0;

/// The window over which the rule estimates the reading's rate (s).
pub const RATE_WINDOW_S: f64 = 0.2;

/// Settings of the dispensing rule.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Dispense {
    /// Tilt reached at the skill's angular speed before the slow, tapped tilt (degrees).
    pub start_deg: f64,
    /// Tilt speed while tapping (degrees/s).
    pub tilt_deg_s: f64,
    /// The most the spatula tilts (degrees).
    pub max_deg: f64,
    /// How far a tap drops the spatula (mm); 0, no taps.
    pub tap_mm: f64,
    /// Steps from one tap's start to the next's (at least 2: down, then up).
    pub tap_every: usize,
    /// Fixed part of the lead (mg).
    pub lead_mg: f64,
    /// Rate part of the lead (s).
    pub lead_s: f64,
    /// Wait after turning back before judging the reading (s).
    pub wait_s: f64,
    /// A settled reading this close below the target ends the dose (mg).
    pub tolerance_mg: f64,
    /// The most scoops, the first included.
    pub max_scoops: usize,
}

impl Default for Dispense {
    /// Chosen on the weighing study's training draws (docs/results/weighing.md says which).
    fn default() -> Self {
        Dispense {
            start_deg: 20.0,
            tilt_deg_s: 20.0,
            max_deg: 110.0,
            tap_mm: 0.5,
            tap_every: 4,
            lead_mg: 0.3,
            lead_s: 0.6,
            wait_s: 1.5,
            tolerance_mg: 1.0,
            max_scoops: 4,
        }
    }
}

impl Dispense {
    /// The settings' names, for `--dispense NAME=VALUE`.
    pub const NAMES: [&'static str; 10] = [
        "start_deg",
        "tilt_deg_s",
        "max_deg",
        "tap_mm",
        "tap_every",
        "lead_mg",
        "lead_s",
        "wait_s",
        "tolerance_mg",
        "max_scoops",
    ];

    /// Sets one setting by name; refuses an unknown name or a value outside its range, in one
    /// line naming both.
    pub fn set(&mut self, name: &str, v: f64) -> Result<()> {
        let count = |v: f64, lo: f64| -> Result<usize> {
            ensure!(
                v.fract() == 0.0 && v >= lo && v <= 1e6,
                "dispense.{name} = {v}: expected a whole number from {lo} to 1e6"
            );
            Ok(v as usize)
        };
        match name {
            "start_deg" => self.start_deg = v,
            "tilt_deg_s" => self.tilt_deg_s = v,
            "max_deg" => self.max_deg = v,
            "tap_mm" => self.tap_mm = v,
            "tap_every" => self.tap_every = count(v, 2.0)?,
            "lead_mg" => self.lead_mg = v,
            "lead_s" => self.lead_s = v,
            "wait_s" => self.wait_s = v,
            "tolerance_mg" => self.tolerance_mg = v,
            "max_scoops" => self.max_scoops = count(v, 1.0)?,
            _ => bail!(
                "dispense.{name}: no such setting; expected one of {}",
                Self::NAMES.join(", ")
            ),
        }
        self.validate()
    }

    /// Refuses settings the rule cannot run, naming the first bad one.
    pub fn validate(&self) -> Result<()> {
        let checks: [(&str, f64, bool, &str); 10] = [
            (
                "start_deg",
                self.start_deg,
                (0.0..180.0).contains(&self.start_deg),
                "in [0, 180)",
            ),
            ("tilt_deg_s", self.tilt_deg_s, self.tilt_deg_s > 0.0, "> 0"),
            (
                "max_deg",
                self.max_deg,
                self.max_deg > self.start_deg && self.max_deg <= 180.0,
                "in (start_deg, 180]",
            ),
            (
                "tap_mm",
                self.tap_mm,
                (0.0..=5.0).contains(&self.tap_mm),
                "in [0, 5] mm",
            ),
            (
                "tap_every",
                self.tap_every as f64,
                self.tap_every >= 2,
                ">= 2 steps",
            ),
            ("lead_mg", self.lead_mg, self.lead_mg >= 0.0, ">= 0"),
            ("lead_s", self.lead_s, self.lead_s >= 0.0, ">= 0"),
            (
                "wait_s",
                self.wait_s,
                self.wait_s >= 0.0 && self.wait_s <= 60.0,
                "in [0, 60] s",
            ),
            (
                "tolerance_mg",
                self.tolerance_mg,
                self.tolerance_mg >= 0.0,
                ">= 0",
            ),
            (
                "max_scoops",
                self.max_scoops as f64,
                (1..=TOPUP_OFFSETS_MM.len()).contains(&self.max_scoops),
                "from 1 to 5",
            ),
        ];
        for (name, v, ok, what) in checks {
            ensure!(
                ok && v.is_finite(),
                "dispense.{name} = {v}: expected {what}"
            );
        }
        Ok(())
    }
}

/// One dose.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DoseReport {
    pub target_mg: f64,
    /// What rests in the boat once everything has settled (mg).
    pub delivered_mg: f64,
    /// `delivered − target` (mg): positive an overshoot.
    pub error_mg: f64,
    /// The balance's final reading (mg).
    pub reading_mg: f64,
    pub scoops: usize,
    pub taps: usize,
    /// Simulated time of the dose (s).
    pub sim_s: f64,
    pub wall_s: f64,
    /// Worker threads the dose ran on (`None` in doses kept before it was recorded).
    #[serde(default)]
    pub threads: Option<usize>,
    pub steps: usize,
    /// The particle-substeps the stages visited: resting powder set aside is not counted.
    pub particle_substeps: f64,
    /// Whether resting powder was set aside while nothing came near it (`sim::rest`); `false`
    /// in doses kept before the rule existed.
    #[serde(default)]
    pub rest: bool,
    /// Mass of one grain (mg).
    pub grain_mg: f64,
    /// The balance's reading (mg), the tilt (degrees) and the spatula's height (mm), one triple
    /// per step.
    pub trace: Vec<(f64, f64, f64)>,
}

/// The scene's skill tool: its index and skill.
pub fn skill_tool(scene: &Scene) -> Result<(usize, &SkillSpec)> {
    scene
        .colliders
        .iter()
        .enumerate()
        .find_map(|(i, c)| match &c.control {
            Some(ControlSpec::Skill(sk)) => Some((i, sk)),
            _ => None,
        })
        .with_context(|| {
            format!(
                "{}: no tool with a Skill control; weighing scoops with one",
                scene.path.display()
            )
        })
}

/// The running dose: the simulation, the controller's view of it and what it records.
struct Run<'a> {
    sim: Simulation,
    tool: usize,
    tilt: f64,
    /// The reading (g) after each step.
    readings: Vec<f64>,
    trace: Vec<(f64, f64, f64)>,
    taps: usize,
    rec: Option<&'a mut Recorder>,
    progress: &'a mut dyn FnMut(usize, f64),
}

impl Run<'_> {
    /// One step with the tool's control `u`; records the reading.
    fn step(&mut self, u: [f64; 6]) -> Result<()> {
        self.sim.drive_tool(self.tool, u);
        self.sim.step()?;
        let r = self.sim.balance_reading_g().unwrap_or(0.0);
        self.readings.push(r);
        let y = self
            .sim
            .collider_pose(self.tool)
            .map_or(0.0, |p| p.translation.y);
        self.trace.push((r * 1e3, self.tilt.to_degrees(), y * 1e3));
        if let Some(rec) = self.rec.as_deref_mut() {
            rec.frame(&mut self.sim.world)?;
            rec.scalar(&self.sim.world, "balance/reading_mg", r * 1e3)?;
            rec.scalar(&self.sim.world, "spatula/tilt_deg", self.tilt.to_degrees())?;
        }
        (self.progress)(self.readings.len(), r * 1e3);
        Ok(())
    }

    fn reading(&self) -> f64 {
        self.readings.last().copied().unwrap_or(0.0)
    }

    /// The reading's slope (g/s) over the last `n` steps.
    fn rate(&self, n: usize, dt: f64) -> f64 {
        let k = self.readings.len();
        if k <= n {
            return 0.0;
        }
        (self.readings[k - 1] - self.readings[k - 1 - n]) / (n as f64 * dt)
    }

    /// Moves the tool to `goal` through the air: turns in place, then moves horizontally, then
    /// vertically, at the skill's speeds.
    fn move_to(&mut self, goal: Pose, sk: &SkillSpec, dt: f64) -> Result<()> {
        let now = self
            .sim
            .collider_pose(self.tool)
            .expect("the tool is in the world");
        let turn = quat_to_rotation_vector(goal.rotation * now.rotation.inverse());
        let d = goal.translation - now.translation;
        let w = sk.angular_speed_deg.to_radians();
        let v = sk.linear_speed;
        let moves = [
            (
                DVec3::ZERO,
                turn,
                crate::skills::phase_steps(turn.length(), w, dt),
            ),
            (
                DVec3::new(d.x, 0.0, d.z),
                DVec3::ZERO,
                crate::skills::phase_steps(d.x.hypot(d.z), v, dt),
            ),
            (
                DVec3::new(0.0, d.y, 0.0),
                DVec3::ZERO,
                crate::skills::phase_steps(d.y, v, dt),
            ),
        ];
        for (t, r, n) in moves {
            if t.length() == 0.0 && r.length() == 0.0 {
                continue;
            }
            let (t, r) = (t / n as f64, r / n as f64);
            for _ in 0..n {
                self.step([t.x, t.y, t.z, r.x, r.y, r.z])?;
            }
        }
        Ok(())
    }
}

/// Runs one dose of `target_mg` on `scene` (which must have a balance and a skill tool) with the
/// rule `d`. `progress(step, reading_mg)` is called after every step.
pub fn dose(
    scene: &Scene,
    target_mg: f64,
    d: &Dispense,
    opts: &SimOptions,
    rrd: Option<&std::path::Path>,
    progress: &mut dyn FnMut(usize, f64),
) -> Result<DoseReport> {
    d.validate()?;
    ensure!(
        target_mg.is_finite() && (0.0..=1e6).contains(&target_mg),
        "--target-mg {target_mg}: expected a mass from 0 to 1e6 mg"
    );
    ensure!(
        scene.balance.is_some(),
        "{}: field balance: missing; weighing reads a balance under the boat (see \
         scenes/vial_weighing.ron)",
        scene.path.display()
    );
    let t0 = Instant::now();
    let tool = skill_tool(scene)?;
    let mut sim = Simulation::new(scene, opts)?;
    let mut rec = match rrd {
        Some(p) => Some(Recorder::create(
            p,
            &mut sim.world,
            scene.record.as_ref().map_or(RECORD_EVERY, |r| r.every),
            scene.task.as_ref().map(|t| t.target.clone()),
            scene
                .record
                .as_ref()
                .and_then(|r| r.point_radius)
                .unwrap_or(0.25 * scene.simulation.dx),
        )?),
        None => None,
    };
    let r =
        run_dose(scene, tool, sim, target_mg, d, rec.as_mut(), progress, t0).map(|r| DoseReport {
            rest: opts.rest.is_some(),
            ..r
        });
    match (rec, &r) {
        (Some(rec), Ok(_)) => rec.finish()?,
        (Some(rec), Err(_)) => rec.discard(),
        (None, _) => {}
    }
    r
}

#[allow(clippy::too_many_arguments)]
fn run_dose(
    scene: &Scene,
    (tool, sk): (usize, &SkillSpec),
    sim: Simulation,
    target_mg: f64,
    d: &Dispense,
    rec: Option<&mut Recorder>,
    progress: &mut dyn FnMut(usize, f64),
    t0: Instant,
) -> Result<DoseReport> {
    let dt = scene.simulation.dt;
    let (controls, phases) = sk.controls(dt, Scene::tool_bottom(&scene.colliders[tool]));
    let carry: Vec<[f64; 6]> = controls[..phases[..4].iter().sum::<usize>()].to_vec();
    let mut run = Run {
        sim,
        tool,
        tilt: 0.0,
        readings: Vec::new(),
        trace: Vec::new(),
        taps: 0,
        rec,
        progress,
    };
    let start = run
        .sim
        .collider_pose(tool)
        .expect("the tool is in the world");
    let axis = DVec3::from(sk.pour_axis).normalize();
    let along = DVec3::from(sk.transport_direction).normalize();
    let target = target_mg * 1e-3;
    let w_fast = sk.angular_speed_deg.to_radians() * dt;
    let w_slow = d.tilt_deg_s.to_radians() * dt;
    let rate_n = ((RATE_WINDOW_S / dt).round() as usize).max(1);
    let wait = (d.wait_s / dt).round() as usize;
    // Below this tilt the powder has not yet moved the reading (radians).
    let mut onset: Option<f64> = None;
    let mut scoops = 0;
    // Bounded: a rule that resumes without end still stops (see `MAX_DOSE_S`).
    let max_steps = (MAX_DOSE_S / dt).ceil() as usize;
    'dose: while scoops < d.max_scoops {
        if scoops > 0 {
            let goal = Pose {
                translation: start.translation + along * TOPUP_OFFSETS_MM[scoops] * 1e-3,
                rotation: start.rotation,
            };
            run.move_to(goal, sk, dt)?;
        }
        scoops += 1;
        for &u in &carry {
            run.step(u)?;
        }
        // Tilt and tap on this scoop until the dose is reached or the spatula is empty.
        loop {
            let resume = onset.map_or(d.start_deg.to_radians(), |a| {
                (a - 5f64.to_radians()).max(0.0)
            });
            let before = run.reading();
            let mut stopped = false;
            let mut k = 0usize;
            while run.tilt < d.max_deg.to_radians() {
                if run.readings.len() >= max_steps {
                    break;
                }
                let lead = d.lead_mg * 1e-3 + d.lead_s * run.rate(rate_n, dt).max(0.0);
                if run.reading() + lead >= target {
                    stopped = true;
                    break;
                }
                let w = if run.tilt < resume { w_fast } else { w_slow };
                let w = w.min(d.max_deg.to_radians() - run.tilt);
                let tapping = run.tilt >= resume && d.tap_mm > 0.0;
                let y = match (tapping, k % d.tap_every) {
                    (true, 0) => -d.tap_mm * 1e-3,
                    (true, 1) => d.tap_mm * 1e-3,
                    _ => 0.0,
                };
                if tapping {
                    k += 1;
                    if y < 0.0 {
                        run.taps += 1;
                    }
                }
                run.tilt += w;
                let r = axis * w;
                run.step([0.0, y, 0.0, r.x, r.y, r.z])?;
                if onset.is_none() && run.reading() > before + 2.0 * scene_noise_g(scene) {
                    onset = Some(run.tilt);
                }
            }
            // A tap's drop in progress is lifted back first.
            if d.tap_mm > 0.0 && k % d.tap_every == 1 {
                run.step([0.0, d.tap_mm * 1e-3, 0.0, 0.0, 0.0, 0.0])?;
            }
            // Back upright.
            while run.tilt > 0.0 {
                let w = w_fast.min(run.tilt);
                run.tilt -= w;
                let r = -axis * w;
                run.step([0.0, 0.0, 0.0, r.x, r.y, r.z])?;
            }
            for _ in 0..wait {
                run.step([0.0; 6])?;
            }
            if run.reading() >= target - d.tolerance_mg * 1e-3 || run.readings.len() >= max_steps {
                break 'dose;
            }
            if !stopped {
                // Tilted all the way and still short: the spatula is empty.
                break;
            }
        }
    }
    // Grains still falling land; the dose is what then rests in the boat.
    for _ in 0..((FINAL_SETTLE_S / dt).ceil() as usize).max(1) {
        run.step([0.0; 6])?;
    }
    let delivered = run.sim.balance_load_g().unwrap_or(0.0) * 1e3;
    let steps = run.readings.len();
    let grain_mg = scene.particle_masses().first().copied().unwrap_or(0.0) * 1e6;
    Ok(DoseReport {
        target_mg,
        delivered_mg: delivered,
        error_mg: delivered - target_mg,
        reading_mg: run.reading() * 1e3,
        scoops,
        taps: run.taps,
        sim_s: steps as f64 * dt,
        wall_s: t0.elapsed().as_secs_f64(),
        threads: Some(run.sim.threads()),
        steps,
        particle_substeps: run.sim.particle_substeps(),
        rest: false,
        grain_mg,
        trace: run.trace,
    })
}

/// The balance's noise (g), the threshold below which a change in the reading is not powder.
fn scene_noise_g(scene: &Scene) -> f64 {
    scene
        .balance
        .as_ref()
        .map_or(0.0, |b| (b.noise_mg.max(b.resolution_mg)) * 1e-3)
}
