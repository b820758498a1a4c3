//! Vectors of lanes for kernels that run several particles at once: one trait, [`Vector`], with
//! a portable implementation on arrays ([`Arr`]) and one on AVX registers ([`F64x4`] and
//! [`F32x8`]).
//!
//! Every operation is IEEE's on each lane (add, subtract, multiply, divide and square root
//! correctly rounded, comparisons false on NaN), so a kernel written over [`Vector`] gives the
//! same bits on arrays, on AVX registers, and one lane at a time in scalar code.
//!
//! The AVX types call `core::arch` intrinsics from `#[inline(always)]` methods. They are for
//! kernels inlined into a function compiled with `#[target_feature(enable = "avx2")]` and called
//! after `is_x86_feature_detected!("avx2")`: there the intrinsics inline into AVX code. They are
//! crate-private for that reason.

use std::ops::{Add, BitAnd, BitOr, Div, Mul, Neg, Not, Sub};

/// A floating-point type, with what the kernels need of it.
pub trait Real:
    Copy
    + PartialOrd
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    const ZERO: Self;
    const ONE: Self;
    fn abs(self) -> Self;
    fn sqrt(self) -> Self;
    fn signum(self) -> Self;
}

macro_rules! real {
    ($t:ty) => {
        impl Real for $t {
            const ZERO: $t = 0.0;
            const ONE: $t = 1.0;
            #[inline(always)]
            fn abs(self) -> $t {
                <$t>::abs(self)
            }
            #[inline(always)]
            fn sqrt(self) -> $t {
                <$t>::sqrt(self)
            }
            #[inline(always)]
            fn signum(self) -> $t {
                <$t>::signum(self)
            }
        }
    };
}
real!(f64);
real!(f32);

/// One mask bit per lane.
pub trait Mask: Copy + BitAnd<Output = Self> + BitOr<Output = Self> + Not<Output = Self> {
    fn splat(b: bool) -> Self;
    fn any(self) -> bool;
    fn all(self) -> bool;
}

/// The most lanes a [`Vector`] has (eight f32 in an AVX register).
pub const MAX_LANES: usize = 8;

/// `LANES` (at most [`MAX_LANES`]) values of `Scalar`, every operation lane by lane.
pub trait Vector:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    type Scalar: Real;
    type Mask: Mask;
    const LANES: usize;
    fn splat(x: Self::Scalar) -> Self;
    /// The first `LANES` values of `x`.
    fn load(x: &[Self::Scalar]) -> Self;
    /// Writes the lanes to the first `LANES` places of `out`.
    fn store(self, out: &mut [Self::Scalar]);
    fn sqrt(self) -> Self;
    fn abs(self) -> Self;
    /// `Real::signum` on each lane (1 for +0, −1 for −0; NaN for NaN).
    fn signum(self) -> Self;
    fn lt(self, o: Self) -> Self::Mask;
    fn le(self, o: Self) -> Self::Mask;
    fn eq(self, o: Self) -> Self::Mask;
    /// `a` where `m` holds, else `b`.
    fn select(m: Self::Mask, a: Self, b: Self) -> Self;
    /// Lane `l` set to `f(l)`, called in lane order (the AVX types insert, not reload).
    fn from_fn(f: impl FnMut(usize) -> Self::Scalar) -> Self;
}

/// f64 lanes, with the two operations on their bits that `math::elementary`'s `ln` and `exp`
/// need. Both are exact, so the portable and the AVX implementations agree to the bit.
pub trait F64Bits: Vector<Scalar = f64> {
    /// `2ᵏ` for lanes that hold `k + ROUND_MAGIC` (`1.5·2⁵²`, which makes the addition round
    /// to an integer) with an integer `k` in `[−1022, 1023]`: the magic's bits plus `k`, plus
    /// 1023, shifted into the exponent field.
    fn pow2_of_rounded(self) -> Self;
    /// The unbiased exponent `e` (as an f64) and the significand `m` in `[1, 2)` of positive
    /// normal lanes, `x = m·2ᵉ`.
    fn exponent_significand(self) -> (Self, Self);
}

/// The constant whose addition rounds an f64 below 2⁵¹ in magnitude to an integer (ties to
/// even), leaving that integer in the low bits of the sum.
pub const ROUND_MAGIC: f64 = 6755399441055744.0;

