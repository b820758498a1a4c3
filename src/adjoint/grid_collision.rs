//! Adjoint of stage 8, grid collision. Domain walls: the forward applies the contact response
//! for each axis in turn, with a fixed axis normal and zero wall velocity; the adjoint replays
//! the three responses from the stored input velocity and applies `contact_response_adj` in
//! reverse. Exact inside each contact regime, one-sided at the switches (see
//! `crate::math::contact`).
//!
//! Collider contact (tools and containers) is not differentiated yet: the backward driver
//! refuses scenes with colliders rather than return a wrong gradient.

use crate::components::*;
use crate::math::contact::{contact_response, contact_response_adj};
use bevy_ecs::prelude::*;
use glam::DVec3;
use rayon::prelude::*;

/// Grid velocity entering the domain-wall response, saved by the backward driver.
#[derive(Resource, Clone, Debug, Default)]
pub struct WallInputVelocity(pub Vec<DVec3>);

pub fn domain_walls_adjoint(
    walls: Res<DomainWalls>,
    grid: Res<Grid>,
    input: Res<WallInputVelocity>,
    mut adj: ResMut<GridAdj>,
) {
    let n = grid.n;
    let cells = walls.cells;
    adj.velocity
        .par_iter_mut()
        .enumerate()
        .for_each(|(idx, g)| {
            let coord = [idx / (n[1] * n[2]), (idx / n[2]) % n[1], idx % n[2]];
            let mut normals = [DVec3::ZERO; 3];
            let mut vin = [DVec3::ZERO; 3];
            let mut v = input.0[idx];
            let mut count = 0;
            for a in 0..3 {
                let mut normal = DVec3::ZERO;
                if coord[a] < cells {
                    normal[a] = 1.0;
                } else if coord[a] + cells >= n[a] {
                    normal[a] = -1.0;
                } else {
                    continue;
                }
                normals[count] = normal;
                vin[count] = v;
                v = contact_response(v, DVec3::ZERO, normal, walls.mode, walls.friction);
                count += 1;
            }
            for k in (0..count).rev() {
                *g = contact_response_adj(
                    vin[k],
                    DVec3::ZERO,
                    normals[k],
                    walls.mode,
                    walls.friction,
                    *g,
                )
                .v;
            }
        });
}
