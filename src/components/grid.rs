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

impl ContactMode {
    /// Every mode, in declaration order.
    pub const ALL: [ContactMode; 3] = [
        ContactMode::Sticky,
        ContactMode::Slip,
        ContactMode::Separate,
    ];
}

/// What P2G sums at a grid node: momentum (kg·m/s) and mass (kg), side by side and aligned to
/// 32 bytes, so that a node's four numbers are one load and one store, one AVX2 register, in the
/// scatter and in the gathers that read them (`crate::math::simd`).
#[repr(C, align(32))]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Node {
    pub momentum: DVec3,
    pub mass: f64,
}

impl Node {
    pub const ZERO: Self = Self {
        momentum: DVec3::ZERO,
        mass: 0.0,
    };
}

/// Grid nodes, stored with x slowest: `index = (i·ny + j)·nz + k`. The x-major layout makes a
/// slab of x-planes one contiguous range, which the race-free P2G scatter relies on.
#[derive(Resource, Clone, Debug)]
pub struct Grid {
    pub origin: DVec3,
    pub dx: f64,
    pub n: [usize; 3],
    /// Node mass and momentum, the P2G sums.
    pub nodes: Vec<Node>,
    /// Node velocity (m/s), `momentum/mass` for nodes heavier than the empty-node threshold.
    pub velocity: Vec<DVec3>,
    /// Whether P2G tracks the part of the grid that particles reach ([`ActiveRows`]), so that
    /// the stages that sweep nodes sweep only that part (the active-block grid). `false` keeps
    /// every sweep dense (the reference the active grid is tested and measured against).
    pub sparse: bool,
    /// The nodes that may be non-zero: `Some(rows)` guarantees that every node outside
    /// `rows`' spans has zero mass, momentum and velocity; `None` promises nothing, and the
    /// sweeps cover every node. Travels with the node arrays (the backward pass's records swap
    /// the three arrays and this together).
    pub active: Option<ActiveRows>,
}

/// The active part of the grid, by node rows (a row is the `n[2]` nodes of one `(i, j)`, one
/// contiguous range of the x-major layout): per row, the span of `k` that some particle's
/// stencil reaches this substep. A stencil spans 3 nodes per axis from its base, so a row
/// `(i, j)` is reached by the particles whose base row is `(i − a, j − b)`, `a, b ∈ {0, 1, 2}`,
/// and its span is the hull of those particles' `[base k, base k + 3)`. Sweeping a span instead
/// of a row costs `O(rows)` per sweep on top of the active nodes: sub-linear in the grid's
/// empty nodes, where the dense sweep is linear.
#[derive(Clone, Debug, Default)]
pub struct ActiveRows {
    /// Per base row `i·ny + j`: the lowest and highest base `k` of the particles based there,
    /// `[u32::MAX, 0]` where none is. Scratch of [`ActiveRows::mark`].
    base: Vec<[u32; 2]>,
    /// Per node row `i·ny + j`: the active span `[k0, k1)`, empty (`k0 == k1`) where no
    /// stencil reaches.
    pub span: Vec<[u32; 2]>,
}

/// The empty span of [`ActiveRows::base`].
const NO_BASE: [u32; 2] = [u32::MAX, 0];

impl ActiveRows {
    /// No active node, on a grid of `n` nodes.
    pub fn empty(n: [usize; 3]) -> Self {
        ActiveRows {
            base: Vec::new(),
            span: vec![[0, 0]; n[0] * n[1]],
        }
    }

    /// Starts a new marking for a grid of `n` nodes: no base row holds a particle.
    pub fn clear(&mut self, n: [usize; 3]) {
        self.base.clear();
        self.base.resize(n[0] * n[1], NO_BASE);
    }

    /// The base rows, for a parallel marker that cuts them itself.
    pub fn base_mut(&mut self) -> &mut [[u32; 2]] {
        &mut self.base
    }