/// An f64's exponent field, its significand field, and 1.0's bits.
const EXP_FIELD: u64 = 0x7ff;
const SIGNIFICAND: u64 = 0x000f_ffff_ffff_ffff;
const ONE_BITS: u64 = 0x3ff0_0000_0000_0000;
/// 2⁵²'s bits: a small integer or'ed into them reads back as `2⁵² + n`.
const TWO52_BITS: u64 = 0x4330_0000_0000_0000;

/// The portable vector: an array, each operation a loop the compiler may vectorise.
#[derive(Clone, Copy, Debug)]
pub struct Arr<T, const N: usize>(pub [T; N]);

/// [`Arr`]'s mask.
#[derive(Clone, Copy, Debug)]
pub struct ArrMask<const N: usize>(pub [bool; N]);

impl<const N: usize> BitAnd for ArrMask<N> {
    type Output = Self;
    #[inline(always)]
    fn bitand(self, o: Self) -> Self {
        ArrMask(std::array::from_fn(|l| self.0[l] & o.0[l]))
    }
}
impl<const N: usize> BitOr for ArrMask<N> {
    type Output = Self;
    #[inline(always)]
    fn bitor(self, o: Self) -> Self {
        ArrMask(std::array::from_fn(|l| self.0[l] | o.0[l]))
    }
}
impl<const N: usize> Not for ArrMask<N> {
    type Output = Self;
    #[inline(always)]
    fn not(self) -> Self {
        ArrMask(self.0.map(|b| !b))
    }
}
impl<const N: usize> Mask for ArrMask<N> {
    #[inline(always)]
    fn splat(b: bool) -> Self {
        ArrMask([b; N])
    }
    #[inline(always)]
    fn any(self) -> bool {
        self.0.iter().any(|&b| b)
    }
    #[inline(always)]
    fn all(self) -> bool {
        self.0.iter().all(|&b| b)
    }
}

macro_rules! arr_op {
    ($tr:ident, $f:ident, $op:tt) => {
        impl<T: Real, const N: usize> $tr for Arr<T, N> {
            type Output = Self;
            #[inline(always)]
            fn $f(self, o: Self) -> Self {
                Arr(std::array::from_fn(|l| self.0[l] $op o.0[l]))
            }
        }
    };
}
arr_op!(Add, add, +);
arr_op!(Sub, sub, -);
arr_op!(Mul, mul, *);
arr_op!(Div, div, /);

impl<T: Real, const N: usize> Neg for Arr<T, N> {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        Arr(self.0.map(|x| -x))
    }
}

impl<T: Real, const N: usize> Vector for Arr<T, N> {
    type Scalar = T;
    type Mask = ArrMask<N>;
    const LANES: usize = N;
    #[inline(always)]
    fn splat(x: T) -> Self {
        Arr([x; N])
    }
    #[inline(always)]
    fn load(x: &[T]) -> Self {
        Arr(std::array::from_fn(|l| x[l]))
    }
    #[inline(always)]
    fn store(self, out: &mut [T]) {
        out[..N].copy_from_slice(&self.0);
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        Arr(self.0.map(T::sqrt))
    }
    #[inline(always)]
    fn abs(self) -> Self {
        Arr(self.0.map(T::abs))
    }
    #[inline(always)]
    fn signum(self) -> Self {
        Arr(self.0.map(T::signum))
    }
    #[inline(always)]
    fn lt(self, o: Self) -> ArrMask<N> {
        ArrMask(std::array::from_fn(|l| self.0[l] < o.0[l]))
    }
    #[inline(always)]
    fn le(self, o: Self) -> ArrMask<N> {
        ArrMask(std::array::from_fn(|l| self.0[l] <= o.0[l]))
    }
    #[inline(always)]
    fn eq(self, o: Self) -> ArrMask<N> {
        ArrMask(std::array::from_fn(|l| self.0[l] == o.0[l]))
    }
    #[inline(always)]
    fn select(m: ArrMask<N>, a: Self, b: Self) -> Self {
        Arr(std::array::from_fn(
            |l| if m.0[l] { a.0[l] } else { b.0[l] },
        ))
    }
    #[inline(always)]
    fn from_fn(f: impl FnMut(usize) -> T) -> Self {
        Arr(std::array::from_fn(f))
    }
}

