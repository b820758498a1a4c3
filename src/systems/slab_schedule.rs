//! The schedule of the race-free slab scatter that P2G and the G2P adjoint share.
//!
//! Both stages bucket particles by the x-slab of their stencil base (see
//! [`crate::systems::p2g::bin_by_slab`]). Slab `s` writes the x-planes
//! `[SLAB·s, SLAB·s + SLAB + 2)`, so it shares nodes with slabs `s − 1` and `s + 1` and with no
//! other. Every node lies in exactly two consecutive slabs, one even and one odd, and its sum is
//! fixed as: the even slab's particles, then the odd slab's, each slab in particle order.
//!
//! **Dataflow, not phases.** The scatter used to run in two phases with a barrier between them:
//! all even slabs in parallel, then all odd ones. A phase splits into as many tasks as it has
//! occupied slabs, so an odd count leaves a thread idle: `sand_box`'s powder fills 5 slabs per
//! phase, 3 + 2 on two threads, which caps the scatter near 1.67×. Here an odd slab waits only
//! for its two even neighbours, so it runs while other even slabs still do. The order
//! constraint is the same (each node: even slab, then odd), so the sums are bitwise those of
//! the phases, for any thread count.
//!
//! Workers claim tasks from a list in a fixed order: the even slabs, with odd slab `2k + 1`
//! placed after even slab `2k + 4`, so that by the time it is claimed its neighbours `2k` and
//! `2k + 2` have usually finished. A claimed task is being run, and an odd slab depends only on
//! tasks claimed before it, so a worker that waits always waits on one that is running.

use rayon::prelude::*;
use std::marker::PhantomData;
use std::ops::Range;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// Width of a scatter slab in x-planes of base nodes. A slab writes `SLAB + 2` planes, and
/// those must not reach slab `s + 2`'s, which start `2·SLAB` planes on, so it must be ≥ 2. The
/// narrowest width gives the most slabs: the default scene's powder, 12 cells across in a cup,
/// makes 6–7 slabs instead of 3–4 at width 4, and its scatters now run on both threads
/// (adjoint G2P 1.60 → 1.08 s over its horizon, 2 threads); on `sand_box` the width makes no
/// measurable difference.
pub const SLAB: usize = 2;

/// The claim order and the per-slab completion flags of one scatter; sized on first use and
/// reused (no allocation per substep).
#[derive(Default)]
pub struct SlabSchedule {
    order: Vec<u32>,
    done: Vec<AtomicBool>,
    next: AtomicUsize,
}

/// Even slabs claimed before the first odd one (the lag between an odd slab and its higher
/// neighbour in the claim order).
const ODD_LAG: usize = 2;

/// Spins on a flag before yielding the thread: a slab's work is microseconds to milliseconds,
/// so a short spin usually suffices and a long wait does not burn the core.
const SPINS_BEFORE_YIELD: u32 = 256;

/// Marks a slab done when dropped, also when its work panics, so that no worker waits forever
/// on it (rayon then carries the panic to the caller).
struct MarkDone<'a>(&'a AtomicBool);

impl Drop for MarkDone<'_> {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Release);
    }
}

fn wait_for(flag: &AtomicBool) {
    let mut spins = 0u32;
    while !flag.load(Ordering::Acquire) {
        if spins < SPINS_BEFORE_YIELD {
            std::hint::spin_loop();
            spins += 1;
        } else {
            std::thread::yield_now();
        }
    }
}

/// The claim order of `n` slabs: evens, with odd slab `2k + 1` after even slab `2k + 2·ODD_LAG`.
pub fn claim_order(n: usize, out: &mut Vec<u32>) {
    out.clear();
    let (evens, odds) = (n.div_ceil(2), n / 2);
    let mut o = 0;
    for e in 0..evens {
        out.push((2 * e) as u32);
        if e >= ODD_LAG && o < odds {
            out.push((2 * o + 1) as u32);
            o += 1;
        }
    }
    out.extend((o..odds).map(|o| (2 * o + 1) as u32));
}

