//! A branch-free `exp` that the compiler can inline and vectorise.
//!
//! The world step evaluates two exponentials per edge of the risk graph (the virtual distance and
//! the social-force repulsion). `f64::exp` is an out-of-line libm call (with its errno wrapper),
//! which also stops the loops around it from being vectorised. [`exp`] is plain arithmetic:
//!
//! * range reduction `x = k ln2 + r`, `|r| <= ln2 / 2`, with `k` the nearest integer to
//!   `x / ln2` (found with the `1.5 * 2^52` shifter, no rounding call) and `ln2` split into a
//!   21-bit-exact high part and a low part (Cody–Waite), so `r` is exact to within an ulp;
//! * `exp(r)` by its Taylor polynomial to degree 13 (truncation error below `4e-18` relative),
//!   evaluated as `1 + (r + r^2 q(r))` so that the rounding error stays near half an ulp, with
//!   `q` by Estrin's scheme (short dependency chains);
//! * scaling by `2^k` as two exact power-of-two factors `2^(k/2)`, `2^(k - k/2)`, so results in
//!   the subnormal range are rounded once and large `k` never builds an invalid exponent.
//!
//! Accuracy (checked by the tests below against `f64::exp` over `[-745, 710]` and on special
//! values): at most 2 ulp for normal results, typically exact or 1 ulp; subnormal results
//! (`x < -708.4`) are within 2 ulp of the subnormal spacing. `exp(x)` is `+inf` for
//! `x > 709.78`, `+0` for `x < -745.14`, `exp(+inf) = +inf`, `exp(-inf) = 0`, and NaN only for a
//! NaN input: a finite argument never gives NaN. The result is a pure function of `x` (no
//! table, no state, no FMA), so it is bit-identical across runs and threads.

use std::f64::consts::LOG2_E;

/// `1.5 * 2^52`: adding it to `|t| < 2^51` rounds `t` to the nearest integer (ties to even) and
/// leaves that integer in the low mantissa bits.
const SHIFTER: f64 = 6_755_399_441_055_744.0;
/// High part of `ln 2` with its low 32 bits zero (fdlibm's `ln2_hi`): `k * LN2_HI` is exact for
/// `|k| < 2^20`.
const LN2_HI: f64 = 0.693_147_180_369_123_8; // 0x3FE62E42FEE00000
/// `ln 2 - LN2_HI`.
const LN2_LO: f64 = 1.908_214_929_270_587_7e-10; // 0x3DEA39EF35793C76
/// Below this every result rounds to zero; clamping keeps `k` small.
const X_MIN: f64 = -746.0;
/// Above this every result overflows to infinity.
const X_MAX: f64 = 710.0;

/// `1/k!` for `k = 2..=13`.
const C: [f64; 12] = [
    1.0 / 2.0,
    1.0 / 6.0,
    1.0 / 24.0,
    1.0 / 120.0,
    1.0 / 720.0,
    1.0 / 5_040.0,
    1.0 / 40_320.0,
    1.0 / 362_880.0,
    1.0 / 3_628_800.0,
    1.0 / 39_916_800.0,
    1.0 / 479_001_600.0,
    1.0 / 6_227_020_800.0,
];

/// `2^n` for `-1022 <= n <= 1023`, built from its exponent bits.
#[inline(always)]
fn pow2i(n: i64) -> f64 {
    f64::from_bits(((n + 1023) as u64) << 52)
}

