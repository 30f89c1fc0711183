//! Elementary functions in pure f32 for the device path: sin/cos for the kernel table, and base-2 powers
//! and logarithms for the log-encoded fields of the wire format.
//!
//! Why not `libm`'s `sinf`/`cosf`/`log2f`/`exp2f`: they are ports of musl, which evaluates in f64 — on a
//! Cortex-M4F (single-precision FPU) every call becomes soft-float `__muldf3`/`__adddf3` routines, in
//! flash and on the hot path, and the device path must not use f64. What the map needs is little: sin/cos
//! of a bounded argument to 1e-6, powers 2^(n/s) at integer n for a few step counts s (a table and an
//! exponent), the smallest such power ≥ x (the same table, so "≥" holds exactly), and a log₂ accurate
//! to ~1e-6. All plain f32 arithmetic, so host and device compute bit-identical results.

/// sin and cos of `x` (|x| ≤ 8π) in f32 arithmetic only: reduction to [−π/4, π/4] and Taylor
/// polynomials, error < 1e-6.
pub fn sin_cos(x: f32) -> (f32, f32) {
    use core::f32::consts::FRAC_PI_2;
    // Cody–Waite reduction: π/2 = HI + LO with HI exact in 10 bits, so q · HI is exact for |q| < 2¹⁴ and
    // the reduced argument keeps its precision.
    const HI: f32 = 1.570_312_5;
    const LO: f32 = 4.838_268e-4;
    let q = libm::floorf(x * (1.0 / FRAC_PI_2) + 0.5);
    let r = (x - q * HI) - q * LO;
    let r2 = r * r;
    let s = r * (1.0 + r2 * (-1.0 / 6.0 + r2 * (1.0 / 120.0 + r2 * (-1.0 / 5040.0))));
    let c = 1.0 + r2 * (-0.5 + r2 * (1.0 / 24.0 + r2 * (-1.0 / 720.0 + r2 * (1.0 / 40320.0))));
    match (q as i32) & 3 {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// 2^(k/16) for k = 0..16, correctly rounded to f32. Coarser steps (8, 4, 2 per octave) use every
/// second, fourth, eighth entry.
const POW2_SIXTEENTHS: [f32; 17] = [
    f32::from_bits(0x3F800000), // 2^(0/16) = 1.0000000
    f32::from_bits(0x3F85AAC3), // 2^(1/16) = 1.0442737
    f32::from_bits(0x3F8B95C2), // 2^(2/16) = 1.0905077
    f32::from_bits(0x3F91C3D3), // 2^(3/16) = 1.1387886
    f32::from_bits(0x3F9837F0), // 2^(4/16) = 1.1892071
    f32::from_bits(0x3F9EF532), // 2^(5/16) = 1.2418578
    f32::from_bits(0x3FA5FED7), // 2^(6/16) = 1.2968396
    f32::from_bits(0x3FAD583F), // 2^(7/16) = 1.3542556
    f32::from_bits(0x3FB504F3), // 2^(8/16) = 1.4142135
    f32::from_bits(0x3FBD08A4), // 2^(9/16) = 1.4768262
    f32::from_bits(0x3FC5672A), // 2^(10/16) = 1.5422108
    f32::from_bits(0x3FCE248C), // 2^(11/16) = 1.6104903
    f32::from_bits(0x3FD744FD), // 2^(12/16) = 1.6817929
    f32::from_bits(0x3FE0CCDF), // 2^(13/16) = 1.7562522
    f32::from_bits(0x3FEAC0C7), // 2^(14/16) = 1.8340081
    f32::from_bits(0x3FF5257D), // 2^(15/16) = 1.9152066
    f32::from_bits(0x40000000), // 2^(16/16) = 2.0000000
];

/// Steps per octave a table lookup supports: 1, 2, 4, 8 or 16.
pub const fn steps_supported(steps: u32) -> bool {
    matches!(steps, 1 | 2 | 4 | 8 | 16)
}

/// 2^e for an integer exponent, saturating to 0 below the normal range and to +∞ above it.
fn pow2_int(e: i32) -> f32 {
    if e < -126 {
        0.0
    } else if e > 127 {
        f32::INFINITY
    } else {
        f32::from_bits(((e + 127) as u32) << 23)
    }
}

/// 2^(n / steps) for an integer n; `steps` ∈ {1, 2, 4, 8, 16} (others give NaN).
pub fn pow2_steps(n: i32, steps: u32) -> f32 {
    if !steps_supported(steps) {
        return f32::NAN;
    }
    let s = steps as i32;
    let (whole, frac) = (n.div_euclid(s), n.rem_euclid(s));
    // Always within the table (frac < s, s divides 16); `get`, so no panic path is linked.
    let Some(&m) = POW2_SIXTEENTHS.get((frac * (16 / s)) as usize) else {
        return f32::NAN;
    };
    // Split the scaling so that 2^whole itself never leaves the normal range for representable results.
    if whole < -126 {
        m * pow2_int(whole + 64) * pow2_int(-64)
    } else {
        m * pow2_int(whole)
    }
}

/// The smallest integer n with 2^(n / steps) ≥ x, for finite x > 0; `steps` ∈ {1, 2, 4, 8, 16}.
/// Exact with respect to [`pow2_steps`]: `pow2_steps(n, steps) ≥ x > pow2_steps(n − 1, steps)`.
pub fn log2_steps_up(x: f32, steps: u32) -> i32 {
    let bits = x.to_bits();
    // Normalise subnormals so the exponent field is meaningful.
    let (bits, bias) = if bits >> 23 == 0 {
        ((x * pow2_int(64)).to_bits(), 64)
    } else {
        (bits, 0)
    };
    let e = (bits >> 23) as i32 - 127 - bias;
    let m = f32::from_bits((bits & 0x007F_FFFF) | 0x3F80_0000); // in [1, 2)
    let s = steps as i32;
    let step = (16 / s.max(1)) as usize;
    let mut k = 0;
    while k < s && POW2_SIXTEENTHS[k as usize * step] < m {
        k += 1;
    }
    e * s + k
}

/// log₂ x for finite x > 0: absolute error below 1e-6 plus the f32 rounding of the result (non-positive x
/// gives −∞, like log₂ 0).
pub fn log2(x: f32) -> f32 {
    if !(x > 0.0) {
        return f32::NEG_INFINITY;
    }
    let bits = x.to_bits();
    let (bits, bias) = if bits >> 23 == 0 {
        ((x * pow2_int(64)).to_bits(), 64.0)
    } else {
        (bits, 0.0)
    };
    let e = ((bits >> 23) as i32 - 127) as f32 - bias;
    log2_parts(e, f32::from_bits((bits & 0x007F_FFFF) | 0x3F80_0000))
}

/// log₂(2^e · m) for a mantissa m in [1, 2): the one polynomial behind [`log2`] and [`log2_normal`].
#[inline(always)]
fn log2_parts(e: f32, m: f32) -> f32 {
    // Centre the mantissa on 1: m in [√½, √2). Written as selects, so loops over it vectorise.
    let big = m > core::f32::consts::SQRT_2;
    let m = if big { m * 0.5 } else { m };
    let e = if big { e + 1.0 } else { e };
    // log₂ m = 2/ln 2 · atanh(t), t = (m − 1)/(m + 1) ∈ [−0.172, 0.172]: the odd series to t⁹ leaves an
    // error below 2·10⁻⁸ (t¹¹/11 · 2/ln 2).
    let t = (m - 1.0) / (m + 1.0);
    let t2 = t * t;
    let series = 1.0 + t2 * (1.0 / 3.0 + t2 * (1.0 / 5.0 + t2 * (1.0 / 7.0 + t2 * (1.0 / 9.0))));
    e + 2.0 * core::f32::consts::LOG2_E * t * series
}

// Branch-free variants for loops that must vectorise (the host's uncertainty sampler,
// [`crate::sampling`]): no edge cases handled, so each is a straight line of f32 operations.

/// log₂ x for positive normal x, branch-free ([`log2`] without its checks): error below 3e-7
/// absolute plus the f32 rounding of the result.
#[inline(always)]
pub(crate) fn log2_normal(x: f32) -> f32 {
    let bits = x.to_bits();
    let e = ((bits >> 23) as i32 - 127) as f32;
    log2_parts(e, f32::from_bits((bits & 0x007F_FFFF) | 0x3F80_0000))
}

/// 2^y for −126 < y < 127, branch-free (vectorises): relative error below 3e-7.
#[inline(always)]
pub(crate) fn exp2(y: f32) -> f32 {
    // Round to the nearest integer by adding 1.5·2²³ (no float → int conversion, which would not
    // vectorise with Rust's saturating semantics): the integer sits in the low mantissa bits.
    const MAGIC: f32 = 12_582_912.0;
    let r = y + MAGIC;
    let i = r.to_bits().wrapping_sub(MAGIC.to_bits()) as i32;
    let x = (y - (r - MAGIC)) * core::f32::consts::LN_2; // |x| ≤ ½ ln 2
                                                         // e^x, |x| ≤ 0.347: Taylor to x⁶ leaves < 2e-8.
    let p = 1.0
        + x * (1.0
            + x * (0.5
                + x * (1.0 / 6.0 + x * (1.0 / 24.0 + x * (1.0 / 120.0 + x * (1.0 / 720.0))))));
    p * f32::from_bits((i.wrapping_add(127) as u32) << 23)
}

/// √x for finite x ≥ 0, branch-free (vectorises, unlike `libm::sqrtf`'s scalar instruction): the
/// bit-trick reciprocal square root and three Newton steps (relative error < 2e-7), times x.
#[inline(always)]
pub(crate) fn sqrt(x: f32) -> f32 {
    let mut y = f32::from_bits(0x5F37_59DF_u32.wrapping_sub(x.to_bits() >> 1));
    let h = 0.5 * x;
    y *= 1.5 - h * y * y;
    y *= 1.5 - h * y * y;
    y *= 1.5 - h * y * y;
    x * y
}

/// (sin πx, cos πx) for |x| < 1, branch-free (vectorises): the half angle h = πx/2 by Taylor series
/// (to h¹¹ and h¹², error below 6e-8), then the double-angle formulas.
#[inline(always)]
pub(crate) fn sin_cos_pi(x: f32) -> (f32, f32) {
    let h = x * core::f32::consts::FRAC_PI_2;
    let h2 = h * h;
    let s = h
        * (1.0
            + h2 * (-1.0 / 6.0
                + h2 * (1.0 / 120.0
                    + h2 * (-1.0 / 5040.0 + h2 * (1.0 / 362_880.0 + h2 * (-1.0 / 39_916_800.0))))));
    let c = 1.0
        + h2 * (-0.5
            + h2 * (1.0 / 24.0
                + h2 * (-1.0 / 720.0
                    + h2 * (1.0 / 40_320.0
                        + h2 * (-1.0 / 3_628_800.0 + h2 * (1.0 / 479_001_600.0))))));
    (2.0 * s * c, c * c - s * s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sin_cos_is_accurate() {
        let mut worst = 0.0f64;
        for i in -100_000..=100_000 {
            let x = i as f32 * (8.0 * core::f32::consts::PI / 100_000.0);
            let (s, c) = sin_cos(x);
            let x = f64::from(x);
            worst = worst
                .max((f64::from(s) - libm::sin(x)).abs())
                .max((f64::from(c) - libm::cos(x)).abs());
        }
        assert!(worst < 1e-6, "worst |error| {worst:e}");
    }

    #[test]
    fn table_is_two_to_the_sixteenths() {
        for (k, v) in POW2_SIXTEENTHS.iter().enumerate() {
            assert_eq!(*v, libm::exp2(k as f64 / 16.0) as f32, "k = {k}");
        }
    }

    #[test]
    fn powers_match_exp2() {
        for steps in [1, 2, 4, 8, 16] {
            for n in -2200..2100 {
                let want = libm::exp2(f64::from(n) / f64::from(steps));
                let got = pow2_steps(n, steps);
                if want < f64::from(f32::MIN_POSITIVE) || want > f64::from(f32::MAX) {
                    continue; // outside the normal range: saturated, checked below
                }
                assert!(
                    ((f64::from(got) - want) / want).abs() < 1.2e-7,
                    "2^({n}/{steps})"
                );
            }
        }
        assert_eq!(pow2_steps(-1300, 8), 0.0);
        assert_eq!(pow2_steps(1100, 8), f32::INFINITY);
        assert!(pow2_steps(3, 3).is_nan());
    }

    #[test]
    fn smallest_power_above_is_exact() {
        let mut x = 0x2468_ACE1u32;
        for _ in 0..200_000 {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            let v = f32::from_bits(x & 0x7FFF_FFFF);
            if !(1e-36..=1e37).contains(&v) {
                continue;
            }
            for steps in [2, 8, 16] {
                let n = log2_steps_up(v, steps);
                assert!(pow2_steps(n, steps) >= v, "{v:e} steps {steps}: n = {n}");
                assert!(
                    pow2_steps(n - 1, steps) < v,
                    "{v:e} steps {steps}: n − 1 = {}",
                    n - 1
                );
            }
        }
        // Exact powers map to themselves.
        assert_eq!(log2_steps_up(1.0, 8), 0);
        assert_eq!(log2_steps_up(2.0, 8), 8);
        assert_eq!(log2_steps_up(pow2_steps(-13, 8), 8), -13);
    }

    #[test]
    fn log2_is_accurate() {
        let mut worst = 0.0f64;
        let mut x = 0x1357_9BDFu32;
        for _ in 0..200_000 {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            let v = f32::from_bits(x & 0x7FFF_FFFF);
            if !(v.is_finite() && v > 0.0) {
                continue;
            }
            let exact = libm::log2(f64::from(v));
            // Below 1e-6 plus the rounding of the f32 result itself (half an ulp of |log₂ x| ≤ 128).
            let err = (f64::from(log2(v)) - exact).abs() - 6e-8 * exact.abs();
            worst = worst.max(err);
        }
        assert!(worst < 1e-6, "worst |error| {worst:e}");
        assert_eq!(log2(8.0), 3.0);
        assert_eq!(log2(0.0), f32::NEG_INFINITY);
        assert_eq!(log2(-1.0), f32::NEG_INFINITY);
    }

    #[test]
    fn branch_free_variants_are_accurate() {
        let mut worst = [0.0f64; 3];
        for i in 1..200_000 {
            let x = i as f32 / 200_000.0; // (0, 1): the polar method's W, Box–Muller's u
            let l = log2_normal(x) as f64;
            // Absolute error plus the f32 rounding of the result.
            worst[0] = worst[0].max((l - (x as f64).log2()).abs() / (1.0 + l.abs()));
            let y = i as f32 * (46.0 / 200_000.0);
            let e = exp2(y) as f64;
            worst[1] = worst[1].max((e / 2f64.powf(y as f64) - 1.0).abs());
            let z = x * 1e4 * (i as f32);
            let r = sqrt(z) as f64;
            worst[2] = worst[2].max((r / (z as f64).sqrt() - 1.0).abs());
        }
        assert!(
            worst[0] < 5e-7 && worst[1] < 5e-7 && worst[2] < 5e-7,
            "{worst:?}"
        );
        assert_eq!(sqrt(0.0), 0.0);
        let mut trig = 0.0f64;
        for i in -100_000..100_000 {
            let x = i as f32 / 100_000.0;
            let (s, c) = sin_cos_pi(x);
            let a = core::f64::consts::PI * x as f64;
            trig = trig
                .max((s as f64 - libm::sin(a)).abs())
                .max((c as f64 - libm::cos(a)).abs());
        }
        assert!(trig < 5e-7, "sin/cos error {trig:e}");
    }
}
