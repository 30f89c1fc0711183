//! Cooling int8 sums into a voxel's compact codes in fixed point: no float arithmetic, for an MCU without
//! an FPU (thumbv6m, riscv32imac), where the f32 cooling runs in software float.
//!
//! Why: a hot voxel fed int8 codes holds exact integer sums ([`CodeSums`]); when it cools, those sums are
//! merged (Chan's formula) into the statistics its [`QuantVoxel`] codes stand for and re-encoded. In f32
//! that is ≈ 16 float operations per dimension: ≈ 70,000 instructions per cooling on riscv32imac and
//! ≈ 130,000 on thumbv6m, in library calls. Here the same merge runs in integers, in units of the int8
//! scale s (a code step): means as i32 with [`MEAN_FRAC`] fraction bits (|m| ≤ 160 steps), scatters as u64
//! on a per-voxel power-of-two unit; only the final codes go through the f32 bit layout (built from
//! integers), so they mean exactly what [`QuantVoxel::decode`] reads. The codes equal the f32 path's to
//! the rounding of the last code step (tests: within 1.3 mean steps and 25 % of scatter on 400 merges;
//! 600 coolings of one voxel walk no farther than the f32 path's).
//!
//! **Not yet wired into the local map**, because every target must cool the same way (the QEMU boards'
//! UART streams are compared with one host twin) and, measured with `boards/measure.sh` with it wired in
//! (`cool` calling it for int8 sums): riscv32imac i8 3,413 → 1,838 instructions per point (goal 2,000
//! met), thumbv6m 5,136 → 4,145 (its divisions and 64-bit multiplies are library calls there), but the
//! Cortex-M4F's i8 row 1,004 → 1,390 (its FPU does the f32 cooling cheaper) and flash +5.7 KB on every
//! target (riscv32imac 62,758 → 71,122 B, over the 64 KiB goal). Before it is wired: 32-bit scatter
//! terms on a per-voxel block exponent (no u64 products or shifts), reciprocals instead of two divisions
//! per dimension, loops kept rolled.

use super::{psi_key, Dither, QuantVoxel, MU_BITS, MU_QMAX, PSI_CODE_MAX, PSI_SHIFT};
use crate::obs::{scatter_numerator, CodeSums};
use half::f16;

/// Fraction bits of a mean in code steps (|m| ≤ 160 steps → < 2²².)
const MEAN_FRAC: i32 = 14;

/// A positive number as m · 2^e with m in [2²³, 2²⁴) (an f32's mantissa and exponent), or zero (m = 0).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Parts {
    m: u32,
    e: i32,
}

impl Parts {
    const ZERO: Self = Self { m: 0, e: 0 };

    /// From an f32's bits (zero, subnormal, negative and non-finite values give zero).
    fn of_bits(bits: u32) -> Self {
        let biased = (bits >> 23) as i32;
        if bits >> 31 != 0 || biased == 0 || biased == 255 {
            return Self::ZERO;
        }
        Self {
            m: (bits & 0x7F_FFFF) | 0x80_0000,
            e: biased - 150,
        }
    }
}

/// `p · 2^sh`, rounded to nearest when shifting right, saturating at 2⁶² when shifting left.
#[inline]
fn shift(p: u64, sh: i32) -> u64 {
    if p == 0 {
        0
    } else if sh >= 0 {
        if sh >= 62 || p.leading_zeros() < 2 + sh as u32 {
            1 << 62
        } else {
            p << sh
        }
    } else {
        let r = (-sh) as u32;
        if r >= 64 {
            0
        } else {
            (p >> (r - 1)).div_ceil(2)
        }
    }
}

