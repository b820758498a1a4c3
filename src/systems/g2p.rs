//! Stage 9, G2P: gather particle velocity and the APIC affine velocity
//!
//! ```text
//! v_p = Σ_i w_ip·v_i,    C_p = (4/dx²)·Σ_i w_ip·v_i·(x_i − x_p)ᵀ
//! ```
//!
//! A gather: each particle reads its 27 nodes, so it is trivially parallel and deterministic.
//! Reads `Grid`, `Position`; writes `Velocity`, `AffineVelocity`.

use crate::components::*;
use crate::math::kernel::stencil;
use crate::systems::FiniteWatch;
use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3};
use rayon::prelude::*;

/// Gathers `(v_p, C_p)` for a particle at `x`, contracted one axis at a time
/// ([`crate::math::kernel::Stencil::node_sums`]): `v_p = Σ w·v_i` and
/// `C_p = (4/dx²)·Σ w·v_i·d_ipᵀ` factor along the axes, so a node costs a few multiply-adds
/// instead of its own weight and outer product.
#[inline(always)]
pub fn gather(grid: &Grid, x: DVec3) -> (DVec3, DMat3) {
    let dx = grid.dx;
    let st = stencil((x - grid.origin) / dx);
    let [bi, bj, bk] = st.base;
    let sums = st.node_sums(1.0 / dx, |a, b, c| {
        (grid.velocity[grid.index(bi + a, bj + b, bk) + c], 0.0)
    });
    (sums.w_g, sums.w_g_d(st.fx, dx) * (4.0 / (dx * dx)))
}

pub fn g2p(
    grid: Res<Grid>,
    mut health: ResMut<Health>,
    mut bodies: Query<(&Body, &Position, &mut Velocity, &mut AffineVelocity)>,
) {
    for (body, x, mut v, mut c) in &mut bodies {
        let watch = FiniteWatch::default();
        v.0.par_iter_mut()
            .zip(c.0.par_iter_mut().zip(x.0.par_iter()))
            .for_each(|(v, (c, x))| {
                (*v, *c) = gather(&grid, *x);
                watch.check(v.is_finite());
            });
        if let Some(i) = watch.first_nonfinite_vec(&v.0) {
            health.report(Fault {
                stage: "g2p",
                field: "v",
                owner: format!("body '{}' particle", body.name),
                index: i,
                value: format!("{:?}", v.0[i]),
            });
        }
    }
}