/// How [`SlabSchedule::scatter`] cuts its second array for each slab.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cut {
    /// A node array like the first: the slab's planes.
    Nodes,
    /// A particle array in scatter order: the slab's particles,
    /// `slab_start[s]..slab_start[s + 1]`.
    Particles,
    /// No second array: `other` is empty and every slab gets it empty.
    None,
}

impl SlabSchedule {
    /// Runs `work(slab, nodes_part, other_part)` for every slab of a binned body (`slab_start`
    /// from [`crate::systems::p2g::bin_by_slab`]), where `nodes_part` is the part of the x-major
    /// node array `nodes` (planes of `plane_len` nodes) that the slab writes and `other_part` is
    /// `other` cut by `cut`. Neighbouring slabs never run at once, and of two neighbours the
    /// even one finishes first, so every node's sum has a fixed order for any thread count.
    pub fn scatter<A: Send, B: Send>(
        &mut self,
        slab_start: &[u32],
        plane_len: usize,
        nodes: &mut [A],
        other: &mut [B],
        cut: Cut,
        work: impl Fn(usize, &mut [A], &mut [B]) + Sync,
    ) {
        let n_slabs = slab_start.len().saturating_sub(1);
        let other_len = match cut {
            Cut::Nodes => nodes.len(),
            Cut::Particles => slab_start.last().map_or(0, |&e| e as usize),
            Cut::None => 0,
        };
        assert_eq!(
            other.len(),
            other_len,
            "second scatter array sized for its cut"
        );
        let len = nodes.len();
        let (nodes, other) = (SharedSlice::new(nodes), SharedSlice::new(other));
        self.run(n_slabs, |s| {
            let r = slab_nodes(s, plane_len, len);
            let o = match cut {
                Cut::Nodes => r.clone(),
                Cut::Particles => slab_start[s] as usize..slab_start[s + 1] as usize,
                Cut::None => 0..0,
            };
            // SAFETY: slab `s` takes only the planes it writes, which meet those of slabs
            // `s ± 1` alone, and `run` never runs neighbouring slabs at once; the slabs'
            // particle ranges are disjoint.
            let (a, b) = unsafe { (nodes.slice(r), other.slice(o)) };
            work(s, a, b);
        });
    }

    /// Runs `work(slab)` for every slab in `0..n_slabs` on the current rayon pool, such that
    /// slabs `s` and `s + 1` never run at the same time and the even one of the two finishes
    /// before the odd one starts.
    fn run(&mut self, n_slabs: usize, work: impl Fn(usize) + Sync) {
        if self.order.len() != n_slabs {
            claim_order(n_slabs, &mut self.order);
            self.done.resize_with(n_slabs, AtomicBool::default);
        }
        for d in &mut self.done {
            *d.get_mut() = false;
        }
        *self.next.get_mut() = 0;
        let workers = rayon::current_num_threads().min(n_slabs);
        if workers <= 1 {
            // In claim order, every odd slab comes after both its neighbours.
            self.order.iter().for_each(|&s| work(s as usize));
            return;
        }
        let this = &*self;
        (0..workers).into_par_iter().for_each(|_| loop {
            let t = this.next.fetch_add(1, Ordering::Relaxed);
            let Some(&s) = this.order.get(t) else { break };
            let s = s as usize;
            if s % 2 == 1 {
                wait_for(&this.done[s - 1]);
                if let Some(next) = this.done.get(s + 1) {
                    wait_for(next);
                }
            }
            let _mark = MarkDone(&this.done[s]);
            work(s);
        });
    }
}

/// The node range (flat, x-major) that slab `slab` writes: x-planes
/// `[SLAB·slab, SLAB·slab + SLAB + 2)` of `plane_len` nodes each, cut at `len`.
fn slab_nodes(slab: usize, plane_len: usize, len: usize) -> Range<usize> {
    let start = (SLAB * slab * plane_len).min(len);
    let end = ((SLAB * slab + SLAB + 2) * plane_len).min(len);
    start..end
}

