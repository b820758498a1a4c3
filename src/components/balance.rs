//! An analytical balance under a container: what rests in the cup's cavity, and what the
//! display shows of it. The balance is an instrument, not physics: no stage reads it, so it has
//! no adjoint; `crate::systems::balance` updates it once per global step.
//!
//! The display follows the load through a first-order lag (a balance's damped settling),
//! plus seeded Gaussian noise, rounded to the readability:
//!
//! ```text
//! m_f ← m_f + (m − m_f)·(1 − e^(−Δt/τ)),    reading = r·round((m_f + σ·ξ)/r)
//! ```

use crate::math::geometry::CupRegion;
use crate::util::SplitMix64;
use bevy_ecs::prelude::*;

/// One balance (on its own entity; a scene has at most one).
#[derive(Component, Clone, Debug)]
pub struct Balance {
    /// The weighing boat's cavity.
    pub boat: CupRegion,
    /// Readability (g).
    pub resolution_g: f64,
    /// Standard deviation of the reading's noise (g).
    pub noise_g: f64,
    /// Time constant of the settling lag (s).
    pub settle_s: f64,
    /// The mass in the cavity now (g): the truth, which a controller must not read.
    pub load_g: f64,
    /// The settling mechanism's state (g).
    pub settled_g: f64,
    /// What the display shows (g).
    pub reading_g: f64,
    /// The noise's stream.
    pub rng: SplitMix64,
}

impl Balance {
    /// A balance at rest on an empty boat.
    pub fn new(boat: CupRegion, spec: &crate::scene::BalanceSpec) -> Balance {
        Balance {
            boat,
            resolution_g: spec.resolution_mg * 1e-3,
            noise_g: spec.noise_mg * 1e-3,
            settle_s: spec.settle_s,
            load_g: 0.0,
            settled_g: 0.0,
            reading_g: 0.0,
            rng: SplitMix64(spec.seed),
        }
    }

    /// Advances the balance by `dt` seconds under the load `load_g` and draws a new reading.
    pub fn update(&mut self, load_g: f64, dt: f64) {
        self.load_g = load_g;
        self.settled_g = settle(self.settled_g, load_g, dt, self.settle_s);
        let noise = if self.noise_g > 0.0 {
            self.noise_g * self.rng.normal()
        } else {
            0.0
        };
        self.reading_g = display(self.settled_g + noise, self.resolution_g);
    }
}

/// The first-order lag over `dt`: exact for a load held constant over the interval.
#[inline]
pub fn settle(settled: f64, load: f64, dt: f64, tau: f64) -> f64 {
    settled + (load - settled) * (1.0 - (-dt / tau).exp())
}

/// A value rounded to the display's step.
#[inline]
pub fn display(value: f64, resolution: f64) -> f64 {
    (value / resolution).round() * resolution
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_lag_reaches_a_step_load_as_an_exponential() {
        // After one time constant a step has risen by 1 − 1/e, after 4.6 by 99 %, however the
        // interval is cut.
        let mut m = 0.0;
        for _ in 0..50 {
            m = settle(m, 1.0, 0.01, 0.5);
        }
        assert!((m - (1.0 - (-1.0f64).exp())).abs() < 1e-12, "{m}");
        let m = settle(0.0, 1.0, 2.3, 0.5);
        assert!((0.98..0.995).contains(&m), "{m}");
    }

    #[test]
    fn the_display_rounds_to_its_step() {
        assert!((display(0.012_34, 1e-4) - 0.0123).abs() < 1e-15);
        assert!((display(0.012_36, 1e-4) - 0.0124).abs() < 1e-15);
        assert_eq!(display(-0.000_04, 1e-4), -0.0);
    }
}
