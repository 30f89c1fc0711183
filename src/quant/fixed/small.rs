//! The coolings the sparse path does not take, for a voxel of at most [`SMALL_MAX_OLD`] points: above all
//! an 8×8 ToF's voxel of one point revisited (n₀ = 1), also a first visit of several points (n₀ = 0) and a
//! young voxel whose mean scale must change or that gets more than a few points; in 32-bit arithmetic.
//!
//! Why its own path: with x = n₀m₀ + Σc (n times the merged mean) and y = Σc − n₁m₀, Chan's merge is
//! m = x/n and S = S₀ + (num·n + n₀y²)/(n₁n), num = n₁Σc² − (Σc)² exact in integers (for n₀ = n₁ = 1:
//! S = y²/2). The general merge forms 64-bit products from 16-bit halves and converts every scatter to an
//! f32 bit pattern through per-voxel units: on the self-test's ToF (thumbv6m) ≈ 34,500 instructions a
//! cooling of a one-point voxel, ≈ 22,000 of a larger one; this path runs those 2,119 coolings (1,428 of
//! them n₀ = 1) in 14,855 each, ≈ 232 a dimension (`PROFILE_SCENARIO=tof_f3_i8 bash
//! boards/measure-targets.sh --profile thumbv6m`: 31.5 M instructions). Here x and y per dimension are
//! two 32-bit products (m₀ = q·σ₀ with σ₀ to 2^−(f+5) steps, f ≤ 20 fraction bits, fewer for many
//! points so that nothing leaves an i32); per cooling one shift for each that brings its largest below
//! 2¹⁵, so the mean code is one 16 × 16-bit product by a 16-bit 1/(nσ) and n₀y² one 15 × 15-bit product;
//! the old scatters from a table of the 32 keys, in the same units; each scatter's f32 bits from a 16-bit
//! mantissa times the per-cooling constant s²/(n₁n) (as the general merge's last step). The mean scale
//! follows the general merge's rules (kept while it fits, else fresh) compared at σ₀'s precision, the
//! codes use the same dither stream conventions (bytes 0, 1 of each dimension's 16 bits: μ, Ψ).
//!
//! Four cuts, each giving the same codes bit for bit (tests: `the_fused_small_merge_is_the_unfused_one`;
//! the QEMU boards' UART streams unchanged): a voxel of at most one point merged with one (no old scatter,
//! no numerator) computes its scatters n₀y'² in the codes' pass, their largest from y's extremes, instead
//! of a pass of their own; leading zeros there from a byte table; the Ψ code straight from the scatter's
//! normalised product, without its f32 bit pattern; and the merge is written over the slot's codes in
//! place (it was returned by value and copied twice). Same profile: 31.5 M → 28.1 M instructions, 13,284
//! a cooling; `bash boards/measure-targets.sh --table`, instructions a point: thumbv6m ToF 8×8 9,498 →
//! 8,961, scanning LiDAR 8,483 → 8,382, depth frames 1,590 → 1,573; riscv32imac 7,787 → 7,388, 6,952 →
//! 6,850, 1,344 → 1,325.
//!
//! Not bit-exact with the general merge: the mean is rounded to 1/512 of a code before the dither (the
//! general path: 1/256), y to 15 significant bits before squaring (the scatter codes read 2 + 8 of the
//! mantissa), and σ is read to 2⁻²⁴ (the general merge: 2⁻¹⁴ steps, which puts a mean of a tenth of a step
//! up to 1.85 codes off; this path ≤ 1.0 on the same 12,000 merges). Tests hold it to the f32 path with the
//! general merge's bounds (`tests.rs`, `small_voxel_merges_match_the_f32_path`).

use super::super::{
    psi_key, Dither, QuantVoxel, MU_BITS, MU_QMAX, PSI_BITS, PSI_CODE_MAX, PSI_SHIFT,
};
use super::bits::*;
use super::{grid, Int8Fix, MEAN_FRAC};
use crate::obs::{scatter_numerator, CodeSums};
use half::f16;

/// Most new points this path takes: any [`CodeSums`] (its fraction bits f fall with n₁ so that
/// |Σc·2^f| and |n₁m₀·2^f| stay below 2³⁰).
pub(super) const SMALL_MAX_NEW: u32 = crate::obs::CODE_SUMS_MAX_COUNT;

