//! Stage 9, G2P: gather particle velocity and the APIC affine velocity
//!
//! ```text
//! v_p = Σ_i w_ip·v_i,    C_p = (4/dx²)·Σ_i w_ip·v_i·(x_i − x_p)ᵀ
//! ```
//!
//! A gather: each particle reads its 27 nodes, so it is trivially parallel and deterministic.
//! Reads `Grid`, `Position`; writes `Velocity`, `AffineVelocity`.

use crate::components::*;
use crate::math::kernel::lanes::gather_many;
use crate::math::kernel::GridView;
use crate::systems::FiniteWatch;
use bevy_ecs::prelude::*;
use rayon::prelude::*;

/// Particles per parallel work item: groups of four in SIMD lanes
/// ([`crate::math::kernel::lanes`]). Any size gives the same bits (a gather is per particle).
const CHUNK: usize = 256;

pub fn g2p(
    grid: Res<Grid>,
    mut health: ResMut<Health>,
    mut bodies: Query<(&Body, &Position, &mut Velocity, &mut AffineVelocity)>,
) {
    for (body, x, mut v, mut c) in &mut bodies {
        let watch = FiniteWatch::default();
        let view = GridView {
            velocity: &grid.velocity,
            origin: grid.origin,
            dx: grid.dx,
            n: grid.n,
        };
        v.0.par_chunks_mut(CHUNK)
            .zip(c.0.par_chunks_mut(CHUNK).zip(x.0.par_chunks(CHUNK)))
            .for_each(|(v, (c, x))| {
                gather_many(&view, x, v, c);
                watch.check(v.iter().all(|v| v.is_finite()));
            });
        if let Some(i) = watch.first_nonfinite_vec(&v.0) {
            health.report(Fault::particle("g2p", "v", &body.name, i, v.0[i]));
        }
    }
}
