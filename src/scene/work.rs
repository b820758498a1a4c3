//! The work a run will take, estimated before it starts, and the limit past which `simulate`
//! asks for `--force`.

use super::{Scene, StabilityReport};

/// The forward pass's rate on the reference machine, in particle-substeps per second: 3.0 M on
/// its 2 threads (docs/results/performance.md). The estimate scales by nothing else, so on
/// another machine it is a unit of work more than a forecast.
pub const REFERENCE_RATE: f64 = 3.0e6;

/// The most particle-substeps a run starts without `--force`: about 55 minutes at
/// [`REFERENCE_RATE`]. The shipped scenes' horizons need at most a few hundred million.
pub const WORK_LIMIT: f64 = 1e10;

/// A grid node's work per substep, as a fraction of a particle's: the grid is reset, updated
/// and collided with the tools every substep whatever the particles. Measured on
/// `policy_dosing`'s grid of 28,917 nodes, 3,960 substeps each: with no particles (a spoon
/// 15 m thick had removed them, a case the reliability study found) a substep took 0.3 ms,
/// against 3.4 ms with the scene's 3,773 particles, so a node costs about 1/80 of a particle;
/// 1/64 errs on the long side.
pub const NODE_WEIGHT: f64 = 1.0 / 64.0;

/// A run's size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WorkEstimate {
    pub particles: usize,
    /// Grid nodes (lattice points).
    pub nodes: usize,
    pub substeps: usize,
    pub steps: usize,
}

impl WorkEstimate {
    /// The work in particle-substeps, the grid's nodes counted at [`NODE_WEIGHT`] of a
    /// particle each.
    pub fn particle_substeps(&self) -> f64 {
        (self.particles as f64 + NODE_WEIGHT * self.nodes as f64)
            * self.substeps as f64
            * self.steps as f64
    }

    /// The work of `rollouts` runs of this one (a fraction counts: a backward pass is a
    /// fraction of a forward one's work), its steps rounded up.
    pub fn times(&self, rollouts: f64) -> WorkEstimate {
        WorkEstimate {
            steps: (self.steps as f64 * rollouts).ceil() as usize,
            ..*self
        }
    }

    /// Seconds at [`REFERENCE_RATE`].
    pub fn seconds(&self) -> f64 {
        self.particle_substeps() / REFERENCE_RATE
    }

    pub fn over_limit(&self) -> bool {
        self.particle_substeps() > WORK_LIMIT
    }

    /// The time at [`REFERENCE_RATE`], in the unit that suits it: `40 s`, `12 min`, `3.5 h`.
    pub fn duration(&self) -> String {
        let s = self.seconds();
        if s < 120.0 {
            format!("{s:.0} s")
        } else if s < 7200.0 {
            format!("{:.0} min", s / 60.0)
        } else if s < 2.0 * 86400.0 {
            format!("{:.1} h", s / 3600.0)
        } else {
            format!("{:.0} days", s / 86400.0)
        }
    }

    /// `N particles × S substeps × T steps = W particle-substeps, about D at 3 M/s`.
    pub fn describe(&self) -> String {
        let time = self.duration();
        format!(
            "{} particles × {} substeps × {} steps, with {} grid nodes at 1/{:.0} of a particle each = {:.2e} particle-substeps, about {time} at the reference machine's {:.0} M particle-substeps/s",
            self.particles,
            self.substeps,
            self.steps,
            self.nodes,
            1.0 / NODE_WEIGHT,
            self.particle_substeps(),
            REFERENCE_RATE / 1e6
        )
    }

    /// What drives the work, and the scene field to point at when the file holds it: the
    /// substeps (what raised them, for `Auto`), the steps (the file's, or the horizon the tool's
    /// controls take), the grid, or the particle count.
    pub fn driver(&self, scene: &Scene, stability: &StabilityReport) -> (Option<String>, String) {
        if self.substeps >= 1000 {
            if !stability.raised() {
                return (
                    Some("simulation.substeps".into()),
                    format!("`simulation.substeps` = {} asks for them", self.substeps),
                );
            }
            if stability.wave_speed >= stability.max_speed {
                let stiffest = scene
                    .materials
                    .iter()
                    .filter(|(name, _)| scene.bodies.iter().any(|b| &b.material == *name))
                    .map(|(name, m)| {
                        let (mu, lambda) = m.lame();
                        (name, ((lambda + 2.0 * mu) / m.density()).sqrt())
                    })
                    .max_by(|a, b| a.1.total_cmp(&b.1));
                if let Some((name, c)) = stiffest {
                    return (Some(format!("materials.{name}.youngs_modulus")), format!(
                        "the stability guard raised the substeps from {} for material '{name}''s elastic wave speed of {c:.3e} m/s: lower `materials.{name}.youngs_modulus` or move `poisson_ratio` away from 0.5",
                        stability.substeps_requested
                    ));
                }
            }
            return (None, format!(
                "the stability guard raised the substeps from {} for a speed of {:.3e} m/s: slow the fastest tool or body",
                stability.substeps_requested, stability.max_speed
            ));
        }
        if self.steps as f64 >= 1e5 {
            return match scene.simulation.steps {
                Some(n) if n == self.steps => (
                    Some("simulation.steps".into()),
                    format!("`simulation.steps` = {}", self.steps),
                ),
                Some(_) => (None, format!("--steps {}", self.steps)),
                None => (
                    None,
                    format!(
                        "the horizon of {} steps that the tool's controls take (its speeds and pauses): set `simulation.steps` to run fewer",
                        self.steps
                    ),
                ),
            };
        }
        if NODE_WEIGHT * self.nodes as f64 > self.particles as f64 {
            return (
                Some("simulation.cells".into()),
                format!(
                    "the grid's {} nodes, more work than its {} particles: lower `simulation.cells`",
                    self.nodes, self.particles
                ),
            );
        }
        (
            None,
            "the particle count: lower `particles_per_cell` or shrink the fills".into(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_estimate_multiplies_and_reads_in_human_units() {
        let w = WorkEstimate {
            particles: 1000,
            nodes: 64_000,
            substeps: 30,
            steps: 100,
        };
        assert_eq!(w.particle_substeps(), 6.0e6);
        assert!(w.describe().contains("about 2 s"), "{}", w.describe());
        let w = WorkEstimate { nodes: 0, ..w };
        assert_eq!(w.particle_substeps(), 3.0e6);
        assert_eq!(w.times(2.5).steps, 250);
        assert_eq!(w.times(0.001).steps, 1);
        assert!(w.describe().contains("about 1 s"), "{}", w.describe());
        assert!(!w.over_limit());
        let big = WorkEstimate {
            particles: 54_872,
            nodes: 0,
            substeps: 984_732,
            steps: 20,
        };
        assert!(
            big.over_limit() && big.describe().contains("days"),
            "{}",
            big.describe()
        );
    }
}
