//! Adjoint of stage 10, particle collision (`systems::particle_collision::project_particle`).
//! Each particle's sequence of projections is replayed from the stored G2P velocity and
//! reversed with `project_particle_adj`. The SDF value and normal depend on the particle and
//! collider poses: `φ̄` and `n̄` flow to `x̄` through `∇φ = n` and the Hessian `R·H·Rᵀ`, and,
//! for a tool, to its translation, rotation and velocities (`NodeAdj::add_tool_contact`). Exact within a regime; the constraint switch `v·n = v_min`, the Coulomb
//! stick/slip switch and the reach test are one-sided (see `crate::math::contact`).

use crate::adjoint::grid_collision::{
    add_collider_adjoints, world_hessian, ChunkAdj, ColliderAdj, MAX_COLLIDERS, REDUCE_CHUNK,
};
use crate::components::*;
use crate::systems::particle_collision::{
    particle_contact, project_particle, project_particle_adj, ContactRule, Reach, MARGIN_CELLS,
};
use bevy_ecs::prelude::*;
use glam::DVec3;
use rayon::prelude::*;

/// The particle velocities entering the particle-collision stage (G2P's output), saved by the
/// backward driver.
#[derive(Component, Clone, Debug, Default)]
pub struct ParticleCollisionInput(pub Vec<DVec3>);

pub fn particle_collision_adjoint(
    params: Res<SimParams>,
    grid: Res<Grid>,
    mut chunks: Local<Vec<ChunkAdj>>,
    mut colliders: Query<(&Collider, &ColliderPose, &mut ColliderAdj)>,
    mut bodies: Query<(
        &Position,
        &ParticleCollisionInput,
        &mut PositionAdj,
        &mut VelocityAdj,
    )>,
) {
    let mut cs: Vec<_> = colliders.iter_mut().collect();
    cs.sort_by_key(|c| c.0.index);
    let dt = params.dt_sub;
    let margin = MARGIN_CELLS * grid.dx;
    // Per collider: its reach and its projection's rule.
    let view: Vec<(usize, &Collider, &ColliderPose, Reach, ContactRule)> = cs
        .iter()
        .enumerate()
        .filter(|(_, c)| c.0.particle_contact)
        .map(|(i, (c, p, _))| (i, *c, *p, Reach::of(c, p), ContactRule::of(c, margin, dt)))
        .collect();
    for (x, input, mut gx, mut gv) in &mut bodies {
        let particle = |i: usize, g: &mut DVec3, gxi: &mut DVec3, acc: &mut ChunkAdj| {
            let xp = x.0[i];
            let mut v = input.0[i];
            // Each hit: the collider's place in `view`, the velocity it met and the hit.
            let mut hits = [(0usize, DVec3::ZERO, (0.0, DVec3::ZERO, DVec3::ZERO)); MAX_COLLIDERS];
            let mut count = 0;
            for (k, (_, c, pose, reach, rule)) in view.iter().enumerate() {
                let Some(hit) = particle_contact(c, pose, reach, xp, v, dt, rule.reach()) else {
                    continue;
                };
                hits[count] = (k, v, hit);
                v = project_particle(v, hit, rule);
                count += 1;
            }
            for &(k, vin, hit) in hits[..count].iter().rev() {
                let (ci, c, pose, _, rule) = &view[k];
                let (ci, n) = (*ci, hit.1);
                let a = project_particle_adj(vin, hit, rule, *g);
                *g = a.v;
                let h = world_hessian(&c.shape, pose, xp);
                acc[ci].friction += a.mu;
                if c.kind == ColliderKind::Tool {
                    *gxi += acc[ci].add_tool_contact(pose, h, xp, n, (a.phi, a.n, a.v_body));
                } else {
                    *gxi += n * a.phi + h * a.n;
                }
            }
        };
        // One partial sum per chunk, into a buffer kept between substeps.
        chunks.clear();
        chunks.resize(gv.0.len().div_ceil(REDUCE_CHUNK), ChunkAdj::default());
        gv.0.par_chunks_mut(REDUCE_CHUNK)
            .zip(gx.0.par_chunks_mut(REDUCE_CHUNK))
            .zip(chunks.par_iter_mut())
            .enumerate()
            .for_each(|(c, ((gs, gxs), acc))| {
                for (j, (g, gxi)) in gs.iter_mut().zip(gxs.iter_mut()).enumerate() {
                    particle(c * REDUCE_CHUNK + j, g, gxi, acc);
                }
            });
        add_collider_adjoints(&chunks, cs.iter_mut().map(|(_, _, a)| &mut **a));
    }
}
