//! Resting powder set aside: a clump of particles that has stood still for a while, with
//! nothing moving near it, leaves the substep's stages until something comes near again
//! (`SimOptions::rest`, forward runs only).
//!
//! A weighing dose spends most of its simulated time tapping a spatula over the boat while the
//! vial's 36k grains rest: every stage still visits them, at the cost of the whole scene. The
//! user's card asks to leave out what a scene does not need; these grains are it, as long as
//! they stay at rest and nothing reaches them.
//!
//! **When a clump parks** (checked after every [`RestRule::check_every`]-th step): the awake
//! particles are grouped into clumps, the connected sets of occupied grid cells where two cells
//! within [`INTERACTION_CELLS`] of each other (L∞) are connected: particles farther apart than
//! that share no grid node, so a clump is exactly a set of particles that no other particle
//! touches through the grid. A clump parks when every one of its particles has moved slower
//! than [`RestRule::speed`] for the last [`RestRule::steps`] steps, and no collider that moves
//! (a tool) is within [`WAKE_CELLS`] cells of it. Parking never cuts through powder: a clump is
//! whole, so no awake particle loses a neighbour.
//!
//! **When it wakes** (checked before every step): when an awake particle, along its path over
//! the coming step (its velocity and gravity's drop), or a moving collider, grown by its
//! motion over the coming step, comes within [`WAKE_CELLS`] cells of a parked particle. The
//! body's parked particles then return to their places in the body's order, with the state
//! they had, and the still counts start again.
//!
//! **What it changes.** A parked particle keeps its position, velocity, `C`, `F` and hardening;
//! what it would have done meanwhile is left out. At rest that is the slow creep of a resting
//! packing (in the weighing vial, grains along the wall slide at about 0.6 mm/s; see
//! docs/results/rest.md, `cargo run --release --example rest_creep`). The balance weighs parked particles too, and recordings and
//! [`super::Simulation::body_states`] show them. It is deterministic: every decision is made on
//! the state in a fixed order, so the results are the same for any thread count.

use crate::components::parked::{merge, split};
use crate::components::*;
use bevy_ecs::prelude::*;
use glam::DVec3;

/// Particles in grid cells farther apart than this (L∞, in cells) share no grid node: a
/// quadratic stencil spans three nodes from its base, so two particles meet on a node only when
/// their cells are within two of each other; one more absorbs a substep's motion.
pub const INTERACTION_CELLS: i64 = 3;

/// How near (in cells, besides the motion over the coming step) an awake particle or a moving
/// collider may come to a parked particle before the clump wakes: the interaction distance
/// plus the collider's contact band and the particle contact's reach, about a cell.
pub const WAKE_CELLS: f64 = 4.0;

/// When resting powder is set aside.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RestRule {
    /// A particle is still while slower than this (m/s).
    pub speed: f64,
    /// ... for this many consecutive steps.
    pub steps: u32,
    /// Steps between the looks for clumps to park.
    pub check_every: u64,
}

impl Default for RestRule {
    /// 1 mm/s over 20 steps: at dx = 1 mm and Δt = 10 ms, a hundredth of a cell a step.
    fn default() -> Self {
        RestRule {
            speed: 1e-3,
            steps: 20,
            check_every: 10,
        }
    }
}

/// The per-particle columns a stage reads or writes, which parking moves together.
type Columns = (
    &'static mut Position,
    &'static mut Velocity,
    &'static mut AffineVelocity,
    &'static mut DeformationGradient,
    &'static mut TrialDeformation,
    &'static mut SvdFactors,
    &'static mut P2gAffine,
    Option<&'static mut Hardening>,
);

type ColumnsItem<'w> = (
    Mut<'w, Position>,
    Mut<'w, Velocity>,
    Mut<'w, AffineVelocity>,
    Mut<'w, DeformationGradient>,
    Mut<'w, TrialDeformation>,
    Mut<'w, SvdFactors>,
    Mut<'w, P2gAffine>,
    Option<Mut<'w, Hardening>>,
);

