//! Scene metrics: transported particles, mean height and energies.

use crate::adjoint::loss::CupRegion;
use crate::components::*;
use bevy_ecs::prelude::*;

/// Summary numbers of one frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FrameMetrics {
    pub particles: usize,
    /// Particles inside the task's target cup (0 without a task).
    pub transported: usize,
    /// Mass inside the target cup (kg).
    pub transported_mass: f64,
    /// Mean particle height (m).
    pub mean_height: f64,
    /// Σ ½ m v² (J).
    pub kinetic_energy: f64,
    /// Σ −m g·x (J), relative to the origin.
    pub gravitational_energy: f64,
    pub max_speed: f64,
}

/// Computes the metrics of the current state; `target` names the target cup, if any.
pub fn frame_metrics(world: &mut World, target: Option<&str>) -> FrameMetrics {
    let g = world.resource::<SimParams>().gravity;
    let cup = target.and_then(|t| {
        let mut q = world.query::<(&Collider, &ColliderPose)>();
        q.iter(world)
            .find(|(c, _)| c.name == t)
            .and_then(|(c, p)| CupRegion::of(&c.shape, p.pose))
    });
    let mut m = FrameMetrics::default();
    let mut sum_y = 0.0;
    let mut q = world.query::<(&Body, &Position, &Velocity)>();
    for (b, x, v) in q.iter(world) {
        m.particles += x.0.len();
        for (x, v) in x.0.iter().zip(&v.0) {
            sum_y += x.y;
            let s2 = v.length_squared();
            m.kinetic_energy += 0.5 * b.particle_mass * s2;
            m.gravitational_energy -= b.particle_mass * g.dot(*x);
            m.max_speed = m.max_speed.max(s2.sqrt());
            if let Some(cup) = &cup {
                if cup.inside(*x) {
                    m.transported += 1;
                    m.transported_mass += b.particle_mass;
                }
            }
        }
    }
    m.mean_height = if m.particles > 0 {
        sum_y / m.particles as f64
    } else {
        0.0
    };
    m
}
