//! A planner continues each action from the state the last one left (`Build::with_start`). A
//! run restarted from a snapshot must be the uninterrupted run: the state is the particles'
//! positions, velocities, APIC `C` and `F` (the grid is rebuilt every substep), so a snapshot
//! that dropped or rounded any of them would show here as a difference of the size of the
//! motion. It is not the same to the bit: the SVD's Jacobi sweeps start from the previous
//! substep's `V` (`systems::svd`), which the snapshot does not carry, and that changes the
//! decomposition in its last bits ([`ROUNDING`]).

mod common;

use powderlab::sim::{Build, SimOptions};

/// The largest difference allowed between a restarted and an uninterrupted run, relative to the
/// motion (positions) or absolute (velocities in m/s, `F`): the SVD's warm start moves its
/// results by a few ulps per substep, which seven steps of a collapse amplify to 1e-12 at most
/// (measured: 2e-14 m, 4e-13 m/s, 9e-13);
/// a dropped column (`C` reset to zero, `F` to the identity) differs by 1e-3 or more.
const ROUNDING: f64 = 1e-9;

#[test]
fn a_run_restarted_from_its_snapshot_is_the_uninterrupted_run() {
    // A collapsing column: every particle moves, shears and yields in the 12 steps.
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/scenes/calibration_tiny.ron");
    let scene = powderlab::scene::Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
    let opts = SimOptions::threads(Some(2));
    let build = Build::new(&scene).unwrap();
    let mut whole = build.simulation(scene.clone(), &opts).unwrap();
    whole.run(12, |_| {}).unwrap();
    let mut first = build.simulation(scene.clone(), &opts).unwrap();
    first.run(5, |_| {}).unwrap();
    let snapshot = first.body_states();
    assert!(
        snapshot[0].v.iter().any(|v| v.length() > 1e-3),
        "the snapshot is taken in motion"
    );
    let mut rest = build
        .with_start(&scene, &snapshot)
        .unwrap()
        .simulation(scene.clone(), &opts)
        .unwrap();
    rest.run(7, |_| {}).unwrap();
    assert_eq!(rest.params().substeps, whole.params().substeps);
    let (a, b) = (rest.body_states(), whole.body_states());
    let moved = b[0]
        .x
        .iter()
        .zip(&snapshot[0].x)
        .map(|(p, q)| (*p - *q).length())
        .fold(0.0, f64::max);
    let worst = |f: &dyn Fn(usize) -> f64| (0..a[0].x.len()).map(f).fold(0.0, f64::max);
    let dx = worst(&|i| (a[0].x[i] - b[0].x[i]).length());
    let dv = worst(&|i| (a[0].v[i] - b[0].v[i]).length());
    let df = worst(&|i| {
        (a[0].f[i] - b[0].f[i])
            .abs()
            .to_cols_array()
            .into_iter()
            .fold(0.0, f64::max)
    });
    assert!(
        moved > 1e-4,
        "the column moves {moved} m after the snapshot"
    );
    assert!(
        dx <= ROUNDING * moved && df <= ROUNDING && dv <= ROUNDING,
        "restarted against uninterrupted: |Δx| {dx:e} m (of {moved:e} m moved), |Δv| {dv:e} m/s, |ΔF| {df:e}"
    );
}

#[test]
fn a_snapshot_may_hold_fewer_particles_but_not_a_broken_one() {
    let scene = common::load("column_collapse_planar.ron");
    let build = Build::new(&scene).unwrap();
    let mut sim = build
        .simulation(scene.clone(), &SimOptions::default())
        .unwrap();
    sim.run(2, |_| {}).unwrap();
    let mut st = sim.body_states();
    // Half the particles, as a planner that discarded the spill would leave.
    let n = st[0].x.len() / 2;
    for b in &mut st {
        b.x.truncate(n);
        b.v.truncate(n);
        b.c.truncate(n);
        b.f.truncate(n);
    }
    let mut half = build
        .with_start(&scene, &st)
        .unwrap()
        .simulation(scene.clone(), &SimOptions::default())
        .unwrap();
    assert_eq!(half.particle_count(), n);
    half.run(2, |_| {}).unwrap();
    common::assert_finite(&mut half);

    let mut ragged = st.clone();
    ragged[0].v.pop();
    let e = build.with_start(&scene, &ragged).unwrap_err().to_string();
    assert!(e.contains("expected the same number"), "{e}");
    let mut nan = st.clone();
    nan[0].f[3].x_axis.y = f64::NAN;
    let e = build.with_start(&scene, &nan).unwrap_err().to_string();
    assert!(e.contains("non-finite"), "{e}");
    // A particle at 50 m/s: the guard raises the substeps for it, as for a scene's velocity.
    let mut fast = st.clone();
    fast[0].v[0].y = -50.0;
    let raised = build.with_start(&scene, &fast).unwrap();
    assert!(
        raised.prepared.stability.substeps > build.prepared.stability.substeps,
        "{:?}",
        raised.prepared.stability
    );
    let e = build.with_start(&scene, &[]).unwrap_err().to_string();
    assert!(e.contains("0 bodies"), "{e}");
}