/// The f32 bit pattern of `v · 2^e` (v > 0), mantissa truncated; 0 if it underflows, f32::MAX if too big.
#[inline]
fn f32_bits(v: u64, e: i32) -> u32 {
    if v == 0 {
        return 0;
    }
    let lz = v.leading_zeros() as i32;
    // v = mant · 2^(40 − lz) with mant in [2²³, 2²⁴).
    let mant = ((v << lz) >> 40) as u32;
    let biased = e + (40 - lz) + 150;
    if biased <= 0 {
        0
    } else if biased >= 255 {
        f32::MAX.to_bits()
    } else {
        ((biased as u32) << 23) | (mant & 0x7F_FFFF)
    }
}

/// An f32 that holds a whole number (a voxel's point count) as an integer, without a float operation.
#[inline]
fn count_of(bits: u32) -> u32 {
    let p = Parts::of_bits(bits);
    shift(u64::from(p.m), p.e).min(u64::from(u32::MAX)) as u32
}

/// The int8 scale s in the integer forms the fixed-point cooling needs (prepared in float once, when the
/// scale is set — not per point).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Int8Fix {
    s: Parts,
    inv_s: Parts,
    s2: Parts,
    inv_s2: Parts,
}

impl Int8Fix {
    /// No scale (cooling int8 sums gives empty codes; the map refuses int8 points then).
    pub const NONE: Self = Self {
        s: Parts::ZERO,
        inv_s: Parts::ZERO,
        s2: Parts::ZERO,
        inv_s2: Parts::ZERO,
    };

    /// The forms of a valid scale (finite, > 0).
    pub fn new(scale: f32) -> Self {
        let s2 = scale * scale;
        Self {
            s: Parts::of_bits(scale.to_bits()),
            inv_s: Parts::of_bits((1.0 / scale).to_bits()),
            s2: Parts::of_bits(s2.to_bits()),
            inv_s2: Parts::of_bits((1.0 / s2).to_bits()),
        }
    }

    /// An f16 mean scale σ in code steps, with [`MEAN_FRAC`] fraction bits.
    fn steps_of(&self, sigma: f16) -> i32 {
        let h = sigma.to_bits();
        let (e16, f) = (i32::from((h >> 10) & 0x1F), u64::from(h & 0x3FF));
        let (m, e) = match e16 {
            0 => (f, -24),              // subnormal (or zero)
            31 => return i32::MAX / 64, // never made by the encoder
            _ => (f | 0x400, e16 - 25),
        };
        let v = shift(m * u64::from(self.inv_s.m), e + self.inv_s.e + MEAN_FRAC);
        v.min(i32::MAX as u64 / 64) as i32
    }
}

