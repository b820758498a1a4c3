//! Substeps do not allocate per particle or per node: after the first step has sized every
//! buffer, a forward substep's allocations are a few small lists (the bodies and colliders
//! sorted into scene order), whatever the particle count; a backward pass's memory grows per
//! step by the step-start state its tape keeps, and by nothing per substep. A counting
//! allocator measures them. (Allocation counts, not timings: nothing here depends on the
//! machine's speed.)

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

struct Counting;
static CALLS: AtomicUsize = AtomicUsize::new(0);
static BYTES: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards every call to the system allocator unchanged; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        CALLS.fetch_add(1, Ordering::Relaxed);
        BYTES.fetch_add(l.size(), Ordering::Relaxed);
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        CALLS.fetch_add(1, Ordering::Relaxed);
        BYTES.fetch_add(n, Ordering::Relaxed);
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static ALLOC: Counting = Counting;

/// Bytes a substep may allocate: the sorted body and collider lists take a few hundred bytes
/// (320 on `sand_box`, 544 on `powder_transport`); one particle array of `sand_box` would take
/// 1.3 MB, so 16 KiB separates the two by two orders of magnitude either way.
const MAX_BYTES_PER_SUBSTEP: usize = 16 << 10;
const SUBSTEPS: usize = 10;

fn allocations_per_substep(scene: &str, threads: usize) -> (f64, f64) {
    let sc =
        powderlab::scene::Scene::load(format!("{}/scenes/{scene}", env!("CARGO_MANIFEST_DIR")))
            .unwrap();
    let mut sim =
        powderlab::sim::Simulation::new(&sc, &powderlab::sim::SimOptions::threads(Some(threads)))
            .unwrap();
    sim.step().unwrap();
    let (c0, b0) = (CALLS.load(Ordering::SeqCst), BYTES.load(Ordering::SeqCst));
    for _ in 0..SUBSTEPS {
        sim.substep().unwrap();
    }
    let (c1, b1) = (CALLS.load(Ordering::SeqCst), BYTES.load(Ordering::SeqCst));
    (
        (c1 - c0) as f64 / SUBSTEPS as f64,
        (b1 - b0) as f64 / SUBSTEPS as f64,
    )
}

/// Bytes allocated by a backward pass over `steps` steps of `sand_box` on 2 threads, and the
/// bytes of one step-start state on its tape.
fn backward_bytes(steps: usize) -> (usize, usize) {
    let path = format!("{}/scenes/sand_box.ron", env!("CARGO_MANIFEST_DIR"));
    let sc = powderlab::scene::Scene::load(path).unwrap();
    let mut sim =
        powderlab::sim::Simulation::new(&sc, &powderlab::sim::SimOptions::threads(Some(2)))
            .unwrap();
    let snapshot = powderlab::adjoint::checkpoint::snapshot(&mut sim.world).bytes();
    let loss = powderlab::adjoint::loss::scene_loss(&sc);
    let b0 = BYTES.load(Ordering::SeqCst);
    let tape = powderlab::adjoint::tape::Tape::Every(steps);
    powderlab::adjoint::tape::gradient(&mut sim, steps, &loss, tape).unwrap();
    (BYTES.load(Ordering::SeqCst) - b0, snapshot)
}

#[test]
fn substeps_allocate_nothing_per_particle_or_node() {
    // One test, so no other test's allocations run between the counts.
    for (scene, threads) in [
        ("sand_box.ron", 1),
        ("sand_box.ron", 2),
        ("powder_transport.ron", 2),
    ] {
        let (calls, bytes) = allocations_per_substep(scene, threads);
        eprintln!("{scene}, {threads} threads: {calls} allocations, {bytes} bytes per substep");
        assert!(
            bytes <= MAX_BYTES_PER_SUBSTEP as f64,
            "{scene} on {threads} threads allocates {bytes} bytes per substep ({calls} calls)"
        );
    }
    // One more step of the backward pass (20 substeps) adds its step-start state to the tape
    // (14.5 MB) and 0.3 MB of small lists; one particle-sized buffer per substep would add
    // 20 × 1.3 MB.
    let ((two, snapshot), (three, _)) = (backward_bytes(2), backward_bytes(3));
    let extra = three as f64 - two as f64;
    eprintln!("backward: one more step allocates {extra} bytes; a step-start state is {snapshot}");
    assert!(
        extra <= snapshot as f64 + (1 << 20) as f64,
        "one more backward step allocates {extra} bytes, the step-start state is {snapshot}"
    );
}
