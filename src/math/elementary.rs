//! `ln` and `exp` of f64, written once over [`F64Bits`] lanes, so that the return mapping can
//! take four particles to an AVX register (`math::return_map::lanes`) and a scalar caller gets
//! the same bits from the same code on one lane.
//!
//! The algorithms are fdlibm's (Sun Microsystems, 1993; as in musl before 2018): for `ln`,
//! `x = m·2ᵉ` with `m` in `[√2/2, √2)`, `f = m − 1`, `s = f/(2 + f)` and
//! `ln(1 + f) = f − f²/2 + s·(f²/2 + R(s²))` with a degree-14 minimax `R`; for `exp`,
//! `x = k·ln 2 + r` with `|r| ≤ ln 2/2` (ln 2 in two parts, so `r` is exact) and
//! `exp r = 1 + r + r·c/(2 − c)` with a degree-10 minimax `c`, then `2ᵏ` put in by the exponent
//! bits. fdlibm gives both as within one unit in the last place of the true value; here
//! `agree_with_std_within_an_ulp` measures them within one of the standard library's.
//!
//! Why not the standard library's: glibc's `log` and `exp` are scalar calls (40 % of the
//! constitutive stage), and which of glibc's variants runs (FMA or not) depends on the CPU, so
//! their last bit did too. These give the same bits on every x86-64 and in every build.

use crate::math::lanes::{Arr, F64Bits, ROUND_MAGIC};

/// fdlibm's constants, by their bits (the decimal beside each).
const LN2_HI: f64 = f64::from_bits(0x3fe6_2e42_fee0_0000); // 6.93147180369123816490e-01: k·LN2_HI is exact
const LN2_LO: f64 = f64::from_bits(0x3dea_39ef_3579_3c76); // 1.90821492927058770002e-10
const INV_LN2: f64 = std::f64::consts::LOG2_E;

const LG1: f64 = f64::from_bits(0x3fe5_5555_5555_5593); // 6.666666666666735130e-01
const LG2: f64 = f64::from_bits(0x3fd9_9999_9997_fa04); // 3.999999999940941908e-01
const LG3: f64 = f64::from_bits(0x3fd2_4924_9422_9359); // 2.857142874366239149e-01
const LG4: f64 = f64::from_bits(0x3fcc_71c5_1d8e_78af); // 2.222219843214978396e-01
const LG5: f64 = f64::from_bits(0x3fc7_4664_96cb_03de); // 1.818357216161805012e-01
const LG6: f64 = f64::from_bits(0x3fc3_9a09_d078_c69f); // 1.531383769920937332e-01
const LG7: f64 = f64::from_bits(0x3fc2_f112_df3e_5244); // 1.479819860511658591e-01

const P1: f64 = f64::from_bits(0x3fc5_5555_5555_553e); // 1.66666666666666019037e-01
const P2: f64 = f64::from_bits(0xbf66_c16c_16be_bd93); // -2.77777777770155933842e-03
const P3: f64 = f64::from_bits(0x3f11_566a_af25_de2c); // 6.61375632143793436117e-05
const P4: f64 = f64::from_bits(0xbebb_bd41_c5d2_6bf1); // -1.65339022054652515390e-06
const P5: f64 = f64::from_bits(0x3e66_3769_72be_a4d0); // 4.13813679705723846039e-08

/// `exp` overflows above this and underflows to zero below [`EXP_UNDERFLOW`]; the argument is
/// clamped just outside them so that `k` stays small, and the result still rounds to ∞ or 0.
const EXP_CLAMP_HI: f64 = 710.0;
const EXP_UNDERFLOW: f64 = -746.0;

