//! The balance, an instrument rather than a stage: once per global step, after the step's
//! substeps, it weighs the powder in its boat's cavity and updates its display
//! (`crate::components::balance`). It writes only the `Balance`, which no stage reads, so it has
//! no adjoint and a backward pass never runs it.
//!
//! Reads `SimParams`, `Body`, `Position`; writes `Balance`.

use crate::components::*;
use bevy_ecs::prelude::*;

/// The mass (g) of the particles inside `balance`'s boat, summed in body and particle order;
/// a body's parked particles (`crate::sim::rest`) rest where they are and weigh as well.
pub fn load_g(balance: &Balance, bodies: &[(&Body, &Position, Option<&Parked>)]) -> f64 {
    let mut kg = 0.0;
    for (b, x, parked) in bodies {
        let parked = parked.map_or(&[][..], |p| p.positions());
        let n =
            x.0.iter()
                .chain(parked)
                .filter(|p| balance.boat.inside(**p))
                .count();
        kg += n as f64 * b.particle_mass;
    }
    kg * 1e3
}

pub fn balance(
    params: Res<SimParams>,
    bodies: Query<(&Body, &Position, Option<&Parked>)>,
    mut balances: Query<&mut Balance>,
) {
    let mut list: Vec<_> = bodies.iter().collect();
    list.sort_by_key(|(b, _, _)| b.index);
    for mut b in &mut balances {
        let load = load_g(&b, &list);
        b.update(load, params.dt);
    }
}
