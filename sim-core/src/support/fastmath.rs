//! A branch-free `exp` that the compiler can inline and vectorise, and an inlinable `atan2`.
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
//!
//! [`atan2`] is fdlibm's `e_atan2.c`/`s_atan.c` (argument reduction to `|x| < 7/16` about
//! `atan(1/2)`, `atan(1)`, `atan(3/2)` or `pi/2`, and a degree-22 odd polynomial): error below
//! 1 ulp, the same quadrant and special-value rules as `f64::atan2`. Every simulated
//! pedestrian's heading is an `atan2` of its velocity each step; libm's costs ~280
//! instructions with its wrapper (7 % of a whole step of a 4-agent scene), this one ~60, and
//! unlike libm's it gives the same bits on every platform.

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

#[allow(clippy::excessive_precision)] // fdlibm's published digits
const ATAN_HI: [f64; 4] = [
    4.636_476_090_008_060_935_15e-01, // atan(0.5) hi
    std::f64::consts::FRAC_PI_4,      // atan(1.0) hi
    9.827_937_232_473_290_540_82e-01, // atan(1.5) hi
    std::f64::consts::FRAC_PI_2,      // atan(inf) hi
];
#[allow(clippy::excessive_precision)]
const ATAN_LO: [f64; 4] = [
    2.269_877_745_296_168_709_24e-17,
    3.061_616_997_868_383_017_93e-17,
    1.390_331_103_123_099_845_16e-17,
    6.123_233_995_736_766_035_87e-17,
];
#[allow(clippy::excessive_precision)]
const AT: [f64; 11] = [
    3.333_333_333_333_293_180_27e-01,
    -1.999_999_999_987_648_324_76e-01,
    1.428_571_427_250_346_637_11e-01,
    -1.111_111_040_546_235_578_80e-01,
    9.090_887_133_436_506_561_96e-02,
    -7.691_876_205_044_829_994_95e-02,
    6.661_073_137_387_531_206_69e-02,
    -5.833_570_133_790_573_486_45e-02,
    4.976_877_994_615_932_360_17e-02,
    -3.653_157_274_421_691_552_70e-02,
    1.628_582_011_536_578_236_23e-02,
];
const PI: f64 = std::f64::consts::PI;
#[allow(clippy::excessive_precision)]
const PI_LO: f64 = 1.224_646_799_147_353_177_2e-16;
const PI_O_2: f64 = std::f64::consts::FRAC_PI_2;
const PI_O_4: f64 = std::f64::consts::FRAC_PI_4;

/// High 32 bits of `x`.
#[inline(always)]
fn high_word(x: f64) -> u32 {
    (x.to_bits() >> 32) as u32
}

/// `atan(x)` (fdlibm `s_atan.c`), error below 1 ulp.
#[inline]
pub fn atan(x: f64) -> f64 {
    let hx = high_word(x);
    let ix = hx & 0x7fff_ffff;
    let negative = hx >> 31 != 0;
    if ix >= 0x4410_0000 {
        // |x| >= 2^66, or NaN.
        if x.is_nan() {
            return x + x;
        }
        let z = ATAN_HI[3] + ATAN_LO[3];
        return if negative { -z } else { z };
    }
    let (id, x) = if ix < 0x3fdc_0000 {
        // |x| < 7/16
        if ix < 0x3e40_0000 {
            // |x| < 2^-27: atan(x) rounds to x.
            return x;
        }
        (None, x)
    } else {
        let x = x.abs();
        if ix < 0x3ff3_0000 {
            // |x| < 19/16
            if ix < 0x3fe6_0000 {
                (Some(0), (2.0 * x - 1.0) / (2.0 + x))
            } else {
                (Some(1), (x - 1.0) / (x + 1.0))
            }
        } else if ix < 0x4003_8000 {
            // |x| < 39/16
            (Some(2), (x - 1.5) / (1.0 + 1.5 * x))
        } else {
            (Some(3), -1.0 / x)
        }
    };
    let z = x * x;
    let w = z * z;
    // Odd and even halves of the polynomial, interleaved.
    let s1 = z * (AT[0] + w * (AT[2] + w * (AT[4] + w * (AT[6] + w * (AT[8] + w * AT[10])))));
    let s2 = w * (AT[1] + w * (AT[3] + w * (AT[5] + w * (AT[7] + w * AT[9]))));
    match id {
        None => x - x * (s1 + s2),
        Some(id) => {
            let z = ATAN_HI[id] - ((x * (s1 + s2) - ATAN_LO[id]) - x);
            if negative {
                -z
            } else {
                z
            }
        }
    }
}

/// `atan2(y, x)` (fdlibm `e_atan2.c`): the angle of `(x, y)` in `[-pi, pi]`, error below 1 ulp,
/// with `f64::atan2`'s rules for zeros, infinities and NaN.
#[inline]
pub fn atan2(y: f64, x: f64) -> f64 {
    if x.is_nan() || y.is_nan() {
        return x + y;
    }
    if x == 1.0 {
        return atan(y);
    }
    // 2 * sign(x) + sign(y)
    let m = (usize::from(x.is_sign_negative()) << 1) | usize::from(y.is_sign_negative());
    if y == 0.0 {
        return match m {
            0 | 1 => y,
            2 => PI,
            _ => -PI,
        };
    }
    if x == 0.0 {
        return if y < 0.0 { -PI_O_2 } else { PI_O_2 };
    }
    if x.is_infinite() {
        return if y.is_infinite() {
            [PI_O_4, -PI_O_4, 3.0 * PI_O_4, -3.0 * PI_O_4][m]
        } else {
            [0.0, -0.0, PI, -PI][m]
        };
    }
    if y.is_infinite() {
        return if y < 0.0 { -PI_O_2 } else { PI_O_2 };
    }
    // Exponent difference of |y| and |x|.
    let k = ((high_word(y) & 0x7ff0_0000) as i32 - (high_word(x) & 0x7ff0_0000) as i32) >> 20;
    let z = if k > 60 {
        // |y / x| > 2^60
        PI_O_2 + 0.5 * PI_LO
    } else if x < 0.0 && k < -60 {
        // |y| / x < -2^-60
        0.0
    } else {
        atan((y / x).abs())
    };
    match m {
        0 => z,
        1 => -z,
        2 => PI - (z - PI_LO),
        _ => (z - PI_LO) - PI,
    }
}