impl<const N: usize> F64Bits for Arr<f64, N> {
    #[inline(always)]
    fn pow2_of_rounded(self) -> Self {
        Arr(self
            .0
            .map(|t| f64::from_bits(t.to_bits().wrapping_add(1023) << 52)))
    }
    #[inline(always)]
    fn exponent_significand(self) -> (Self, Self) {
        let e = self.0.map(|x| {
            let field = (x.to_bits() >> 52) & EXP_FIELD;
            (f64::from_bits(field | TWO52_BITS) - f64::from_bits(TWO52_BITS)) - 1023.0
        });
        let m = self
            .0
            .map(|x| f64::from_bits((x.to_bits() & SIGNIFICAND) | ONE_BITS));
        (Arr(e), Arr(m))
    }
}

#[cfg(target_arch = "x86_64")]
pub(crate) use avx::{F32x8, F64x4};

/// AVX registers (see the module docs for where they may run).
#[cfg(target_arch = "x86_64")]
mod avx {
    use super::{Mask, Vector};
    use std::arch::x86_64::*;
    use std::ops::{Add, BitAnd, BitOr, Div, Mul, Neg, Not, Sub};

    /// `impl $tr for $t` by the two-register intrinsic `$intr` (its `unsafe`: as below, the
    /// intrinsic needs AVX, which the functions these types run in have).
    macro_rules! avx_op {
        ($t:ident, $tr:ident, $f:ident, $intr:ident) => {
            impl $tr for $t {
                type Output = Self;
                #[inline(always)]
                fn $f(self, o: Self) -> Self {
                    $t(unsafe { $intr(self.0, o.0) })
                }
            }
        };
    }

    macro_rules! avx_vector {
        ($v:ident, $m:ident, $reg:ty, $t:ty, $n:expr, $sfx:ident,
         $set1:ident, $loadu:ident, $storeu:ident, $add:ident, $sub:ident, $mul:ident,
         $div:ident, $sqrt:ident, $and:ident, $andnot:ident, $or:ident, $xor:ident,
         $cmp:ident, $blendv:ident, $movemask:ident, $full:expr, $setr:ident) => {
            /// Four f64 or eight f32 lanes in one AVX register.
            #[derive(Clone, Copy, Debug)]
            pub struct $v($reg);

            /// Its mask: all bits of a lane set where it holds.
            #[derive(Clone, Copy, Debug)]
            pub struct $m($reg);

            // SAFETY (every `unsafe` below): the intrinsics need AVX, which the functions these
            // types run in are compiled for and called only after detecting (module docs).
            avx_op!($m, BitAnd, bitand, $and);
            avx_op!($m, BitOr, bitor, $or);
            impl Not for $m {
                type Output = Self;
                #[inline(always)]
                fn not(self) -> Self {
                    $m(unsafe { $xor(self.0, $cmp::<_CMP_EQ_UQ>(self.0, self.0)) })
                }
            }
            impl Mask for $m {
                #[inline(always)]
                fn splat(b: bool) -> Self {
                    let z = unsafe { $set1(0.0) };
                    $m(if b {
                        unsafe { $cmp::<_CMP_EQ_OQ>(z, z) }
                    } else {
                        z
                    })
                }
                #[inline(always)]
                fn any(self) -> bool {
                    unsafe { $movemask(self.0) != 0 }
                }
                #[inline(always)]
                fn all(self) -> bool {
                    unsafe { $movemask(self.0) == $full }
                }
            }
            avx_op!($v, Add, add, $add);
            avx_op!($v, Sub, sub, $sub);
            avx_op!($v, Mul, mul, $mul);
            avx_op!($v, Div, div, $div);
            impl Neg for $v {
                type Output = Self;
                /// Flips the sign bit, as Rust's `-x` does.
                #[inline(always)]
                fn neg(self) -> Self {
                    $v(unsafe { $xor(self.0, $set1(-0.0)) })
                }
            }
            impl Vector for $v {
                type Scalar = $t;
                type Mask = $m;
                const LANES: usize = $n;
                #[inline(always)]
                fn splat(x: $t) -> Self {
                    $v(unsafe { $set1(x) })
                }
                #[inline(always)]
                fn load(x: &[$t]) -> Self {
                    assert!(x.len() >= $n);
                    $v(unsafe { $loadu(x.as_ptr()) })
                }
                #[inline(always)]
                fn store(self, out: &mut [$t]) {
                    assert!(out.len() >= $n);
                    unsafe { $storeu(out.as_mut_ptr(), self.0) }
                }
                #[inline(always)]
                fn sqrt(self) -> Self {
                    $v(unsafe { $sqrt(self.0) })
                }
                /// Clears the sign bit, as `abs` does.
                #[inline(always)]
                fn abs(self) -> Self {
                    $v(unsafe { $andnot($set1(-0.0), self.0) })
                }
                #[inline(always)]
                fn signum(self) -> Self {
                    // ±1 with x's sign bit; NaN stays NaN (x ≠ x only there).
                    let one = unsafe { $or($and(self.0, $set1(-0.0)), $set1(1.0)) };
                    let nan = unsafe { $cmp::<_CMP_UNORD_Q>(self.0, self.0) };
                    $v(unsafe { $blendv(one, self.0, nan) })
                }
                #[inline(always)]
                fn lt(self, o: Self) -> $m {
                    $m(unsafe { $cmp::<_CMP_LT_OQ>(self.0, o.0) })
                }
                #[inline(always)]
                fn le(self, o: Self) -> $m {
                    $m(unsafe { $cmp::<_CMP_LE_OQ>(self.0, o.0) })
                }
                #[inline(always)]
                fn eq(self, o: Self) -> $m {
                    $m(unsafe { $cmp::<_CMP_EQ_OQ>(self.0, o.0) })
                }
                #[inline(always)]
                fn select(m: $m, a: Self, b: Self) -> Self {
                    $v(unsafe { $blendv(b.0, a.0, m.0) })
                }
                #[inline(always)]
                fn from_fn(f: impl FnMut(usize) -> $t) -> Self {
                    $v($setr(f))
                }
            }
        };
    }

