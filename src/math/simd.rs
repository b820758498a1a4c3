//! Runs a loop compiled for the host's vector unit where it has one.
//!
//! The crate builds for the x86-64 baseline (SSE2, two f64 per register). [`vectorized`] runs a
//! [`Kernel`] inside a function compiled with AVX2 (four f64 per register) when the CPU has it:
//! the kernel's `run`, which must be `#[inline(always)]`, and everything it inlines are compiled
//! there for AVX2, so that a grid node's four numbers (`crate::components::Node`) move as one
//! register. Rust never contracts a multiply and an add into an FMA on its own, and AVX2 enables
//! no FMA, so the AVX2 code computes the same operations in the same order: its results are
//! bitwise those of the baseline code (the test below runs both).
//!
//! A kernel is a struct, not a closure: a closure cannot be marked `#[inline(always)]`, and one
//! that LLVM declines to inline is compiled for the baseline, whatever its caller's features.

/// A loop to run through [`vectorized`]. Implementations mark `run` `#[inline(always)]`.
pub trait Kernel {
    type Output;
    fn run(self) -> Self::Output;
}

/// Runs `k`, compiled for AVX2 where the CPU has it (see the module docs).
#[inline(always)]
pub fn vectorized<K: Kernel>(k: K) -> K::Output {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, the only feature the function is compiled for.
        return unsafe { run_avx2(k) };
    }
    k.run()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn run_avx2<K: Kernel>(k: K) -> K::Output {
    k.run()
}

/// Runs `k` compiled for the baseline only, for tests that compare the two builds.
pub fn baseline<K: Kernel>(k: K) -> K::Output {
    k.run()
}