#[cfg(test)]
mod atan_tests {
    use super::{atan, atan2};

    fn ulps(a: f64, b: f64) -> u64 {
        if a == b {
            return 0;
        }
        assert_eq!(a.is_sign_negative(), b.is_sign_negative(), "{a} {b}");
        a.to_bits().abs_diff(b.to_bits())
    }

    struct Rng(u64);
    impl Rng {
        fn next_u64(&mut self) -> u64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
        }
        fn next_f64(&mut self) -> f64 {
            (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    #[test]
    fn atan2_matches_libm_within_one_ulp() {
        let mut rng = Rng(0x2545_F491_4F6C_DD1D);
        for scale in [1e-300, 1e-9, 1e-3, 1.0, 2.0, 10.0, 1e6, 1e300] {
            for _ in 0..100_000 {
                let y = (2.0 * rng.next_f64() - 1.0) * scale;
                let x = (2.0 * rng.next_f64() - 1.0) * scale;
                let (got, want) = (atan2(y, x), y.atan2(x));
                assert!(
                    ulps(got, want) <= 1,
                    "atan2({y:e}, {x:e}) = {got:e}, libm {want:e}"
                );
            }
        }
        // Velocities as the simulator has them: every direction, speeds up to 6 m/s, and
        // mixed magnitudes (one component tiny).
        for _ in 0..300_000 {
            let (a, r) = (rng.next_f64() * std::f64::consts::TAU, 6.0 * rng.next_f64());
            let (y, x) = (r * a.sin(), r * a.cos());
            assert!(ulps(atan2(y, x), y.atan2(x)) <= 1, "atan2({y:e}, {x:e})");
            let t = rng.next_f64() * 1e-20;
            assert!(ulps(atan2(t, x), t.atan2(x)) <= 1, "atan2({t:e}, {x:e})");
            assert!(ulps(atan2(y, t), y.atan2(t)) <= 1, "atan2({y:e}, {t:e})");
        }
    }

    #[test]
    fn atan2_of_random_bit_patterns_agrees_with_libm() {
        let mut rng = Rng(7);
        for _ in 0..1_000_000 {
            let (y, x) = (
                f64::from_bits(rng.next_u64()),
                f64::from_bits(rng.next_u64()),
            );
            let (got, want) = (atan2(y, x), y.atan2(x));
            if want.is_nan() {
                assert!(got.is_nan(), "atan2({y:e}, {x:e}) = {got}");
            } else {
                assert!(
                    ulps(got, want) <= 1,
                    "atan2({y:e}, {x:e}) = {got:e}, libm {want:e}"
                );
            }
        }
    }

    #[test]
    fn atan2_special_values_as_libm() {
        let vals = [
            0.0,
            -0.0,
            1.0,
            -1.0,
            0.5,
            f64::MIN_POSITIVE,
            -f64::MIN_POSITIVE,
            5e-324,
            f64::MAX,
            -f64::MAX,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ];
        for &y in &vals {
            for &x in &vals {
                let (got, want) = (atan2(y, x), y.atan2(x));
                if y == 0.0 || x == 0.0 || y.is_infinite() || x.is_infinite() {
                    // The exact cases: signed zeros, multiples of pi/4.
                    assert_eq!(got.to_bits(), want.to_bits(), "atan2({y:e}, {x:e})");
                } else {
                    assert!(
                        ulps(got, want) <= 1,
                        "atan2({y:e}, {x:e}) = {got:e}, {want:e}"
                    );
                }
            }
            assert!(atan2(y, f64::NAN).is_nan() && atan2(f64::NAN, y).is_nan());
        }
    }

    #[test]
    fn constants_are_the_fdlibm_bits() {
        assert_eq!(super::ATAN_HI[1].to_bits(), 0x3FE9_21FB_5444_2D18);
        assert_eq!(super::ATAN_HI[3].to_bits(), 0x3FF9_21FB_5444_2D18);
        assert_eq!(super::ATAN_LO[3].to_bits(), 0x3C91_A626_3314_5C07);
        assert_eq!(super::PI.to_bits(), std::f64::consts::PI.to_bits());
        assert_eq!(super::PI_LO.to_bits(), 0x3CA1_A626_3314_5C07);
        assert_eq!(
            super::PI_O_2.to_bits(),
            std::f64::consts::FRAC_PI_2.to_bits()
        );
    }

    #[test]
    fn atan_matches_libm() {
        let mut rng = Rng(99);
        for _ in 0..500_000 {
            let x = f64::from_bits(rng.next_u64());
            let (got, want) = (atan(x), x.atan());
            if want.is_nan() {
                assert!(got.is_nan());
            } else {
                assert!(ulps(got, want) <= 1, "atan({x:e}) = {got:e}, libm {want:e}");
            }
        }
    }
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
