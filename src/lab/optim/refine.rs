//! Trajectory refinement beyond five numbers: residuals added to a skill's per-step controls.
//!
//! The skill maps Θ to a spoon trajectory of straight phases. A residual bends the transport and
//! the pour: on the window of steps from the start of the transport to the end of the pour,
//! each of the six control channels (translation and rotation vector per step) gets
//! `scale_c·Σ_j w_j·φ_j(step)`, with `φ_j` the piecewise-linear hat functions on `knots` evenly
//! spaced knots over the window (a linear spline; one knot is a constant offset), and
//! `w ∈ [−1, 1]^(6·knots)`. `scale` is half of the skill's largest per-step displacement (its
//! linear and angular speed times the step), so that `w = ±1` slows, reverses or doubles a phase
//! but never more. The map is linear in `w`, and its adjoint ([`Residual::apply_adj`]) turns the
//! backward pass's `∂L/∂u` per step into `∂L/∂w`.

/// A residual on a window of a skill's steps.
#[derive(Clone, Debug, PartialEq)]
pub struct Residual {
    /// Knots per channel; the dimension is `6·knots`.
    pub knots: usize,
    /// First step of the window.
    pub start: usize,
    /// Steps in the window (at least 1).
    pub len: usize,
    /// Scale per channel: three translations (m per step), three rotations (rad per step).
    pub scale: [f64; 6],
}

impl Residual {
    /// The parameters' count.
    pub fn dim(&self) -> usize {
        6 * self.knots
    }

    /// The hat function `φ_j` at the window's `i`-th step (0-based).
    pub fn basis(&self, i: usize, j: usize) -> f64 {
        if self.knots <= 1 {
            return 1.0;
        }
        // Knot j at position j/(knots − 1) of the window, the step at i/(len − 1).
        let x = if self.len <= 1 {
            0.0
        } else {
            i as f64 / (self.len - 1) as f64
        };
        let h = 1.0 / (self.knots - 1) as f64;
        (1.0 - (x - j as f64 * h).abs() / h).max(0.0)
    }

    /// Adds the residual of `w` (channel-major: `w[c·knots + j]`) to `controls`.
    pub fn apply(&self, controls: &mut [[f64; 6]], w: &[f64]) {
        for i in 0..self.len {
            let Some(u) = controls.get_mut(self.start + i) else {
                break;
            };
            for (c, uc) in u.iter_mut().enumerate() {
                *uc += self.scale[c]
                    * (0..self.knots)
                        .map(|j| w[c * self.knots + j] * self.basis(i, j))
                        .sum::<f64>();
            }
        }
    }

    /// `∂L/∂w` from `∂L/∂u` per step: the transpose of [`Residual::apply`].
    pub fn apply_adj(&self, g_controls: &[[f64; 6]]) -> Vec<f64> {
        let mut g = vec![0.0; self.dim()];
        for i in 0..self.len {
            let Some(gu) = g_controls.get(self.start + i) else {
                break;
            };
            for c in 0..6 {
                for j in 0..self.knots {
                    g[c * self.knots + j] += self.scale[c] * self.basis(i, j) * gu[c];
                }
            }
        }
        g
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::SplitMix64;

    fn residual(knots: usize) -> Residual {
        Residual {
            knots,
            start: 3,
            len: 17,
            scale: [1e-3, 2e-3, 5e-4, 0.01, 0.02, 0.03],
        }
    }

    #[test]
    fn the_hats_sum_to_one_and_interpolate_the_knots() {
        for knots in [1, 2, 5, 16] {
            let r = residual(knots);
            for i in 0..r.len {
                let s: f64 = (0..knots).map(|j| r.basis(i, j)).sum();
                assert!((s - 1.0).abs() < 1e-12, "knots {knots} step {i}: {s}");
            }
        }
        let r = residual(5);
        // Knot 2 sits at the window's middle step (8 of 0..=16).
        assert!((r.basis(8, 2) - 1.0).abs() < 1e-15 && r.basis(8, 1).abs() < 1e-15);
    }

    #[test]
    fn the_adjoint_is_the_transpose() {
        // <apply(w), g> = <w, apply_adj(g)> for random w and g, exactly up to round-off.
        let mut rng = SplitMix64(5);
        for knots in [1, 5, 16] {
            let r = residual(knots);
            let w: Vec<f64> = (0..r.dim()).map(|_| rng.uniform_in(-1.0, 1.0)).collect();
            let g: Vec<[f64; 6]> = (0..25)
                .map(|_| std::array::from_fn(|_| rng.normal()))
                .collect();
            let mut u = vec![[0.0; 6]; 25];
            r.apply(&mut u, &w);
            let lhs: f64 = u
                .iter()
                .zip(&g)
                .map(|(a, b)| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>())
                .sum();
            let rhs: f64 = w.iter().zip(r.apply_adj(&g)).map(|(a, b)| a * b).sum();
            assert!(
                (lhs - rhs).abs() <= 1e-12 * lhs.abs().max(1e-12),
                "{lhs} {rhs}"
            );
            // Steps outside the window are untouched.
            assert!(u[..3].iter().chain(&u[20..]).all(|s| s == &[0.0; 6]));
        }
    }
}
