//! The active-block grid (`Grid::active`: the stages that sweep nodes visit only the spans that
//! particles' stencils reach) gives the dense grid's results to the bit, forward and backward:
//! every node it skips is one the dense sweep finds empty and leaves alone.
//!
//! The forward scene fills one corner of its domain, against the floor and two walls, with a
//! tool passing through and a second body in the opposite corner (both bodies mark the spans),
//! so that the walls, the collider contact and the skipped empty space all take part; the test also checks that most of the grid was skipped and that no node
//! outside the spans holds a value. The backward case is the small transport scene (containers,
//! a skill-driven spoon, friction walls), whose records swap grids in and out.

use glam::DVec3;
use powderlab::adjoint::tape::{gradient, Gradients, Tape};
use powderlab::components::{state_fingerprint, BodyState, Grid, Node};
use powderlab::scene::Scene;
use powderlab::sim::Simulation;

mod common;

const CORNER: &str = r#"Scene(
    simulation: (cells: (32, 20, 32), dx: 0.01, dt: 0.01, substeps: 10, stability: Auto,
                 walls: (cells: 3, contact: Slip, friction: 0.3)),
    materials: { "sand": DruckerPrager((youngs_modulus: 2e4, poisson_ratio: 0.3, friction_deg: 30.0)) },
    bodies: [(name: "sand", material: "sand", fill: Box(min: (0.03, 0.03, 0.03), max: (0.09, 0.10, 0.09)),
              particles_per_cell: 8, lattice: Jittered(0.4), velocity: (0.3, 0.0, 0.1)),
             (name: "heap", material: "sand", fill: Box(min: (0.22, 0.03, 0.23), max: (0.26, 0.06, 0.27)),
              particles_per_cell: 8, lattice: Jittered(0.4), velocity: (-0.2, 0.0, 0.0))],
    colliders: [
        (name: "blade", kind: Tool, shape: Box(half_extents: (0.005, 0.03, 0.04)),
         position: (0.02, 0.06, 0.06), friction: 0.2, contact: Separate,
         control: Constant(linear: (0.2, 0.0, 0.0), steps: 12)),
    ],
)"#;

const STEPS: usize = 12;

fn corner() -> Scene {
    common::parse(CORNER).unwrap_or_else(|e| panic!("{e}"))
}

fn run(scene: &Scene, sparse: bool, threads: usize) -> (Vec<BodyState>, Simulation) {
    let mut sim = common::build(scene, threads);
    sim.world.resource_mut::<Grid>().sparse = sparse;
    sim.run(STEPS, |_| {}).unwrap();
    (sim.body_states(), sim)
}

#[test]
fn a_corner_scene_ends_in_the_dense_grids_state_to_the_bit() {
    let scene = corner();
    let (dense, dense_sim) = run(&scene, false, 2);
    assert!(dense_sim.world.resource::<Grid>().active.is_none());
    for threads in [1, 2] {
        let (sparse, sim) = run(&scene, true, threads);
        // A short message on failure: the states are thousands of particles.
        assert!(
            sparse == dense,
            "{threads} threads: final state bits {:016x} against the dense grid's {:016x}",
            state_fingerprint(&sparse),
            state_fingerprint(&dense)
        );
        let grid = sim.world.resource::<Grid>();
        let rows = grid
            .active
            .as_ref()
            .expect("a sparse grid tracks its active part");
        let total = grid.node_count();
        // The test is about skipping: the powder reaches well under half of the grid.
        assert!(
            rows.nodes() * 3 < total,
            "{} of {total} nodes active",
            rows.nodes()
        );
        // Every node outside the spans is zero, so a sweep that skips it misses nothing.
        let mut inside = vec![false; total];
        for (row, s) in rows.span.iter().enumerate() {
            let r0 = row * grid.n[2];
            inside[r0 + s[0] as usize..r0 + s[1] as usize].fill(true);
        }
        for (i, _) in inside.iter().enumerate().filter(|(_, &a)| !a) {
            assert!(
                grid.nodes[i] == Node::ZERO && grid.velocity[i] == DVec3::ZERO,
                "node {i} outside the active spans is not zero"
            );
        }
        // And every non-empty node of the dense run is inside them.
        let dense_grid = dense_sim.world.resource::<Grid>();
        for (i, m) in dense_grid.nodes.iter().map(|n| n.mass).enumerate() {
            assert!(
                m == 0.0 || inside[i],
                "node {i} has mass {m} outside the spans"
            );
        }
    }
}

fn grads(scene: &Scene, sparse: bool) -> Gradients {
    let mut sim = common::build(scene, 2);
    sim.world.resource_mut::<Grid>().sparse = sparse;
    let loss = powderlab::adjoint::loss::scene_loss(scene);
    // Checkpoints every 3 steps: the backward pass recomputes segments, swapping grids in and
    // out of its records.
    gradient(&mut sim, 10, &loss, Tape::Every(3)).unwrap()
}

#[test]
fn gradients_through_containers_and_a_tool_match_the_dense_grids_to_the_bit() {
    let scene = common::load_test_scene("tiny_transport.ron");
    let (a, b) = (grads(&scene, true), grads(&scene, false));
    assert_eq!(a.loss.to_bits(), b.loss.to_bits());
    assert_eq!(a.x0, b.x0);
    assert_eq!(a.v0, b.v0);
    assert_eq!(a.gravity, b.gravity);
    assert_eq!(a.friction, b.friction);
    assert_eq!(a.tool_start, b.tool_start);
    assert_eq!(a.tool_start_rotation, b.tool_start_rotation);
    assert_eq!(a.controls, b.controls);
    assert!(a.v0.iter().flatten().any(|g| *g != DVec3::ZERO));
}
