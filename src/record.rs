//! Headless Rerun recording (docs/design.md §7).
//!
//! Entities:
//! - `world/powder/<body>`: `Points3D` coloured by speed;
//! - `world/tools/<name>`, `world/containers/<name>`: a static `Mesh3D` plus a `Transform3D`
//!   per recorded frame;
//! - `metrics/transported_particles`, `metrics/mean_height`, `metrics/kinetic_energy`,
//!   `metrics/gravitational_energy`, `metrics/elastic_energy`, `metrics/total_energy`: `Scalars`;
//! - whole curves such as an optimisation's loss per epoch ([`Recorder::series`]).
//!
//! Timelines: `step` (sequence) and `sim_time` (duration). The file is written to
//! `<out>.partial` and renamed when the recording is finished, so a reader never sees a
//! half-written `.rrd` under the final name; an interrupted run leaves the `.partial` stream,
//! which Rerun still opens.

use crate::components::*;

use crate::metrics::{frame_metrics, FrameMetrics};
use crate::util::partial_path;
use bevy_ecs::prelude::*;
use rerun::{Mesh3D, Points3D, RecordingStream, Scalars, Transform3D};
use std::path::{Path, PathBuf};

/// An open recording.
pub struct Recorder {
    rec: RecordingStream,
    path: PathBuf,
    every: usize,
    target: Option<String>,
    point_radius: f32,
    /// Added to the world's step on the timelines: a sequence of simulations (a plan's scoops)
    /// recorded one after another.
    step_offset: usize,
}

fn entity_of(c: &Collider) -> String {
    match c.kind {
        ColliderKind::Tool => format!("world/tools/{}", c.name),
        ColliderKind::Container => format!("world/containers/{}", c.name),
    }
}

/// Speed colour map: dark blue at rest through cyan and yellow to red at `v_ref`.
pub fn speed_colour(speed: f64, v_ref: f64) -> [u8; 4] {
    let t = (speed / v_ref).clamp(0.0, 1.0) as f32;
    let stops = [
        [40.0, 60.0, 140.0],
        [60.0, 190.0, 210.0],
        [240.0, 220.0, 80.0],
        [220.0, 50.0, 40.0],
    ];
    let x = t * 3.0;
    let i = (x.floor() as usize).min(2);
    let f = x - i as f32;
    let c: [f32; 3] = std::array::from_fn(|k| stops[i][k] * (1.0 - f) + stops[i + 1][k] * f);
    [c[0] as u8, c[1] as u8, c[2] as u8, 255]
}

impl Recorder {
    /// Opens `path` for recording a simulation of `scene` with the scene's recording options
    /// (`record`: every 1 step and a point radius of half the particle spacing at 8 particles
    /// per cell, 0.25·dx, unless it says otherwise), its task's target cup highlighted.
    pub fn for_scene(
        path: &Path,
        world: &mut World,
        scene: &crate::scene::Scene,
    ) -> anyhow::Result<Recorder> {
        let spec = scene.record.as_ref();
        Recorder::create(
            path,
            world,
            spec.map_or(1, |r| r.every),
            scene.task.as_ref().map(|t| t.target.clone()),
            spec.and_then(|r| r.point_radius)
                .unwrap_or(0.25 * scene.simulation.dx),
        )
    }

    /// Opens `path` for recording and logs the static collider meshes.
    pub fn create(
        path: &Path,
        world: &mut World,
        every: usize,
        target: Option<String>,
        point_radius: f64,
    ) -> anyhow::Result<Recorder> {
        let rec = rerun::RecordingStreamBuilder::new("powderlab").save(partial_path(path))?;
        let mut q = world.query::<&Collider>();
        let mut cs: Vec<_> = q.iter(world).cloned().collect();
        cs.sort_by_key(|c| c.index);
        for c in &cs {
            let m = c.shape.mesh();
            let colour = match c.kind {
                ColliderKind::Tool => [200, 200, 210, 255],
                ColliderKind::Container => [150, 170, 200, 140],
            };
            rec.log_static(
                entity_of(c),
                &Mesh3D::new(m.vertices)
                    .with_triangle_indices(m.triangles)
                    .with_albedo_factor(rerun::Rgba32::from_unmultiplied_rgba(
                        colour[0], colour[1], colour[2], colour[3],
                    )),
            )?;
        }
        Ok(Recorder {
            rec,
            path: path.to_path_buf(),
            every: every.max(1),
            target,
            point_radius: point_radius as f32,
            step_offset: 0,
        })
    }

    /// Records the current state if the step is a recorded one.
    pub fn frame(&mut self, world: &mut World) -> anyhow::Result<()> {
        if !self.records(world) {
            return Ok(());
        }
        let m = frame_metrics(world, self.target.as_deref());
        self.frame_with(world, &m)
    }

    /// Records the next simulation's step `k` at step `k + offset`.
    pub fn set_step_offset(&mut self, offset: usize) {
        self.step_offset = offset;
    }

    /// The file the recording completes to.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Whether the current step is a recorded one.
    pub fn records(&self, world: &World) -> bool {
        world.resource::<Clock>().step.is_multiple_of(self.every)
    }