/// `e^x`, branch-free (see the module documentation for its accuracy).
#[inline(always)]
pub fn exp(x: f64) -> f64 {
    // Comparisons rather than `max`/`min`, so that a NaN input stays NaN.
    let xc = if x < X_MIN { X_MIN } else { x };
    let xc = if xc > X_MAX { X_MAX } else { xc };
    let kd = xc * LOG2_E + SHIFTER;
    let k = kd - SHIFTER;
    let ki = (kd.to_bits() as i64).wrapping_sub(SHIFTER.to_bits() as i64);
    let r = (xc - k * LN2_HI) - k * LN2_LO;
    // q(r) = sum_k C[k] r^k by Estrin's scheme: a dependency chain of 8 operations instead of
    // Horner's 24, so consecutive edges overlap in the pipeline.
    let r2 = r * r;
    let r4 = r2 * r2;
    let r8 = r4 * r4;
    let p01 = C[0] + C[1] * r;
    let p23 = C[2] + C[3] * r;
    let p45 = C[4] + C[5] * r;
    let p67 = C[6] + C[7] * r;
    let p89 = C[8] + C[9] * r;
    let p1011 = C[10] + C[11] * r;
    let q03 = p01 + p23 * r2;
    let q47 = p45 + p67 * r2;
    let q811 = p89 + p1011 * r2;
    let q = (q03 + q47 * r4) + q811 * r8;
    let p = 1.0 + (r + r2 * q);
    // |ki| <= 1077 here, so both halves are valid normal exponents.
    let k1 = ki >> 1;
    let k2 = ki - k1;
    p * pow2i(k1) * pow2i(k2)
}

#[cfg(test)]
mod tests {
    use super::exp;

    /// Distance in units in the last place between two finite non-negative doubles.
    fn ulps(a: f64, b: f64) -> u64 {
        assert!(a >= 0.0 && b >= 0.0, "{a} {b}");
        a.to_bits().abs_diff(b.to_bits())
    }

    /// A small deterministic generator (xorshift64*).
    struct Rng(u64);
    impl Rng {
        fn next_f64(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    #[test]
    fn matches_libm_within_two_ulp_over_the_whole_range() {
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
        let mut worst = 0;
        for (lo, hi, n) in [
            (-745.2, 710.0, 2_000_000),
            (-40.0, 40.0, 2_000_000),
            (-1.0, 1.0, 1_000_000),
            (-1e-6, 1e-6, 200_000),
            (-708.5, -700.0, 200_000),
            (700.0, 709.8, 200_000),
        ] {
            for _ in 0..n {
                let x = lo + (hi - lo) * rng.next_f64();
                let (got, want) = (exp(x), x.exp());
                let d = ulps(got, want);
                assert!(d <= 2, "exp({x:e}) = {got:e}, libm {want:e}, {d} ulp");
                worst = worst.max(d);
            }
        }
        assert!(worst <= 2);
    }

    #[test]
    fn reduction_constants_are_the_fdlibm_bits() {
        assert_eq!(super::LN2_HI.to_bits(), 0x3FE6_2E42_FEE0_0000);
        assert_eq!(super::LN2_LO.to_bits(), 0x3DEA_39EF_3579_3C76);
    }

    #[test]
    fn integers_and_exact_points() {
        assert_eq!(exp(0.0), 1.0);
        assert_eq!(exp(-0.0), 1.0);
        for k in -745..=709 {
            let x = k as f64;
            assert!(ulps(exp(x), x.exp()) <= 2, "exp({x})");
        }
    }

    #[test]
    fn special_values_and_extremes() {
        assert_eq!(exp(f64::INFINITY), f64::INFINITY);
        assert_eq!(exp(f64::NEG_INFINITY), 0.0);
        assert!(exp(f64::NAN).is_nan());
        assert_eq!(exp(709.79), f64::INFINITY);
        assert_eq!(exp(710.0), f64::INFINITY);
        assert_eq!(exp(1e300), f64::INFINITY);
        assert_eq!(exp(f64::MAX), f64::INFINITY);
        assert_eq!(exp(-745.2), 0.0);
        assert_eq!(exp(-1e300), 0.0);
        assert_eq!(exp(f64::MIN), 0.0);
        assert!(exp(709.78).is_finite());
        assert!(exp(-745.1) > 0.0);
        assert_eq!(exp(f64::MIN_POSITIVE), 1.0);
        assert_eq!(exp(-f64::MIN_POSITIVE), 1.0);
    }

    #[test]
    fn never_nan_for_finite_input() {
        let mut rng = Rng(12345);
        for _ in 0..1_000_000 {
            // Random bit patterns cover every exponent, huge and tiny.
            let bits = (rng.next_f64() * u64::MAX as f64) as u64;
            let x = f64::from_bits(bits);
            if x.is_finite() {
                let y = exp(x);
                assert!(!y.is_nan() && y >= 0.0, "exp({x:e}) = {y}");
            }
        }
    }
}