/// Most points a voxel may hold for this path (as n₁: f falls with bits(n₀) so that |n₀m₀·2^f| < 2²⁹).
pub(super) const SMALL_MAX_OLD: u32 = 255;

/// The bits of `v` (0 for 0).
#[inline(always)]
fn bits_of(v: u32) -> i32 {
    32 - lz(v) as i32
}

/// `v` rounded to a multiple of 2^`sh` and divided by it (`sh` < 31).
#[inline(always)]
fn round_shr(v: i32, sh: u32) -> i32 {
    v.wrapping_add((1u32 << sh >> 1) as i32).wrapping_shr(sh)
}

/// Leading zeros of a byte (8 for 0).
const LZ8: [u8; 256] = {
    let mut t = [0u8; 256];
    let mut b = 0;
    while b < 256 {
        t[b] = (b as u8).leading_zeros() as u8;
        b += 1;
    }
    t
};

/// [`top16`] of `v` > 0 by two halving steps and a table of a byte's leading zeros: ≈ 10 instructions
/// against ≈ 26 for the five halving steps of `lz` on v6-M (and RV32 without Zbb), once a dimension in
/// the codes' pass.
#[inline(always)]
pub(super) fn top16_by_table(v: u32) -> (u32, i32) {
    let (mut v, mut z) = (v, 0);
    if v >> 16 == 0 {
        v <<= 16;
        z = 16;
    }
    if v >> 24 == 0 {
        v <<= 8;
        z += 8;
    }
    let k = u32::from(LZ8.get((v >> 24) as usize).copied().unwrap_or(0));
    ((v << k) >> 16, 16 - (z + k) as i32)
}

/// Extra fraction bits of σ₀ beyond a mean's: q·σ₀ (|q| ≤ 64) rounded once, to half a unit.
const SIGMA_EXTRA: u32 = 5;

impl Int8Fix {
    /// An f16 mean scale σ in code steps with f + [`SIGMA_EXTRA`] fraction bits, f the most (≤ 20) that
    /// keep σ·2^f below 2²⁰; to 2⁻²⁴ relative ([`Self::steps_of`] gives 14 bits, to 2⁻²⁰: too coarse for
    /// the distance of a point from a mean it nearly equals, whose square is the scatter here). `None` from
    /// 64 steps up.
    fn steps_fine(&self, sigma: f16) -> Option<(i32, u32)> {
        let h = sigma.to_bits();
        let (e16, m) = (i32::from((h >> 10) & 0x1F), u32::from(h & 0x3FF));
        let (m, e) = match e16 {
            0 => (m, -24),
            31 => return None,
            _ => (m | 0x400, e16 - 25),
        };
        // σ·2^25 from the 11-bit × 24-bit mantissas.
        let down = -(e + self.inv_s.e + 20 + SIGMA_EXTRA as i32);
        if down < 0 {
            return None;
        }
        let v = shr_sat32(mul32(m, self.inv_s.m), down as u32);
        let k = (bits_of(v) - 20 - SIGMA_EXTRA as i32).max(0) as u32;
        (k <= 6).then(|| (round_shr(v as i32, k), 20 - k))
    }
}

impl<const D: usize, const P: usize> QuantVoxel<D, P> {
    /// These codes, of `n0` points, merged with `sums` of scale `fix`, in place (no 104-byte value
    /// returned and copied twice on its way to the slot). False, and nothing changed, when a range would
    /// not fit (a scale of 64 steps or more, more points; nothing consumed from `dither` then).
    #[inline(never)]
    pub(super) fn merge_small_here(
        &mut self,
        sums: &CodeSums<D>,
        fix: &Int8Fix,
        n0: u32,
        fine: bool,
        dither: &mut Dither,
    ) -> bool {
        self.merge_small_in::<true>(sums, fix, n0, fine, dither)
            .is_some()
    }