    /// [`Recorder::frame`] with the frame's metrics already computed by the caller (with the
    /// scene's task target, as [`Recorder::for_scene`] takes it), so that a driver that also
    /// needs them every step computes them once.
    pub fn frame_with(&mut self, world: &mut World, m: &FrameMetrics) -> anyhow::Result<()> {
        if !self.records(world) {
            return Ok(());
        }
        let step = world.resource::<Clock>().step + self.step_offset;
        let dt = world.resource::<SimParams>().dt;
        self.rec.set_time_sequence("step", step as i64);
        self.rec.set_duration_secs("sim_time", step as f64 * dt);
        let mut q = world.query::<(&Body, &Position, &Velocity, Option<&Parked>)>();
        let mut bodies: Vec<_> = q.iter(world).collect();
        bodies.sort_by_key(|b| b.0.index);
        for (b, x, v, parked) in bodies {
            // Parked particles (`sim::rest`) rest where they are, at zero speed.
            let parked = parked.map_or(&[][..], |p| p.positions());
            let pts: Vec<[f32; 3]> =
                x.0.iter()
                    .chain(parked)
                    .map(|p| [p.x as f32, p.y as f32, p.z as f32])
                    .collect();
            let at_rest = std::iter::repeat_n(glam::DVec3::ZERO, parked.len());
            let cols: Vec<rerun::Color> =
                v.0.iter()
                    .copied()
                    .chain(at_rest)
                    .map(|v| {
                        let c = speed_colour(v.length(), 0.5);
                        rerun::Color::from_unmultiplied_rgba(c[0], c[1], c[2], c[3])
                    })
                    .collect();
            self.rec.log(
                format!("world/powder/{}", b.name),
                &Points3D::new(pts)
                    .with_colors(cols)
                    .with_radii([self.point_radius]),
            )?;
        }
        let mut q = world.query::<(&Collider, &ColliderPose)>();
        for (c, p) in q.iter(world) {
            let t = p.pose.translation;
            let r = p.pose.rotation;
            self.rec.log(
                entity_of(c),
                &Transform3D::from_translation_rotation(
                    [t.x as f32, t.y as f32, t.z as f32],
                    rerun::Quaternion::from_xyzw([r.x as f32, r.y as f32, r.z as f32, r.w as f32]),
                ),
            )?;
        }
        self.rec.log(
            "metrics/transported_particles",
            &Scalars::single(m.transported as f64),
        )?;
        self.rec
            .log("metrics/mean_height", &Scalars::single(m.mean_height))?;
        self.rec
            .log("metrics/kinetic_energy", &Scalars::single(m.kinetic_energy))?;
        self.rec.log(
            "metrics/gravitational_energy",
            &Scalars::single(m.gravitational_energy),
        )?;
        self.rec
            .log("metrics/elastic_energy", &Scalars::single(m.elastic_energy))?;
        self.rec
            .log("metrics/total_energy", &Scalars::single(m.total_energy()))?;
        Ok(())
    }

    /// Logs one value of a quantity that changes with the simulation (an instrument's reading)
    /// as `Scalars` under `entity`, at the world's current step, on every step whether or not
    /// the step's particles are recorded.
    pub fn scalar(&mut self, world: &World, entity: &str, value: f64) -> anyhow::Result<()> {
        let step = world.resource::<Clock>().step + self.step_offset;
        let dt = world.resource::<SimParams>().dt;
        self.rec.set_time_sequence("step", step as i64);
        self.rec.set_duration_secs("sim_time", step as f64 * dt);
        self.rec.log(entity, &Scalars::single(value))?;
        Ok(())
    }

    /// Logs a whole curve at once on the sequence timeline `timeline` (1-based), as `Scalars`
    /// under `metrics/<name>`.
    pub fn series(
        &mut self,
        name: &str,
        timeline: &'static str,
        values: impl Iterator<Item = f64>,
    ) -> anyhow::Result<()> {
        let values: Vec<f64> = values.collect();
        let times = rerun::TimeColumn::new_sequence(timeline, 1..=values.len() as i64);
        self.rec.send_columns(
            format!("metrics/{name}"),
            [times],
            Scalars::update_fields()
                .with_scalars(values)
                .columns_of_unit_batches()?,
        )?;
        Ok(())
    }

    /// Logs points that do not change (an observation to compare the run with) under `entity`,
    /// in one colour.
    pub fn static_points(
        &mut self,
        entity: &str,
        points: &[glam::DVec3],
        colour: [u8; 4],
    ) -> anyhow::Result<()> {
        let pts: Vec<[f32; 3]> = points
            .iter()
            .map(|p| [p.x as f32, p.y as f32, p.z as f32])
            .collect();
        self.rec.log_static(
            entity,
            &Points3D::new(pts)
                .with_colors([rerun::Color::from_unmultiplied_rgba(
                    colour[0], colour[1], colour[2], colour[3],
                )])
                .with_radii([self.point_radius]),
        )?;
        Ok(())
    }

    /// Flushes the recording and leaves it under its `.partial` name (a run that failed, with
    /// `--keep-partial`); returns that path.
    pub fn keep_partial(self) -> anyhow::Result<PathBuf> {
        self.rec.flush_blocking()?;
        drop(self.rec);
        Ok(partial_path(&self.path))
    }

    /// Drops the recording of a run that failed and removes its `.partial` file.
    pub fn discard(self) {
        let _ = self.rec.flush_blocking();
        drop(self.rec);
        let _ = std::fs::remove_file(partial_path(&self.path));
    }

    /// Flushes and moves the recording to its final name.
    pub fn finish(self) -> anyhow::Result<()> {
        self.rec.flush_blocking()?;
        drop(self.rec);
        std::fs::rename(partial_path(&self.path), &self.path)?;
        Ok(())
    }
}