impl<const D: usize, const P: usize> QuantVoxel<D, P> {
    /// These codes merged with int8 sums of scale `fix` (Chan's formula) and re-encoded, in integers: what
    /// [`Self::reencode`] of the decoded codes merged with [`CodeSums::to_obs`] gives, to the rounding of the
    /// last code step. Keeps the mean's scale when it still fits, as [`Self::reencode`] does.
    ///
    /// Three passes over the dimensions: the merged means (and the distance between the two means), the
    /// merged scatters (as the f32 bit patterns of their values), then the codes with the dither stream
    /// `reencode` uses. Every product fits its width by the bounds of int8 codes (|Σc| ≤ 255·127).
    #[inline(never)]
    pub fn merge_codes_fixed(
        &self,
        sums: &CodeSums<D>,
        fix: &Int8Fix,
        dither: &mut Dither,
    ) -> Self {
        let n1 = sums.count;
        if n1 == 0 || fix.s.m == 0 {
            return *self;
        }
        let n0 = count_of(self.count.to_bits());
        let n = n0.saturating_add(n1).min(1 << 30);
        let (mu_part, psi_part) = self.codes.split_at(super::section_len(D, MU_BITS));
        let mut mu = [0u8; D];
        let mut psi = [0u8; D];
        super::unpack(mu_part, MU_BITS, &mut mu);
        super::unpack(psi_part, super::PSI_BITS, &mut psi);
        let sigma = if n0 > 0 {
            fix.steps_of(self.mu_scale)
        } else {
            0
        };

        // ---- pass 1, means in code steps (MEAN_FRAC fraction bits): with x = Σc − n₁m₀, the merged mean
        // is m₀ + x/n and the new points' mean is m₀ + x/n₁ (d = x/n₁). Divisions by reciprocals (2³²/n).
        let recip = |k: u32| -> i64 { ((1u64 << 32) / u64::from(k.max(1))) as i64 };
        let (rn, rn1) = (recip(n), recip(n1));
        let mut mean = [0i32; D];
        let mut diff = [0i32; D];
        let mut max_abs = 0u32;
        for (((m, dd), &q), &sum) in mean.iter_mut().zip(&mut diff).zip(&mu).zip(&sums.sum) {
            let q = (i32::from(q) << (32 - MU_BITS)) >> (32 - MU_BITS);
            let m0 = q.wrapping_mul(sigma);
            let x = i64::from((sum << MEAN_FRAC).wrapping_sub((n1 as i32).wrapping_mul(m0)));
            *m = m0.wrapping_add(((x * rn + (1 << 31)) >> 32) as i32);
            *dd = ((x * rn1 + (1 << 31)) >> 32) as i32;
            max_abs = max_abs.max(m.unsigned_abs());
        }

        // ---- the mean's scale: kept while it fits (as `reencode`), else max|m|·1.25/q_max rounded up in f16.
        let max_abs = max_abs.min(1 << 24) as i32;
        let qmax = MU_QMAX;
        let keep = sigma > 0
            && max_abs <= sigma.saturating_mul(qmax)
            && max_abs.saturating_mul(4) >= sigma.saturating_mul(qmax);
        let (mu_scale, sigma) = if keep {
            (self.mu_scale, sigma)
        } else if max_abs == 0 {
            (f16::ZERO, 0)
        } else {
            // max·1.25/63 · s, with 1.25/63 ≈ 332,881 · 2⁻²⁴.
            let v = max_abs as u64 * 332_881;
            let lz = v.leading_zeros() as i32;
            let top = (v << lz) >> 32; // v ≈ top · 2^(32 − lz)
            let bits = f32_bits(top * u64::from(fix.s.m), 32 - lz - 24 - MEAN_FRAC + fix.s.e);
            let mut s = f16::from_f32(f32::from_bits(bits));
            let mut sig = fix.steps_of(s);
            if sig.saturating_mul(qmax) < max_abs {
                s = f16::from_bits(s.to_bits() + 1);
                sig = fix.steps_of(s);
            }
            (s, sig)
        };

        // ---- pass 2, scatters in units of c²·2^g, g chosen so that n·127²·1.25 < 2³¹; each ends as the
        // f32 bit pattern of its value (what the minifloat codes are cut from).
        let g = (32 - n.leading_zeros() as i32) - 16;
        let w = ((u64::from(n0) * u64::from(n1)) << 8) / u64::from(n); // n₀n₁/n, 8 fraction bits
        let r1 = (1u64 << 32) / u64::from(n1); // 2³²/n₁
        let old_shift = fix.inv_s2.e - 129 - g; // minifloat 2^(E−129)·(4+f) → units, with 1/s²
        let base_old = u32::from(self.psi_base);
        let mut scatter = [0u32; D];
        let mut psi_max_bits = 0u32;
        for ((((b, &c), &d), &sum), &sq) in scatter
            .iter_mut()
            .zip(&psi)
            .zip(&diff)
            .zip(&sums.sum)
            .zip(&sums.squares)
        {
            let k = u32::from(c) + base_old; // the old scatter's minifloat: exponent k/4, mantissa 1 + (k%4)/4
            let old = if n0 == 0 || k < 4 {
                0
            } else {
                let v = u64::from(4 + (k & 3)) * u64::from(fix.inv_s2.m);
                let sh = (k >> 2) as i32 + old_shift;
                if sh >= 0 {
                    v << sh.min(8)
                } else if sh > -64 {
                    v >> -sh
                } else {
                    0
                }
            };
            let within = (u64::from(scatter_numerator(n1, sum, sq)) * r1) >> (32 + g);
            let d2 = u64::from(d.unsigned_abs()).pow(2);
            let between = (d2 * w) >> (36 + g); // d: 14 fraction bits, squared 28, w 8
            let total = (old + within + between).min(u64::from(u32::MAX)) as u32;
            // total · 2^g · s² as f32 bits: normalise, one 32×24-bit product, renormalise by one bit.
            *b = if total == 0 {
                0
            } else {
                let lz = total.leading_zeros() as i32;
                let p = u64::from(total << lz) * u64::from(fix.s2.m); // in [2⁵⁴, 2⁵⁶)
                let hi = (p >> 55) as i32; // 1 if the product reached 2⁵⁵
                let mant = (p >> (31 + hi)) as u32;
                let biased = 150 + 31 + hi + g - lz + fix.s2.e;
                if biased <= 0 {
                    0
                } else if biased >= 255 {
                    f32::MAX.to_bits()
                } else {
                    ((biased as u32) << 23) | (mant & 0x7F_FFFF)
                }
            };
            psi_max_bits = psi_max_bits.max(*b);
        }
        let top = (psi_max_bits.min(f32::MAX.to_bits()) >> PSI_SHIFT) + 1;
        let psi_base = top.saturating_sub(PSI_CODE_MAX) as u16;

        // ---- pass 3, codes, with the dither stream `reencode` uses (bytes 0, 1: μ, Ψ of a dimension; 2, 3:
        // the next). μ: m/σ by a reciprocal (2⁴⁰/σ) to 1/256 of a step, plus a dither below one step, floored.
        let r_sigma = if sigma > 0 {
            ((1i64 << 40) + i64::from(sigma / 2)) / i64::from(sigma)
        } else {
            0
        };
        let base = psi_base as i32;
        let mu_code = |m: i32, dither: u32| -> u8 {
            let u = ((i64::from(m).wrapping_mul(r_sigma) + (1 << 31)) >> 32) as i32;
            let q = (u + (dither & 0xFF) as i32) >> 8;
            q.clamp(-MU_QMAX - 1, MU_QMAX) as u8 & ((1 << MU_BITS) - 1) as u8
        };
        let psi_code = |bits: u32, dither: u32| -> u8 {
            (psi_key(f32::from_bits(bits), dither as u8) as i32 - base)
                .clamp(0, PSI_CODE_MAX as i32) as u8
        };
        for (((m, b), mc), pc) in mean
            .chunks_exact(2)
            .zip(scatter.chunks_exact(2))
            .zip(mu.chunks_exact_mut(2))
            .zip(psi.chunks_exact_mut(2))
        {
            let d = dither.next();
            mc[0] = mu_code(m[0], d);
            pc[0] = psi_code(b[0], d >> 8);
            mc[1] = mu_code(m[1], d >> 16);
            pc[1] = psi_code(b[1], d >> 24);
        }
        if D % 2 == 1 {
            let d = dither.next();
            if let (Some(mc), Some(pc), Some(&m), Some(&b)) =
                (mu.last_mut(), psi.last_mut(), mean.last(), scatter.last())
            {
                *mc = mu_code(m, d);
                *pc = psi_code(b, d >> 8);
            }
        }
        let mut codes = [0u8; P];
        let (mu_out, psi_out) = codes.split_at_mut(super::section_len(D, MU_BITS));
        super::pack(&mu, MU_BITS, mu_out);
        super::pack(&psi, super::PSI_BITS, psi_out);
        Self {
            count: f32::from_bits(f32_bits(u64::from(n), 0)),
            mu_scale,
            psi_base,
            codes,
        }
    }
}

#[cfg(test)]
mod tests;