/// The natural logarithm on each lane: `−∞` at ±0, NaN below zero and at NaN, `∞` at `∞`.
#[inline(always)]
pub fn ln_lanes<V: F64Bits>(x: V) -> V {
    let (zero, one, half) = (V::splat(0.0), V::splat(1.0), V::splat(0.5));
    // Subnormals are scaled into the normal range first (2⁵⁴ is exact).
    let tiny = x.lt(V::splat(f64::MIN_POSITIVE));
    let xs = V::select(tiny, x * V::splat(18014398509481984.0), x);
    let (e, m) = xs.exponent_significand();
    let e = V::select(tiny, e - V::splat(54.0), e);
    let big = V::splat(std::f64::consts::SQRT_2).le(m);
    let m = V::select(big, m * half, m);
    let e = V::select(big, e + one, e);
    let f = m - one;
    let hfsq = half * f * f;
    let s = f / (V::splat(2.0) + f);
    let z = s * s;
    let w = z * z;
    let t1 = w * (V::splat(LG2) + w * (V::splat(LG4) + w * V::splat(LG6)));
    let t2 = z * (V::splat(LG1) + w * (V::splat(LG3) + w * (V::splat(LG5) + w * V::splat(LG7))));
    let r = t2 + t1;
    let y = s * (hfsq + r) + e * V::splat(LN2_LO) - hfsq + f + e * V::splat(LN2_HI);
    // The edges: 0 gives −∞, a negative number NaN, ∞ itself; NaN falls through `x ≠ x`.
    let y = V::select(x.eq(zero), V::splat(f64::NEG_INFINITY), y);
    let y = V::select(x.lt(zero), V::splat(f64::NAN), y);
    let y = V::select(x.eq(V::splat(f64::INFINITY)), x, y);
    V::select(x.eq(x), y, x)
}

/// `eˣ` on each lane: ∞ above about 709.78, 0 below about −745.13, NaN at NaN.
#[inline(always)]
pub fn exp_lanes<V: F64Bits>(x: V) -> V {
    let (one, magic) = (V::splat(1.0), V::splat(ROUND_MAGIC));
    let lo_clamp = V::splat(EXP_UNDERFLOW);
    let hi_clamp = V::splat(EXP_CLAMP_HI);
    let xc = V::select(x.lt(lo_clamp), lo_clamp, x);
    let xc = V::select(hi_clamp.lt(xc), hi_clamp, xc);
    // k = round(x/ln 2), ties to even, and r = x − k·ln 2 in two parts.
    let k = (xc * V::splat(INV_LN2) + magic) - magic;
    let hi = xc - k * V::splat(LN2_HI);
    let lo = k * V::splat(LN2_LO);
    let r = hi - lo;
    let rr = r * r;
    let c = r - rr
        * (V::splat(P1)
            + rr * (V::splat(P2) + rr * (V::splat(P3) + rr * (V::splat(P4) + rr * V::splat(P5)))));
    let y = one + (r * c / (V::splat(2.0) - c) - lo + hi);
    // 2ᵏ as two powers within the normal range, so that results near overflow and in the
    // subnormal range are rounded once, by the last product.
    let ka = (k * V::splat(0.5) + magic) - magic;
    let kb = k - ka;
    let y = y * (ka + magic).pow2_of_rounded() * (kb + magic).pow2_of_rounded();
    V::select(x.eq(x), y, x)
}

/// [`ln_lanes`] of one number: the same operations, so the same bits.
#[inline(always)]
pub fn ln(x: f64) -> f64 {
    ln_lanes(Arr([x])).0[0]
}

