//! The forward substep does not allocate per particle or per node: after the first step has
//! sized every buffer, a substep's allocations are a few small lists (the bodies and colliders
//! sorted into scene order), whatever the particle count. A counting allocator measures them.
//! (Allocation counts, not timings: nothing here depends on the machine's speed.)

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
    let mut sim = powderlab::sim::Simulation::new(
        &sc,
        &powderlab::sim::SimOptions {
            threads: Some(threads),
            ..Default::default()
        },
    )
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

#[test]
fn a_substep_allocates_nothing_per_particle_or_node() {
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
}