    /// The lanes `f(0), f(1), …` inserted into a register, not stored and reloaded: a 256-bit
    /// load from narrower stores cannot be forwarded and stalls.
    #[inline(always)]
    fn setr_pd(mut f: impl FnMut(usize) -> f64) -> __m256d {
        let (a, b, c, d) = (f(0), f(1), f(2), f(3));
        // SAFETY: AVX, as for every operation of the type (module docs).
        unsafe { _mm256_setr_pd(a, b, c, d) }
    }
    #[inline(always)]
    fn setr_ps(f: impl FnMut(usize) -> f32) -> __m256 {
        let v: [f32; 8] = std::array::from_fn(f);
        // SAFETY: as above.
        unsafe { _mm256_setr_ps(v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7]) }
    }

    avx_vector!(
        F64x4,
        M64x4,
        __m256d,
        f64,
        4,
        pd,
        _mm256_set1_pd,
        _mm256_loadu_pd,
        _mm256_storeu_pd,
        _mm256_add_pd,
        _mm256_sub_pd,
        _mm256_mul_pd,
        _mm256_div_pd,
        _mm256_sqrt_pd,
        _mm256_and_pd,
        _mm256_andnot_pd,
        _mm256_or_pd,
        _mm256_xor_pd,
        _mm256_cmp_pd,
        _mm256_blendv_pd,
        _mm256_movemask_pd,
        0xF,
        setr_pd
    );
    impl super::F64Bits for F64x4 {
        // SAFETY (both): AVX2's integer intrinsics, in functions compiled for AVX2 (above).
        #[inline(always)]
        fn pow2_of_rounded(self) -> Self {
            unsafe {
                let b = _mm256_add_epi64(_mm256_castpd_si256(self.0), _mm256_set1_epi64x(1023));
                F64x4(_mm256_castsi256_pd(_mm256_slli_epi64::<52>(b)))
            }
        }
        #[inline(always)]
        fn exponent_significand(self) -> (Self, Self) {
            use super::{EXP_FIELD, ONE_BITS, SIGNIFICAND, TWO52_BITS};
            unsafe {
                let b = _mm256_castpd_si256(self.0);
                let two52 = _mm256_set1_epi64x(TWO52_BITS as i64);
                let field = _mm256_and_si256(
                    _mm256_srli_epi64::<52>(b),
                    _mm256_set1_epi64x(EXP_FIELD as i64),
                );
                let biased = _mm256_sub_pd(
                    _mm256_castsi256_pd(_mm256_or_si256(field, two52)),
                    _mm256_castsi256_pd(two52),
                );
                let e = _mm256_sub_pd(biased, _mm256_set1_pd(1023.0));
                let m = _mm256_or_si256(
                    _mm256_and_si256(b, _mm256_set1_epi64x(SIGNIFICAND as i64)),
                    _mm256_set1_epi64x(ONE_BITS as i64),
                );
                (F64x4(e), F64x4(_mm256_castsi256_pd(m)))
            }
        }
    }

    avx_vector!(
        F32x8,
        M32x8,
        __m256,
        f32,
        8,
        ps,
        _mm256_set1_ps,
        _mm256_loadu_ps,
        _mm256_storeu_ps,
        _mm256_add_ps,
        _mm256_sub_ps,
        _mm256_mul_ps,
        _mm256_div_ps,
        _mm256_sqrt_ps,
        _mm256_and_ps,
        _mm256_andnot_ps,
        _mm256_or_ps,
        _mm256_xor_ps,
        _mm256_cmp_ps,
        _mm256_blendv_ps,
        _mm256_movemask_ps,
        0xFF,
        setr_ps
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every operation of the trait on `x` and `y`, masks turned into values by `select`.
    #[inline(always)]
    fn ops<V: Vector>(x: V, y: V) -> [V; 12] {
        let (one, zero) = (V::splat(V::Scalar::ONE), V::splat(V::Scalar::ZERO));
        let m = |k: V::Mask| V::select(k, one, zero);
        let any = if (x.lt(y) | y.eq(x)).any() { one } else { zero };
        let all = if (!x.le(y) & x.eq(x)).all() {
            one
        } else {
            zero
        };
        [
            x + y,
            x - y,
            x * y,
            x / y,
            -x,
            x.abs().sqrt(),
            x.signum(),
            m(x.lt(y)),
            m(x.le(y)),
            m(x.eq(y)),
            V::select(x.lt(y) & !y.eq(zero), x, y),
            any + all + m(<V::Mask as Mask>::splat(true)),
        ]
    }

    fn values<T: Real>(k: usize, from: fn(f64) -> T) -> Vec<T> {
        let special = [
            0.0,
            -0.0,
            1.0,
            -1.0,
            1e-300,
            -3.5,
            2.0,
            f64::INFINITY,
            f64::NAN,
            7e-40,
        ];
        (0..k)
            .map(|i| from(special[(i * 7 + k) % special.len()] * (1.0 + i as f64 * 0.37)))
            .collect()
    }

    fn same_bits<T: Real + std::fmt::Debug>(a: &[T], b: &[T], bits: fn(T) -> u64) {
        for (x, y) in a.iter().zip(b) {
            assert_eq!(bits(*x), bits(*y), "{a:?} against {b:?}");
        }
    }

    /// The AVX registers give the arrays' bits for every operation, on signed zeros,
    /// subnormals, infinities and NaN (whose comparisons are false).
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx_registers_equal_the_portable_arrays() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        #[target_feature(enable = "avx2")]
        fn avx64(x: &[f64], y: &[f64]) -> Vec<f64> {
            let mut out = vec![0.0; 48];
            for (k, r) in ops(F64x4::load(x), F64x4::load(y)).into_iter().enumerate() {
                r.store(&mut out[4 * k..]);
            }
            out
        }
        #[target_feature(enable = "avx2")]
        fn avx32(x: &[f32], y: &[f32]) -> Vec<f32> {
            let mut out = vec![0.0; 96];
            for (k, r) in ops(F32x8::load(x), F32x8::load(y)).into_iter().enumerate() {
                r.store(&mut out[8 * k..]);
            }
            out
        }
        for k in 4..40 {
            let (x, y) = (values(k, |v| v), values(k + 3, |v| v));
            let (x, y) = (&x[k - 4..k], &y[k - 1..k + 3]);
            let arr: Vec<f64> = ops(Arr::<f64, 4>::load(x), Arr::load(y))
                .iter()
                .flat_map(|r| r.0)
                .collect();
            // SAFETY: the CPU has AVX2 (checked above).
            same_bits(&unsafe { avx64(x, y) }, &arr, f64::to_bits);
            let (x, y) = (values(k + 4, |v| v as f32), values(k + 7, |v| v as f32));
            let (x, y) = (&x[k - 4..k + 4], &y[k - 1..k + 7]);
            let arr: Vec<f32> = ops(Arr::<f32, 8>::load(x), Arr::load(y))
                .iter()
                .flat_map(|r| r.0)
                .collect();
            same_bits(&unsafe { avx32(x, y) }, &arr, |v| v.to_bits().into());
        }
    }
}
