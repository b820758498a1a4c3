//! Scene metrics: transported particles, mean height and energies.

use crate::components::*;
use crate::math::geometry::CupRegion;
use crate::math::return_map::{hencky, hencky_energy};
use crate::math::svd::{svd3_warm_group, svd3_warm_lanes, LANES};
use bevy_ecs::prelude::*;
use glam::DMat3;

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
    /// Σ V₀·ψ(ε) (J): stored elastic energy of StVK in Hencky strain, ε = ln σ(F).
    pub elastic_energy: f64,
    pub max_speed: f64,
}

/// The task's score in the current state: `(transported, target − transported)`, in the task's
/// unit (particles or grams). The indicator of the seed paper; its absolute value is the dose
/// error.
pub fn task_indicator(world: &mut World, task: &crate::scene::TaskSpec) -> (f64, f64) {
    let m = frame_metrics(world, Some(&task.target));
    let (target, transported) = match task.target_value {
        crate::scene::TargetValue::Particles(n) => (n, m.transported as f64),
        crate::scene::TargetValue::Grams(g) => (g, m.transported_mass * 1e3),
    };
    (transported, target - transported)
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
    let mut q = world.query::<(
        &Body,
        &Position,
        &Velocity,
        &DeformationGradient,
        Option<&Parked>,
    )>();
    for (b, x, v, f, parked) in q.iter(world) {
        // Parked particles (`sim::rest`) count where they rest, with the state they keep.
        let (px, (pv, _, pf)) = parked.map_or((&[][..], (&[][..], &[][..], &[][..])), |p| {
            (p.positions(), p.state())
        });
        let (mu, lambda) = b.lame;
        m.elastic_energy += b.particle_volume
            * (elastic_energy_sum(&f.0, mu, lambda) + elastic_energy_sum(pf, mu, lambda));
        m.particles += x.0.len() + px.len();
        for (x, v) in x.0.iter().zip(&v.0).chain(px.iter().zip(pv)) {
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

/// `Σ_p ψ(ln σ(F_p))` over `fs`, in particle order. The singular values come from the lane SVD
/// four particles at a time (`svd3_warm_group`, bitwise equal to the scalar SVD), so the sum
/// is the same as particle by particle with the scalar SVD, at a fraction of the cost: the
/// energy budget runs this every step of `simulate`.
fn elastic_energy_sum(fs: &[DMat3], mu: f64, lambda: f64) -> f64 {
    let mut sum = 0.0;
    for group in fs.chunks(LANES) {
        let v0 = &[DMat3::IDENTITY; LANES][..group.len()];
        for d in svd3_warm_group(svd3_warm_lanes, group, v0) {
            sum += hencky_energy(hencky(d.s), mu, lambda);
        }
    }
    sum
}

impl FrameMetrics {
    /// Kinetic + gravitational + elastic energy (J).
    pub fn total_energy(&self) -> f64 {
        self.kinetic_energy + self.gravitational_energy + self.elastic_energy
    }
}

/// Largest rise of the total energy allowed before it is flagged, as a fraction of the energy
/// in play (see [`EnergyMonitor`]). Friction, plastic flow and the APIC transfers only take
/// energy out, but symplectic Euler's energy oscillates about its conserved value with a
/// relative amplitude of order ω·Δt_sub: a sand block bouncing elastically between the domain
/// walls (`validate stability`, "powder packed against the domain boundary") swings by 6.4 % of
/// the energy in play without any trend. An instability grows the energy
/// by orders of magnitude within a few steps, so 10 % separates the two.
pub const ENERGY_GAIN_TOL: f64 = 0.1;

/// Watches the total energy of a run for a spurious gain.
///
/// The gain at a frame is the total energy minus its lowest value so far; the energy in play is
/// the largest of kinetic + elastic energy and of the gravitational energy released since the
/// start. A gain above [`ENERGY_GAIN_TOL`] of the energy in play is flagged, unless a tool is
/// driven (a moving tool does work on the powder, so a gain is physical; it is then reported,
/// not flagged).
#[derive(Clone, Debug, Default)]
pub struct EnergyMonitor {
    pub initial: Option<f64>,
    initial_gravitational: f64,
    lowest: f64,
    /// Largest gain seen (J) and the frame it was seen at.
    pub largest_gain: f64,
    pub largest_gain_frame: usize,
    /// Largest energy in play (J).
    pub scale: f64,
    pub last: f64,
    frames: usize,
}

impl EnergyMonitor {
    /// Takes one frame's metrics.
    pub fn observe(&mut self, m: &FrameMetrics) {
        let e = m.total_energy();
        if self.initial.is_none() {
            self.initial = Some(e);
            self.initial_gravitational = m.gravitational_energy;
            self.lowest = e;
        }
        self.lowest = self.lowest.min(e);
        // A non-finite energy is an infinite gain (the simulator stops on one anyway).
        let gain = if e.is_finite() {
            e - self.lowest
        } else {
            f64::INFINITY
        };
        if gain > self.largest_gain {
            self.largest_gain = gain;
            self.largest_gain_frame = self.frames;
        }
        self.scale = self
            .scale
            .max(m.kinetic_energy + m.elastic_energy)
            .max(self.initial_gravitational - m.gravitational_energy);
        self.last = e;
        self.frames += 1;
    }

    /// The largest gain as a fraction of the energy in play (0 if nothing moved).
    pub fn gain_fraction(&self) -> f64 {
        if self.scale > 0.0 {
            self.largest_gain / self.scale
        } else {
            0.0
        }
    }

    /// Whether the largest gain exceeds [`ENERGY_GAIN_TOL`] of the energy in play.
    pub fn spurious_gain(&self) -> bool {
        self.largest_gain.is_infinite() || self.gain_fraction() > ENERGY_GAIN_TOL
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::svd::svd3;
    use glam::DVec3;

    fn frame(ke: f64, pe: f64, el: f64) -> FrameMetrics {
        FrameMetrics {
            kinetic_energy: ke,
            gravitational_energy: pe,
            elastic_energy: el,
            ..Default::default()
        }
    }

    #[test]
    fn a_falling_body_that_loses_energy_is_not_flagged() {
        let mut m = EnergyMonitor::default();
        m.observe(&frame(0.0, 10.0, 0.0));
        m.observe(&frame(4.0, 6.0, 0.0));
        m.observe(&frame(7.0, 2.0, 0.5));
        m.observe(&frame(0.1, 1.0, 0.2));
        assert!(!m.spurious_gain());
        assert_eq!(m.largest_gain, 0.0);
        assert!((m.scale - 9.0).abs() < 1e-12);
    }

    #[test]
    fn a_rise_above_the_lowest_total_is_flagged() {
        let mut m = EnergyMonitor::default();
        m.observe(&frame(0.0, 10.0, 0.0));
        m.observe(&frame(2.0, 5.0, 0.0));
        m.observe(&frame(3.0, 5.0, 0.0));
        assert!((m.largest_gain - 1.0).abs() < 1e-12);
        assert!((m.gain_fraction() - 0.2).abs() < 1e-12);
        assert_eq!(m.largest_gain_frame, 2);
        assert!(m.spurious_gain());
    }

    /// The lane SVD path sums the same values in the same order as the scalar SVD particle by
    /// particle: bitwise equal, for a count that is not a multiple of the lane width, with
    /// stretched, sheared and near-identity deformation gradients.
    #[test]
    fn elastic_energy_sum_is_the_scalar_sum_bitwise() {
        let mut rng = crate::util::SplitMix64(99);
        let mut fs: Vec<DMat3> = (0..11)
            .map(|_| {
                DMat3::IDENTITY
                    + DMat3::from_cols_array(&std::array::from_fn(|_| 0.3 * rng.normal()))
            })
            .collect();
        fs.push(DMat3::IDENTITY);
        fs.push(DMat3::from_diagonal(DVec3::new(
            1.0 + 1e-9,
            1.0,
            1.0 - 1e-9,
        )));
        let (mu, lambda) = (1.3e3, 2.1e3);
        let scalar: f64 = fs
            .iter()
            .map(|f| hencky_energy(hencky(svd3(*f).s), mu, lambda))
            .sum();
        assert_eq!(
            elastic_energy_sum(&fs, mu, lambda).to_bits(),
            scalar.to_bits()
        );
    }

    #[test]
    fn a_nan_energy_is_flagged() {
        let mut m = EnergyMonitor::default();
        m.observe(&frame(0.0, 1.0, 0.0));
        m.observe(&frame(f64::NAN, 1.0, 0.0));
        assert!(m.spurious_gain());
    }
}
