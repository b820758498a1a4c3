//! The background grid: a box of nodes at `origin + (i, j, k)·dx`.

use bevy_ecs::prelude::*;
use glam::DVec3;
use serde::{Deserialize, Serialize};

/// How a collider or wall acts on the velocity relative to it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
pub enum ContactMode {
    /// The relative velocity is set to zero.
    Sticky,
    /// The normal relative velocity is removed in both directions; Coulomb friction applies.
    Slip,
    /// Only an approaching normal velocity is removed; Coulomb friction applies.
    #[default]
    Separate,
}

/// Grid nodes, stored with x slowest: `index = (i·ny + j)·nz + k`. The x-major layout makes a
/// slab of x-planes one contiguous range, which the race-free P2G scatter relies on.
#[derive(Resource, Clone, Debug)]
pub struct Grid {
    pub origin: DVec3,
    pub dx: f64,
    pub n: [usize; 3],
    /// Node mass (kg).
    pub mass: Vec<f64>,
    /// Node momentum (kg·m/s), written by P2G.
    pub momentum: Vec<DVec3>,
    /// Node velocity (m/s), `momentum/mass` for nodes heavier than the empty-node threshold.
    pub velocity: Vec<DVec3>,
}

/// Grid velocity entering the collider response at the nodes it acts on (the non-empty ones),
/// saved by the forward collider stage when the resource exists (the backward driver's
/// recomputation inserts it; a plain forward run does not), for the adjoint to replay the
/// responses from. Other entries are stale and never read.
#[derive(Resource, Clone, Debug, Default)]
pub struct ColliderInputVelocity(pub Vec<DVec3>);

/// Grid velocity entering the domain-wall response at the nodes it acts on (the non-empty
/// wall-layer ones), saved like [`ColliderInputVelocity`].
#[derive(Resource, Clone, Debug, Default)]
pub struct WallInputVelocity(pub Vec<DVec3>);

impl Grid {
    pub fn new(origin: DVec3, dx: f64, n: [usize; 3]) -> Self {
        let len = n[0] * n[1] * n[2];
        Self {
            origin,
            dx,
            n,
            mass: vec![0.0; len],
            momentum: vec![DVec3::ZERO; len],
            velocity: vec![DVec3::ZERO; len],
        }
    }

    #[inline(always)]
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        (i * self.n[1] + j) * self.n[2] + k
    }

    /// Node coordinates of a flat index.
    #[inline(always)]
    pub fn coords(&self, idx: usize) -> [usize; 3] {
        let k = idx % self.n[2];
        let j = (idx / self.n[2]) % self.n[1];
        let i = idx / (self.n[1] * self.n[2]);
        [i, j, k]
    }

    #[inline(always)]
    pub fn node_position(&self, idx: usize) -> DVec3 {
        let [i, j, k] = self.coords(idx);
        self.origin + DVec3::new(i as f64, j as f64, k as f64) * self.dx
    }

    /// Nodes in one x-plane.
    #[inline(always)]
    pub fn plane_len(&self) -> usize {
        self.n[1] * self.n[2]
    }

    /// Upper corner of the node box.
    pub fn extent_max(&self) -> DVec3 {
        self.origin
            + DVec3::new(
                (self.n[0] - 1) as f64,
                (self.n[1] - 1) as f64,
                (self.n[2] - 1) as f64,
            ) * self.dx
    }
}

/// Domain walls: the outer `cells` layers of nodes on every face act as walls.
#[derive(Resource, Clone, Copy, Debug)]
pub struct DomainWalls {
    pub cells: usize,
    pub mode: ContactMode,
    pub friction: f64,
}