/// Moves the particles `mask` marks from the columns into `p`, and marks the cells near them.
fn park(p: &mut Parked, cols: &mut ColumnsItem, mask: Vec<bool>, grid: Cells) {
    let (x, v, c, f, ft, svd, a, q) = cols;
    p.x = split(&mut x.0, &mask);
    p.v = split(&mut v.0, &mask);
    p.c = split(&mut c.0, &mask);
    p.f = split(&mut f.0, &mask);
    p.ft = split(&mut ft.0, &mask);
    p.u = split(&mut svd.u, &mask);
    p.s = split(&mut svd.s, &mask);
    p.sv = split(&mut svd.v, &mask);
    p.a = split(&mut a.0, &mask);
    if let Some(q) = q {
        p.q = split(&mut q.0, &mask);
    }
    p.mask = mask;
    p.still.clear();
    p.grid = grid;
    let mut seen = vec![false; grid.count()];
    p.cells =
        p.x.iter()
            .map(|x| grid.of_point(*x))
            .filter(|c| !std::mem::replace(&mut seen[grid.flat(*c)], true))
            .collect();
    p.near = vec![false; grid.count()];
    let r = WAKE_CELLS.ceil() as i64;
    for c in &p.cells {
        grid.around(*c, r, |d| p.near[grid.flat(d)] = true);
    }
}

/// Returns every parked particle of `p` to its place in the columns.
fn wake(p: &mut Parked, cols: &mut ColumnsItem) {
    let (x, v, c, f, ft, svd, a, q) = cols;
    let mask = std::mem::take(&mut p.mask);
    merge(&mut x.0, &mut p.x, &mask);
    merge(&mut v.0, &mut p.v, &mask);
    merge(&mut c.0, &mut p.c, &mask);
    merge(&mut f.0, &mut p.f, &mask);
    merge(&mut ft.0, &mut p.ft, &mask);
    merge(&mut svd.u, &mut p.u, &mask);
    merge(&mut svd.s, &mut p.s, &mask);
    merge(&mut svd.v, &mut p.sv, &mask);
    merge(&mut a.0, &mut p.a, &mask);
    if let Some(q) = q {
        merge(&mut q.0, &mut p.q, &mask);
    }
    p.still.clear();
    p.cells.clear();
    p.near.clear();
}

/// A collider that moves over the coming step (a tool), with how far its surface can move.
struct Mover {
    shape: crate::math::sdf::Shape,
    pose: ColliderPose,
    radius: f64,
    travel: f64,
}

fn movers(world: &mut World, step: usize) -> Vec<Mover> {
    let mut q = world.query::<(&Collider, &ColliderPose, Option<&Control>)>();
    q.iter(world)
        .filter(|(c, _, _)| c.kind == ColliderKind::Tool)
        .map(|(c, pose, ctl)| {
            let u = ctl.and_then(|k| k.per_step.get(step).copied());
            let u = u.unwrap_or([0.0; 6]);
            let t = DVec3::new(u[0], u[1], u[2]).length();
            let r = DVec3::new(u[3], u[4], u[5]).length();
            Mover {
                shape: c.shape.clone(),
                pose: *pose,
                radius: c.bounding_radius,
                travel: t + r * c.bounding_radius,
            }
        })
        .collect()
}

impl Mover {
    /// Whether the collider, over the coming step, comes within `reach` of `p`.
    fn near(&self, p: DVec3, reach: f64) -> bool {
        let r = reach + self.travel;
        if (p - self.pose.pose.translation).length() > self.radius + r {
            return false;
        }
        let local = self.pose.pose.to_local(p);
        self.pose.sdf_at_local(&self.shape, local).0 < r
    }
}

/// Before a step: wakes every body whose parked particles an awake particle (along its path
/// over the step) or a moving collider comes near.
pub fn before_step(world: &mut World) {
    let (dt, g) = {
        let p = world.resource::<SimParams>();
        (p.dt, p.gravity)
    };
    // Most steps have nothing parked: no paths to gather then.
    let mut parked = world.query::<&Parked>();
    if parked.iter(world).all(|p| p.is_empty()) {
        return;
    }
    let dx = world.resource::<Grid>().dx;
    let step = world.resource::<Clock>().step;
    let movers = movers(world, step);
    let mut q = world.query::<(&Position, &Velocity)>();
    let mut paths: Vec<(DVec3, DVec3)> = Vec::new();
    for (x, v) in q.iter(world) {
        paths.extend(x.0.iter().zip(&v.0).map(|(x, v)| (*x, *v)));
    }
    let reach = WAKE_CELLS * dx;
    let mut q = world.query::<(&mut Parked, Columns)>();
    for (mut p, mut cols) in q.iter_mut(world) {
        if p.mask.is_empty() {
            continue;
        }
        let grid = p.grid;
        // A path: x + v·s + ½g·s² for s in [0, Δt], looked at every half cell.
        let path_near = paths.iter().any(|&(x, v)| {
            let fall = 0.5 * g * dt * dt;
            let len = (v * dt).length() + fall.length();
            let n = (len / (0.5 * dx)).ceil().max(1.0) as usize;
            (0..=n).any(|k| {
                let s = k as f64 / n as f64;
                let y = x + v * (dt * s) + fall * (s * s);
                p.near[grid.flat(grid.of_point(y))]
            })
        });
        let half = 0.5 * dx * 3f64.sqrt();
        let mover_near = || {
            movers.iter().any(|m| {
                p.cells
                    .iter()
                    .any(|c| m.near(grid.centre(*c), reach + half))
            })
        };
        if path_near || mover_near() {
            wake(&mut p, &mut cols);
        }
    }
}