    /// Records a particle whose stencil base is `(·, ·, k)` in the base row entry `row`.
    #[inline(always)]
    pub fn mark(row: &mut [u32; 2], k: usize) {
        let k = k as u32;
        row[0] = row[0].min(k);
        row[1] = row[1].max(k);
    }

    /// Derives the node rows' spans from the marked base rows (see the type's docs).
    pub fn finish(&mut self, n: [usize; 3]) {
        use rayon::prelude::*;
        let (nx, ny) = (n[0], n[1]);
        self.span.resize(nx * ny, [0, 0]);
        let base = &self.base;
        self.span
            .par_chunks_mut(ny)
            .enumerate()
            .for_each(|(i, plane)| {
                for (j, span) in plane.iter_mut().enumerate() {
                    let mut hull = NO_BASE;
                    for bi in i.saturating_sub(2)..=i {
                        for bj in j.saturating_sub(2)..=j {
                            let b = base[bi * ny + bj];
                            hull = [hull[0].min(b[0]), hull[1].max(b[1])];
                        }
                    }
                    *span = if hull[0] <= hull[1] {
                        [hull[0], (hull[1] + 3).min(n[2] as u32)]
                    } else {
                        [0, 0]
                    };
                }
            });
    }

    /// Active nodes (for reports and tests).
    pub fn nodes(&self) -> usize {
        self.span.iter().map(|s| (s[1] - s[0]) as usize).sum()
    }
}

/// Calls `f(range)` for each flat node range of `spans` (per-row spans as in
/// [`ActiveRows::span`], rows of `nz` nodes), in index order, skipping empty ones; or once for
/// all `nodes` when `spans` is `None`. The sequential walk over the active part, for sums that
/// need a fixed order and for copies.
pub fn for_span_ranges(
    spans: Option<&[[u32; 2]]>,
    nodes: usize,
    nz: usize,
    mut f: impl FnMut(std::ops::Range<usize>),
) {
    match spans {
        Some(spans) => {
            for (row, s) in spans.iter().enumerate() {
                if s[1] > s[0] {
                    f(row * nz + s[0] as usize..row * nz + s[1] as usize);
                }
            }
        }
        None => f(0..nodes),
    }
}

/// Calls `f(index, node)` for every node of `nodes`, an x-major array of a grid of `n` nodes,
/// that lies in a span of `active`, or for every node when `active` is `None`; one x-plane per
/// parallel task, each plane's nodes in index order. The result of a per-node `f` does not
/// depend on the thread count.
#[inline(always)]
pub fn for_active_nodes<T: Send>(
    nodes: &mut [T],
    n: [usize; 3],
    active: Option<&ActiveRows>,
    f: impl Fn(usize, &mut T) + Sync,
) {
    use rayon::prelude::*;
    let plane_len = n[1] * n[2];
    nodes
        .par_chunks_mut(plane_len)
        .enumerate()
        .for_each(|(i, plane)| {
            let p0 = i * plane_len;
            match active {
                Some(rows) => {
                    for (j, span) in rows.span[i * n[1]..(i + 1) * n[1]].iter().enumerate() {
                        let (k0, k1) = (span[0] as usize, span[1] as usize);
                        let r0 = j * n[2];
                        for (k, node) in plane[r0 + k0..r0 + k1].iter_mut().enumerate() {
                            f(p0 + r0 + k0 + k, node);
                        }
                    }
                }
                None => {
                    for (k, node) in plane.iter_mut().enumerate() {
                        f(p0 + k, node);
                    }
                }
            }
        });
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
            nodes: vec![Node::ZERO; len],
            velocity: vec![DVec3::ZERO; len],
            sparse: true,
            // The first grid reset zeroes every node and starts the tracking.
            active: None,
        }
    }

    /// Number of nodes.
    #[inline(always)]
    pub fn node_count(&self) -> usize {
        self.nodes.len()
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