/// A mutable slice that the tasks of one [`SlabSchedule::run`] share, each taking the part its
/// slab writes.
struct SharedSlice<'a, T> {
    ptr: *mut T,
    len: usize,
    _borrow: PhantomData<&'a mut [T]>,
}

// SAFETY: a `SharedSlice` is an exclusive borrow of a `[T]` handed to several threads; the
// callers of `slice` guarantee that no two parts in use overlap, so sending `T`s between threads
// is all that is needed.
unsafe impl<T: Send> Sync for SharedSlice<'_, T> {}
unsafe impl<T: Send> Send for SharedSlice<'_, T> {}

impl<'a, T> SharedSlice<'a, T> {
    fn new(s: &'a mut [T]) -> Self {
        SharedSlice {
            ptr: s.as_mut_ptr(),
            len: s.len(),
            _borrow: PhantomData,
        }
    }

    /// The part `r` of the slice.
    ///
    /// # Safety
    /// While the returned slice lives, no other slice taken from `self` may overlap `r`.
    #[allow(clippy::mut_from_ref)]
    unsafe fn slice(&self, r: Range<usize>) -> &mut [T] {
        assert!(
            r.start <= r.end && r.end <= self.len,
            "slab range out of bounds"
        );
        // SAFETY: in bounds (checked), and exclusive by the caller's guarantee.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(r.start), r.end - r.start) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;

    #[test]
    fn claim_order_is_a_permutation_with_odd_slabs_after_their_neighbours() {
        let mut order = Vec::new();
        for n in 0..40 {
            claim_order(n, &mut order);
            let mut sorted = order.clone();
            sorted.sort_unstable();
            assert_eq!(sorted, (0..n as u32).collect::<Vec<_>>(), "n = {n}");
            let pos = |s: u32| order.iter().position(|&x| x == s).unwrap();
            for s in (1..n as u32).step_by(2) {
                assert!(pos(s - 1) < pos(s), "n = {n}, slab {s}");
                if s + 1 < n as u32 {
                    assert!(pos(s + 1) < pos(s), "n = {n}, slab {s}");
                }
            }
        }
    }

    /// Every slab runs once, no two neighbours overlap in time, and each odd slab starts after
    /// both of its neighbours finished (a log of start and end events, on 1, 2 and 4 threads).
    #[test]
    fn neighbours_never_overlap_and_evens_finish_first() {
        for threads in [1, 2, 4] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            for n in [1, 2, 3, 7, 24] {
                let log = Mutex::new(Vec::new());
                let mut schedule = SlabSchedule::default();
                pool.install(|| {
                    schedule.run(n, |s| {
                        log.lock().unwrap().push((s, true));
                        // Uneven work, so that the order of events varies.
                        std::thread::sleep(std::time::Duration::from_micros(50 * (s % 3) as u64));
                        log.lock().unwrap().push((s, false));
                    })
                });
                let log = log.into_inner().unwrap();
                assert_eq!(log.len(), 2 * n);
                let mut running = vec![false; n];
                let mut finished = vec![false; n];
                for (s, start) in log {
                    if start {
                        assert!(!finished[s] && !running[s], "slab {s} ran twice");
                        for nb in [s.wrapping_sub(1), s + 1] {
                            if nb < n {
                                assert!(!running[nb], "slabs {s} and {nb} overlapped");
                                if s % 2 == 1 {
                                    assert!(finished[nb], "odd slab {s} before even {nb}");
                                }
                            }
                        }
                        running[s] = true;
                    } else {
                        running[s] = false;
                        finished[s] = true;
                    }
                }
                assert!(finished.iter().all(|&f| f), "{threads} threads, {n} slabs");
            }
        }
    }

    #[test]
    fn slab_nodes_cover_their_planes_and_stop_at_the_end() {
        assert_eq!(SLAB, 2, "the ranges below are for slabs of 2 planes");
        assert_eq!(slab_nodes(0, 10, 1000), 0..40);
        assert_eq!(slab_nodes(3, 10, 1000), 60..100);
        assert_eq!(slab_nodes(49, 10, 1000), 980..1000);
        assert_eq!(slab_nodes(60, 10, 1000), 1000..1000);
    }
}