/// After a step: counts each awake particle's still steps and, every `rule.check_every` steps,
/// parks the clumps that are still and that no moving collider is near. The clumps are found
/// over every body's particles together, since particles of two bodies share grid nodes too.
pub fn after_step(world: &mut World, rule: &RestRule) {
    let step = world.resource::<Clock>().step;
    let grid = Cells::of(world.resource::<Grid>());
    let check = (step as u64).is_multiple_of(rule.check_every);
    let mut q = world.query::<(Entity, &mut Parked, Columns)>();
    // Per body: its entity, and its particles' positions and still counts.
    let mut bodies: Vec<(Entity, usize)> = Vec::new();
    let (mut x, mut still) = (Vec::new(), Vec::new());
    for (e, mut p, mut cols) in q.iter_mut(world) {
        let v = &cols.1 .0;
        if p.still.len() != v.len() {
            p.still = vec![0; v.len()];
        }
        for (s, v) in p.still.iter_mut().zip(v) {
            *s = if v.length() < rule.speed { *s + 1 } else { 0 };
        }
        if !check {
            continue;
        }
        // The whole body is looked at again: parked particles return to their places first,
        // counted as still, so that a clump that has come to rest beside them parks with them.
        let mut s = std::mem::take(&mut p.still);
        if !p.mask.is_empty() {
            let mut parked_still = vec![rule.steps; p.len()];
            merge(&mut s, &mut parked_still, &p.mask);
            wake(&mut p, &mut cols);
        }
        bodies.push((e, s.len()));
        x.extend_from_slice(&cols.0 .0);
        still.extend(s);
    }
    if !check {
        return;
    }
    let movers = movers(world, step);
    let mask = parkable(grid, &x, &still, rule.steps, &movers, WAKE_CELLS * grid.dx);
    let mut q = world.query::<(&mut Parked, Columns)>();
    let mut at = 0;
    for (e, n) in bodies {
        let (mut p, mut cols) = q.get_mut(world, e).expect("the body is still there");
        let (m, s) = (&mask[at..at + n], &still[at..at + n]);
        at += n;
        if m.iter().any(|&m| m) {
            park(&mut p, &mut cols, m.to_vec(), grid);
        }
        // The awake particles keep their counts.
        p.still = s.to_vec();
        if !p.mask.is_empty() {
            let mask = p.mask.clone();
            split(&mut p.still, &mask);
        }
    }
}

/// The particles of the clumps that may park: every particle of the clump still for `steps`
/// steps, and no moving collider within `reach` of the clump's cells.
fn parkable(
    grid: Cells,
    x: &[DVec3],
    still: &[u32],
    steps: u32,
    movers: &[Mover],
    reach: f64,
) -> Vec<bool> {
    let cells: Vec<[i64; 3]> = x.iter().map(|x| grid.of_point(*x)).collect();
    // Per cell: whether occupied, and whether some particle in it is not still.
    let mut occupied = vec![false; grid.count()];
    let mut moving = vec![false; grid.count()];
    for (c, s) in cells.iter().zip(still) {
        let f = grid.flat(*c);
        occupied[f] = true;
        moving[f] |= *s < steps;
    }
    // Clumps: flood fill over the occupied cells within INTERACTION_CELLS of each other.
    let mut clump = vec![u32::MAX; grid.count()];
    let mut good: Vec<bool> = Vec::new();
    let half = 0.5 * grid.dx * 3f64.sqrt();
    let mut stack = Vec::new();
    for start in &cells {
        if clump[grid.flat(*start)] != u32::MAX {
            continue;
        }
        let id = good.len() as u32;
        let mut ok = true;
        clump[grid.flat(*start)] = id;
        stack.push(*start);
        while let Some(c) = stack.pop() {
            ok = ok
                && !moving[grid.flat(c)]
                && !movers.iter().any(|m| m.near(grid.centre(c), reach + half));
            grid.around(c, INTERACTION_CELLS, |d| {
                let f = grid.flat(d);
                if occupied[f] && clump[f] == u32::MAX {
                    clump[f] = id;
                    stack.push(d);
                }
            });
        }
        good.push(ok);
    }
    cells
        .iter()
        .map(|c| good[clump[grid.flat(*c)] as usize])
        .collect()
}
