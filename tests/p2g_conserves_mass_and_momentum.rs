//! P2G conserves mass exactly and momentum to round-off, and the 3-D stencil is a partition of
//! unity whose weight gradients sum to zero.

use bevy_ecs::system::RunSystemOnce;
use glam::{DMat3, DVec3};
use powderlab::components::*;
use powderlab::math::kernel::{stencil, weights_1d, weights_1d_deriv};
use powderlab::systems::{grid_reset::grid_reset, p2g::p2g};

mod common;

/// Relative round-off allowed for sums over ~10⁴ particles × 27 nodes in f64.
const SUM_REL_TOL: f64 = 1e-12;

use powderlab::util::lcg_uniform as lcg;

#[test]
fn stencil_partition_of_unity_in_3d() {
    let mut s = 11;
    for _ in 0..1000 {
        let x = DVec3::new(
            5.0 + 3.0 * lcg(&mut s),
            5.0 + 3.0 * lcg(&mut s),
            5.0 + 3.0 * lcg(&mut s),
        );
        let st = stencil(x);
        let mut sum = 0.0;
        let mut grad = DVec3::ZERO;
        let mut first_moment = DVec3::ZERO;
        for a in 0..3 {
            for b in 0..3 {
                for c in 0..3 {
                    let w = st.w[0][a] * st.w[1][b] * st.w[2][c];
                    sum += w;
                    let (da, db, dc) = (
                        weights_1d_deriv(st.fx.x),
                        weights_1d_deriv(st.fx.y),
                        weights_1d_deriv(st.fx.z),
                    );
                    let (wa, wb, wc) = (
                        weights_1d(st.fx.x),
                        weights_1d(st.fx.y),
                        weights_1d(st.fx.z),
                    );
                    grad += DVec3::new(
                        da[a] * wb[b] * wc[c],
                        wa[a] * db[b] * wc[c],
                        wa[a] * wb[b] * dc[c],
                    );
                    first_moment += w * (DVec3::new(a as f64, b as f64, c as f64) - st.fx);
                }
            }
        }
        assert!((sum - 1.0).abs() < 1e-15);
        assert!(grad.abs().max_element() < 1e-15);
        assert!(first_moment.abs().max_element() < 1e-15);
    }
}

#[test]
fn p2g_conserves_mass_and_momentum() {
    let mut world = bevy_ecs::world::World::new();
    let n = [20, 20, 20];
    let dx = 0.01;
    world.insert_resource(Grid::new(DVec3::ZERO, dx, n));
    world.insert_resource(SimParams {
        dt: 0.01,
        substeps: 20,
        dt_sub: 5e-4,
        gravity: DVec3::ZERO,
        empty_node_mass: 0.0,
        svd: Precision::F64,
    });
    world.insert_resource(Health::default());
    let mut s = 5;
    let np = 10_000;
    let x: Vec<DVec3> = (0..np)
        .map(|_| {
            DVec3::new(
                0.02 + 0.15 * lcg(&mut s),
                0.02 + 0.15 * lcg(&mut s),
                0.02 + 0.15 * lcg(&mut s),
            )
        })
        .collect();
    let v: Vec<DVec3> = (0..np)
        .map(|_| DVec3::new(lcg(&mut s) - 0.5, lcg(&mut s) - 0.5, lcg(&mut s) - 0.5))
        .collect();
    // An arbitrary affine term (APIC C plus stress): it must not create net momentum.
    let a: Vec<DMat3> = (0..np)
        .map(|_| DMat3::from_cols_array(&std::array::from_fn(|_| lcg(&mut s) - 0.5)))
        .collect();
    let m = 1.7e-3;
    world.spawn((
        Body {
            name: "b".into(),
            index: 0,
            particle_mass: m,
            particle_volume: 1e-6,
            lame: (0.0, 0.0),
        },
        Position(x),
        Velocity(v.clone()),
        P2gAffine(a),
        ScatterOrder::default(),
    ));
    world.run_system_once(grid_reset).unwrap();
    world.run_system_once(p2g).unwrap();
    let g = world.resource::<Grid>();
    let mass: f64 = g.nodes.iter().map(|n| n.mass).sum();
    let mom: DVec3 = g.nodes.iter().map(|n| n.momentum).sum();
    let total_m = m * np as f64;
    let total_p: DVec3 = v.iter().map(|v| *v * m).sum();
    assert!(
        (mass - total_m).abs() <= SUM_REL_TOL * total_m,
        "mass {mass} vs {total_m}"
    );
    assert!(
        (mom - total_p).length() <= SUM_REL_TOL * total_m,
        "momentum {mom} vs {total_p}"
    );
}