/// [`exp_lanes`] of one number: the same operations, so the same bits.
#[inline(always)]
pub fn exp(x: f64) -> f64 {
    exp_lanes(Arr([x])).0[0]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The distance in units in the last place between two finite f64 of one sign.
    fn ulps(a: f64, b: f64) -> u64 {
        (a.to_bits() as i64 - b.to_bits() as i64).unsigned_abs()
    }

    /// A deterministic spread of `n` numbers between `lo` and `hi` (a low-discrepancy walk, so
    /// the whole range is covered at every scale of `n`).
    fn spread(lo: f64, hi: f64, n: usize) -> impl Iterator<Item = f64> {
        let golden = 0.618_033_988_749_894_9;
        (0..n).map(move |i| lo + (hi - lo) * ((i as f64 * golden) % 1.0))
    }

    /// Both functions are within one ulp of the standard library's (itself within one ulp of
    /// the true value; the two differ by at most one on almost every argument): over the
    /// strains and stretches the return mapping sees, over their whole ranges, and for `exp`
    /// into the subnormal results, where one rounding at the end keeps them within one ulp.
    #[test]
    fn agree_with_std_within_an_ulp() {
        let mut worst = (0u64, 0u64);
        for x in spread(1e-6, 4.0, 200_000)
            .chain(spread(1.0 - 1e-6, 1.0 + 1e-6, 20_000))
            .chain(spread(-300.0, 300.0, 20_000).map(|e| 10f64.powf(e)))
            .chain([f64::MIN_POSITIVE, 1e-310, 5e-324, f64::MAX])
        {
            let d = ulps(ln(x), x.ln());
            assert!(d <= 1, "ln({x:e}) = {:e} against {:e}", ln(x), x.ln());
            worst.0 = worst.0.max(d);
        }
        for x in spread(-15.0, 3.0, 200_000)
            .chain(spread(-1e-6, 1e-6, 20_000))
            .chain(spread(-745.0, 709.7, 100_000))
        {
            let d = ulps(exp(x), x.exp());
            assert!(d <= 1, "exp({x:e}) = {:e} against {:e}", exp(x), x.exp());
            worst.1 = worst.1.max(d);
        }
        assert_eq!((ln(1.0), exp(0.0)), (0.0, 1.0));
        assert!(ln(1.0).is_sign_positive());
        println!("worst ulps from std: ln {}, exp {}", worst.0, worst.1);
    }

    #[test]
    fn edges_follow_ieee() {
        let inf = f64::INFINITY;
        assert_eq!(ln(0.0), -inf);
        assert_eq!(ln(-0.0), -inf);
        assert_eq!(ln(inf), inf);
        assert!(ln(-1.0).is_nan() && ln(f64::NAN).is_nan() && ln(-inf).is_nan());
        assert_eq!(exp(-inf), 0.0);
        assert_eq!(exp(inf), inf);
        assert_eq!(exp(709.8), inf);
        assert_eq!(exp(-745.2), 0.0);
        assert!(exp(f64::NAN).is_nan());
        assert_eq!(exp(-745.0), 5e-324);
        assert_eq!(exp(709.78), 709.78f64.exp());
    }

    /// AVX registers give the portable lanes' bits, including the edges.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx_registers_equal_the_portable_lanes() {
        use crate::math::lanes::{F64x4, Vector};
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        #[target_feature(enable = "avx2")]
        fn both(x: &[f64; 4]) -> [f64; 8] {
            let mut out = [0.0; 8];
            ln_lanes(F64x4::load(x)).store(&mut out[..4]);
            exp_lanes(F64x4::load(x)).store(&mut out[4..]);
            out
        }
        let edges = [0.0, -0.0, 1.0, -1.0, 5e-324, f64::INFINITY, f64::NAN, 1e300];
        let xs: Vec<f64> = spread(-800.0, 800.0, 4_000)
            .chain(spread(1e-7, 3.0, 4_000))
            .chain(edges)
            .collect();
        for x in xs.chunks_exact(4) {
            let x: [f64; 4] = x.try_into().unwrap();
            // SAFETY: the CPU has AVX2 (checked above).
            let avx = unsafe { both(&x) };
            let (l, e) = (ln_lanes(Arr(x)).0, exp_lanes(Arr(x)).0);
            for (a, b) in avx.iter().zip(l.iter().chain(&e)) {
                assert_eq!(a.to_bits(), b.to_bits(), "{x:?}");
            }
        }
    }
}
