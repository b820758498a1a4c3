//! The parked particles of a body: the resting powder `crate::sim::rest` sets aside, kept
//! here with the columns they left so that the instruments, the recordings and the state
//! snapshots still see them.

use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3};

/// The grid's cells, as the rest rule sees them: node `i` at `origin + i·dx`, cell `i` the cube
/// from node `i` to node `i + 1` (clamped into the grid).
#[derive(Clone, Copy, Debug, Default)]
pub struct Cells {
    pub origin: DVec3,
    pub dx: f64,
    pub n: [usize; 3],
}

impl Cells {
    pub fn of(grid: &super::Grid) -> Self {
        Cells {
            origin: grid.origin,
            dx: grid.dx,
            n: grid.n,
        }
    }

    /// How many cells the grid has.
    pub fn count(&self) -> usize {
        self.n[0] * self.n[1] * self.n[2]
    }

    /// The cell of `x`, clamped into the grid.
    pub fn of_point(&self, x: DVec3) -> [i64; 3] {
        let g = (x - self.origin) / self.dx;
        let c = |v: f64, n: usize| (v.floor() as i64).clamp(0, n as i64 - 1);
        [c(g.x, self.n[0]), c(g.y, self.n[1]), c(g.z, self.n[2])]
    }

    pub fn flat(&self, [i, j, k]: [i64; 3]) -> usize {
        (i as usize * self.n[1] + j as usize) * self.n[2] + k as usize
    }

    /// The centre of cell `c`.
    pub fn centre(&self, c: [i64; 3]) -> DVec3 {
        self.origin + (DVec3::new(c[0] as f64, c[1] as f64, c[2] as f64) + 0.5) * self.dx
    }

    /// Calls `f` on every cell within `r` of `c` (L∞) inside the grid.
    pub fn around(&self, c: [i64; 3], r: i64, mut f: impl FnMut([i64; 3])) {
        for di in -r..=r {
            for dj in -r..=r {
                for dk in -r..=r {
                    let d = [c[0] + di, c[1] + dj, c[2] + dk];
                    if (0..3).all(|a| d[a] >= 0 && d[a] < self.n[a] as i64) {
                        f(d);
                    }
                }
            }
        }
    }
}

/// A body's parked particles and the still counts of its awake ones.
#[derive(Component, Clone, Debug, Default)]
pub struct Parked {
    /// In the body's full order, `true` where the particle is parked; empty while none is.
    pub(crate) mask: Vec<bool>,
    pub(crate) x: Vec<DVec3>,
    pub(crate) v: Vec<DVec3>,
    pub(crate) c: Vec<DMat3>,
    pub(crate) f: Vec<DMat3>,
    pub(crate) ft: Vec<DMat3>,
    pub(crate) u: Vec<DMat3>,
    pub(crate) s: Vec<DVec3>,
    pub(crate) sv: Vec<DMat3>,
    pub(crate) a: Vec<DMat3>,
    pub(crate) q: Vec<f64>,
    /// The cells the parked particles occupy, and per grid cell whether it lies within
    /// `crate::sim::rest::WAKE_CELLS` (rounded up, L∞) of one of them.
    pub(crate) cells: Vec<[i64; 3]>,
    pub(crate) near: Vec<bool>,
    pub(crate) grid: Cells,
    /// Per awake particle, the steps it has been still for.
    pub(crate) still: Vec<u32>,
}

impl Parked {
    /// The parked positions.
    pub fn positions(&self) -> &[DVec3] {
        &self.x
    }

    /// How many particles are parked.
    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// `awake` and the parked `parked` in the body's full order.
    pub fn merged<T: Copy>(&self, awake: &[T], parked: &[T]) -> Vec<T> {
        let mut out = awake.to_vec();
        if !self.mask.is_empty() {
            merge(&mut out, &mut parked.to_vec(), &self.mask);
        }
        out
    }

    /// The parked velocities, `C` and `F` (for `crate::sim::Simulation::body_states`).
    pub fn state(&self) -> (&[DVec3], &[DMat3], &[DMat3]) {
        (&self.v, &self.c, &self.f)
    }
}

/// Keeps the entries of `col` where `mask` is false and returns the others, both in order.
pub(crate) fn split<T: Copy>(col: &mut Vec<T>, mask: &[bool]) -> Vec<T> {
    let mut parked = Vec::new();
    let mut k = 0;
    col.retain(|e| {
        let m = mask[k];
        k += 1;
        if m {
            parked.push(*e);
        }
        !m
    });
    parked
}

/// Puts `parked` back into `col` at the places `mask` marks.
pub(crate) fn merge<T: Copy>(col: &mut Vec<T>, parked: &mut Vec<T>, mask: &[bool]) {
    let awake = std::mem::take(col);
    let (mut a, mut p) = (awake.into_iter(), parked.drain(..));
    *col = mask
        .iter()
        .map(|&m| if m { p.next() } else { a.next() }.expect("the mask fits the columns"))
        .collect();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_then_merge_restores_the_order() {
        let col: Vec<u32> = (0..20).collect();
        let mask: Vec<bool> = (0..20).map(|i| i % 3 == 1 || i > 16).collect();
        let mut awake = col.clone();
        let mut parked = split(&mut awake, &mask);
        assert_eq!(parked, vec![1, 4, 7, 10, 13, 16, 17, 18, 19]);
        assert!(awake.iter().all(|i| !mask[*i as usize]));
        merge(&mut awake, &mut parked, &mask);
        assert_eq!(awake, col);
        assert!(parked.is_empty());
    }
}