    /// [`Self::merge_small_here`] as a value (`None`: not taken); `FUSE` false: the scatters always in a
    /// pass of their own, what the tests hold the fused form to, bit for bit.
    #[cfg(test)]
    pub(super) fn merge_small<const FUSE: bool>(
        &self,
        sums: &CodeSums<D>,
        fix: &Int8Fix,
        n0: u32,
        fine: bool,
        dither: &mut Dither,
    ) -> Option<Self> {
        let mut out = *self;
        out.merge_small_in::<FUSE>(sums, fix, n0, fine, dither)?;
        Some(out)
    }

    /// The merge, written over these codes at its end (`None` before anything is written); `FUSE`: a
    /// voxel of at most one point merged with one (no old scatter, no numerator: the scatter is n₀y², its
    /// largest known from y's extremes) computes each scatter where its codes are made, not in a pass of
    /// its own.
    #[inline(always)]
    fn merge_small_in<const FUSE: bool>(
        &mut self,
        sums: &CodeSums<D>,
        fix: &Int8Fix,
        n0: u32,
        fine: bool,
        dither: &mut Dither,
    ) -> Option<()> {
        let n1 = sums.count;
        if n1 == 0 || n1 > SMALL_MAX_NEW || n0 > SMALL_MAX_OLD {
            return None;
        }
        let n = n0 + n1;
        // σ₀·2^f < 2^(20 − e) with e = bits(n₁) − 3 (≥ 0): |n₁·m₀|·2^f < 2²⁹ and |Σc|·2^f ≤ 2³⁰, so y
        // fits an i32 (and |q·σ₀·2^(f+5)| < 2³¹).
        let (sig_fine, f) = fix.steps_fine(self.mu_scale)?;
        let e = (bits_of(n0.max(n1)) - 3).max(0) as u32;
        let (sig_fine, f) = (round_shr(sig_fine, e), f - e);
        let (mut qs, mut ks) = ([0u8; D], [0u8; D]);
        let (mu_in, psi_in) = self.codes.split_at(super::super::section_len(D, MU_BITS));
        unpack_codes::<{ MU_BITS as usize }>(mu_in, &mut qs);
        // The old scatters (0 for a voxel of one point, whatever its codes).
        let scattered = n0 >= 2;
        if scattered {
            unpack_codes::<{ PSI_BITS as usize }>(psi_in, &mut ks);
        }

        // ---- pass 1: x = n·m and y per dimension, in steps with MEAN_FRAC fraction bits; their maxima.
        let (mut max_x, mut max_num) = (0u32, 0u32);
        // y's extremes (with 0): the largest |y|, and where no other term adds to the scatter the largest
        // n₀y'² (y' = y/2^ys rises with y).
        let (mut y_lo, mut y_hi) = (0i32, 0i32);
        let mut xy: [(i32, i32); D] = core::array::from_fn(|i| {
            let q = i32::from((qs.get(i).copied().unwrap_or(0) << 1) as i8 >> 1);
            let c = sums.sum(i) << f;
            let m0 = round_shr(q.wrapping_mul(sig_fine), SIGMA_EXTRA);
            let x = c.wrapping_add((n0 as i32).wrapping_mul(m0));
            let y = c.wrapping_sub((n1 as i32).wrapping_mul(m0));
            max_x = max_x.max(x.unsigned_abs());
            y_lo = y_lo.min(y);
            y_hi = y_hi.max(y);
            if n1 > 1 {
                max_num = max_num.max(scatter_numerator(n1, sums.sum(i), sums.square(i)));
            }
            (x, y)
        });
        let max_y = y_lo.unsigned_abs().max(y_hi.unsigned_abs());

        // ---- the mean's scale, by the general merge's rules (kept while n·max|m| ≤ n·σ₀·q_max and
        // reaches a quarter of it, 1/1.25 on the fine grid), compared at 2^−(f+5) (σ₀ in steps with 14
        // fraction bits is 5 bits wide for a mean of a tenth of a step: the general merge's flaw).
        let (within, headroom) = grid(fine);
        let lhs = u64::from(max_x) << SIGMA_EXTRA;
        let rhs = mul32(n * MU_QMAX as u32, sig_fine as u32);
        let keep = sig_fine > 0 && lhs <= rhs && lhs * within.0 as u64 >= rhs * within.1 as u64;
        let (mu_scale, (sig, fs)) = if keep {
            (self.mu_scale, (sig_fine, f))
        } else {
            let to_mean_frac = 32 + f - MEAN_FRAC as u32;
            let max_abs = shr_sat32(
                mul32(max_x, recip(n)) + (1 << (to_mean_frac - 1)),
                to_mean_frac,
            )
            .min(1 << 24) as i32;
            let (s, _) = fix.fresh_scale(max_abs, headroom);
            (s, fix.steps_fine(s)?)
        };

        // ---- the mean code in 1/256 of a step: x/(nσ)·2⁸ = x'·t / 2^rs with x' = x/2^xs < 2¹⁵ and
        // t = (2³¹ − 1)/(nσ)₁₆ < 2¹⁶ (nσ ≈ (nσ)₁₆ · 2^de, its top 16 bits): a 32-bit product.
        let xs = (bits_of(max_x) - 15).max(0) as u32;
        let (r_ns, rs) = if sig > 0 {
            let (st, se) = top16(sig as u32);
            let (dt, de) = top16(n * st);
            (
                (i32::MAX as u32) / dt.max(1),
                18 + de + se - xs as i32 + f as i32 - fs as i32,
            )
        } else {
            (0, 1)
        };
        if !(1..=31).contains(&rs) {
            return None;
        }
        let rs = rs as u32;

        // ---- the scatter: T = num·n·2^(2f − 2ys) + (y/2^ys)², ys chosen so both terms are < 2³⁰; its value
        // T · 2^(2ys − 2f) · s²/(n₁n). The constant as a 16-bit mantissa k and exponent ke.
        let f = f as i32;
        // num·n with the numerator first cut by 2^r so the product fits: ≤ 2³¹ · 2⁸ from 255 points.
        let r = (bits_of(max_num) + bits_of(n) - 31).max(0);
        // y' = y/2^ys with n₀y'² < 2³⁰.
        let mut ys = if n0 > 0 {
            (bits_of(max_y) - (30 - bits_of(n0)) / 2).max(0)
        } else {
            0
        };
        if n1 > 1 {
            ys = ys.max((bits_of((max_num >> r) * n) + r + 2 * f - 29) / 2);
        }
        // The old scatter of key k (code plus base) times n₁n, in units of 2^(2ys − 2f) steps²: (4 + k mod 4)
        // · 2^(k/4 − 129) / s² · n₁n, the constant 1/s² · n₁n as a 16-bit mantissa c and exponent.
        let (nn, nne) = top16(n1 * n);
        let (c, ce) = top16((fix.inv_s2.m >> 8) * nn);
        let old_exp = ce + nne + 8 + fix.inv_s2.e - 129 + 2 * f;
        let base_old = u32::from(self.psi_base);
        let old_value = |k: u32| ((4 + (k & 3)) * c, (k >> 2) as i32 + old_exp);
        if scattered {
            // The largest old scatter below 2³⁰ too.
            let kmax = base_old + u32::from(ks.iter().copied().max().unwrap_or(0));
            if kmax >= 4 {
                let (p, pe) = old_value(kmax);
                ys = ys.max((bits_of(p) + pe - 29) / 2);
            }
        }
        if ys > 24 {
            return None; // the old scatter dwarfs what a 32-bit y could add: the general merge
        }
        let num_sh = r + 2 * f - 2 * ys; // ≥ −31: f ≥ 9
        let (rnn, re) = top16(recip(n1 * n));
        let (k, ke2) = top16((fix.s2.m >> 8) * rnn);
        let ke = ke2 + 8 + fix.s2.e + re - 32 + 2 * ys - 2 * f;
        let mut old_units = [0u32; 1 << PSI_BITS];
        if scattered {
            for (code, o) in old_units.iter_mut().enumerate() {
                let k = code as u32 + base_old;
                if k >= 4 {
                    let (p, pe) = old_value(k);
                    *o = shift(p, pe - 2 * ys);
                }
            }
        }
        // The scatter in units, n₀y'² + the old scatter's + num·n·2^num_sh.
        let scatter_of = |y: i32| {
            let y = round_shr(y, ys as u32);
            (y.wrapping_mul(y) as u32).wrapping_mul(n0)
        };
        let fused = FUSE && !scattered && n1 == 1;
        let mut max_t = 0u32;
        if fused {
            max_t = scatter_of(y_lo).max(scatter_of(y_hi));
        } else {
            for (i, (_, v)) in xy.iter_mut().enumerate() {
                let old = usize::from(ks.get(i).copied().unwrap_or(0));
                let mut t = scatter_of(*v).wrapping_add(old_units.get(old).copied().unwrap_or(0));
                if n1 > 1 {
                    // num again (two products) rather than kept from pass 1 (an array more on the stack).
                    let num =
                        (scatter_numerator(n1, sums.sum(i), sums.square(i)) >> r).wrapping_mul(n);
                    t = t.wrapping_add(if num_sh >= 0 {
                        num << num_sh
                    } else {
                        num >> -num_sh
                    });
                }
                *v = t as i32;
                max_t = max_t.max(t);
            }
        }
        let bits = |t: u32| -> u32 {
            if t == 0 {
                return 0;
            }
            let (t16, te) = top16_by_table(t);
            let p = t16 * k;
            let hi = (p >> 31) as i32;
            let mant = (p << (1 - hi)) >> 8;
            let biased = 157 + hi + te + ke;
            if biased <= 0 {
                0
            } else if biased >= 255 {
                f32::MAX.to_bits()
            } else {
                ((biased as u32) << 23) | (mant & 0x7F_FFFF)
            }
        };
        let top = (bits(max_t) >> PSI_SHIFT) + 1;
        let psi_base = top.saturating_sub(PSI_CODE_MAX) as u16;
        let base = i32::from(psi_base);
        // The Ψ code without the f32 bit pattern, when every nonzero scatter's biased exponent
        // E = 157 + hi + te + ke is in 1..=254 (te ≥ −15 for t ≥ 1; at most max_t's + 1): the key is
        // 4E + ((M + dd) >> 21) with M the mantissa's 23 bits, dd the dither's (`psi_key`), and
        // (M + dd) >> 21 = (p' + dd·2⁸) >> 29 with p' the normalised product less its top bit (floors
        // nest), all in a u32. ≈ 20 instructions a dimension fewer on v6-M than bits, then key.
        let fast_key = FUSE && (max_t == 0 || (ke >= -141 && top16_by_table(max_t).1 + ke <= 96));
        let key_base = 4 * (157 + ke) - base;
        let code_of = |t: u32, d8: u32| -> u8 {
            let code = if fast_key {
                if t == 0 {
                    return 0;
                }
                let (t16, te) = top16_by_table(t);
                let p = t16 * k;
                let hi = p >> 31;
                let r = (((p << (1 - hi)) & 0x7FFF_FFFF) + (d8 << 21) + (1 << 20)) >> 29;
                key_base + 4 * (te + hi as i32) + r as i32
            } else {
                psi_key(f32::from_bits(bits(t)), d8 as u8) as i32 - base
            };
            code.clamp(0, PSI_CODE_MAX as i32) as u8
        };

        // ---- the codes, with the dither stream of the general merge.
        let (mut mu_codes, mut psi_codes) = ([0u8; D], [0u8; D]);
        let mut d = 0;
        let out = xy.iter().zip(mu_codes.iter_mut().zip(&mut psi_codes));
        for (i, (&(x, yt), (mc, pc))) in out.enumerate() {
            d = if i % 2 == 0 { dither.next() } else { d >> 16 };
            let t = if fused { scatter_of(yt) } else { yt as u32 };
            let u = round_shr(round_shr(x, xs).wrapping_mul(r_ns as i32), rs);
            let q = (u + (d & 0xFF) as i32) >> 8;
            *mc = q.clamp(-MU_QMAX - 1, MU_QMAX) as u8 & ((1 << MU_BITS) - 1) as u8;
            *pc = code_of(t, (d >> 8) & 0xFF);
        }
        // Every byte of both sections written (the packing fills the last byte's spare bits with 0).
        let (mu_out, psi_out) = self
            .codes
            .split_at_mut(super::super::section_len(D, MU_BITS));
        pack_codes::<{ MU_BITS as usize }>(&mu_codes, mu_out);
        pack_codes::<{ PSI_BITS as usize }>(&psi_codes, psi_out);
        self.count = f32::from_bits(f32_bits(n, 0));
        self.mu_scale = mu_scale;
        self.psi_base = psi_base;
        Some(())
    }
}
