//! Cooling int8 sums into a voxel's compact codes in fixed point: no float arithmetic, for an MCU without
//! an FPU (thumbv6m, riscv32imac), where the f32 cooling runs in software float.
//!
//! Why: a hot voxel fed int8 codes holds exact integer sums ([`CodeSums`]); when it cools, those sums are
//! merged (Chan's formula) into the statistics its [`QuantVoxel`] codes stand for and re-encoded. In f32
//! that is ≈ 16 float operations per dimension: ≈ 70,000 instructions per cooling on riscv32imac and
//! ≈ 130,000 on thumbv6m, in library calls. Here the same merge runs in integers, in units of the int8
//! scale s (a code step): means as i32 with [`MEAN_FRAC`] fraction bits (|m| ≤ 160 steps), scatters on a
//! per-voxel power-of-two unit, products of 16-bit pieces where 16 bits are enough; only the final codes go
//! through the f32 bit layout (built from integers), so they mean exactly what [`QuantVoxel::decode`]
//! reads. The codes equal the f32 path's to the rounding of the last code step (tests: within 1.3 mean
//! steps and one scatter step on 400 merges; 600 coolings of one voxel walk no farther than the f32 path's).
//!
//! Only the targets without an FPU cool int8 sums this way ([`super::Cooling::NATIVE`]; a hosted build
//! links both, so the QEMU boards' host twins compute what each board does). Measured with
//! `boards/measure.sh` (depth frames, f = 3, i8 features, instructions per point): riscv32imac 3,393 →
//! 1,824 (1,767 in one pass), thumbv6m 5,111 → 2,521 (2,667 at opt-level 2; 2,302 in one pass), but the
//! Cortex-M4F 1,004 → 1,312 — its FPU runs the f32 cooling in fewer instructions than these integer passes
//! (≈ 150 per dimension), so it keeps the f32 cooling (1,015). The
//! per-dimension helpers are kept out of line on riscv32imac (flash: it stays under 64 KiB); on v6-M the 64-bit
//! products are built from 16-bit halves.
//!
//! A few points into a voxel of many (a scanning LiDAR's usual cooling) take `sparse` (feature
//! `sparse-cooling`, the boards' build): the same merge in the old codes' units, 32-bit products only. The
//! minimal build (`default-features = false`) leaves it out: riscv32imac's has no room for both paths. Both
//! keep the map's mean grid (a weighed map's finer one, as the f32 cooling's `reencode_fine`): the coarse
//! grid had cost the LiDAR's base station 0.0475 RMS ‖Δμ‖/‖μ‖ against 0.0260 with the f32 cooling.
//! `bash boards/measure-targets.sh --table` (instructions per point, f = 3, i8 features; before → sparse
//! path → and the fine grid, which re-grids more often), scanning LiDAR: thumbv6m 16,651 → 11,865 →
//! 12,515, riscv32imac 11,946 → 8,703 → 9,266; depth frames 1,869 → 1,849 and 1,549 → 1,550; the
//! firmware's stream at the base station 0.0226 → 0.0180 on both (lidar_f3_i8 0.0475 → 0.0260).
//!
//! The coolings of a young voxel (≤ 255 points) that the sparse path does not take — an 8×8 ToF's voxel
//! of one point revisited above all, also a first visit of several points and a scale that must change —
//! take `small` (feature `sparse-cooling`): the same merge in 32-bit products, the old scatters from a
//! table of the 32 keys, σ read to 2⁻²⁴ (this general merge reads it to 2⁻¹⁴ steps: up to 1.85 codes off
//! for a mean of a tenth of a step; the small path ≤ 1.0 on the same merges, test
//! `small_voxel_merges_match_the_f32_path`). `bash boards/measure-targets.sh --table`, instructions a
//! point, f = 3, i8 features: thumbv6m ToF 8×8 12,124 → 10,132, scanning LiDAR 8,968 → 8,768, depth frames
//! 1,755 → 1,591; riscv32imac 9,012 → 8,276, 7,294 → 7,260, 1,394 → 1,354; the firmware's stream at the
//! base station 0.0129 → 0.0129 on both (lidar_f3_i8 0.0226 → 0.0225). The boards' build's flash
//! +4,004 B (thumbv6m, 82,296 → 86,300) and +4,796 B (riscv32imac, 88,322 → 93,118), thumbv6m's stack
//! 4,052 → 4,348 B; the minimal build unchanged to the byte.

use super::{
    psi_key, Dither, QuantVoxel, MU_BITS, MU_QMAX, PSI_CODE_MAX, PSI_SHIFT, PSI_STEPS_LOG2,
};
use crate::obs::CodeSums;
use half::f16;

/// The per-dimension steps of the cooling: one out-of-line copy in riscv32imac's minimal build (its flash is
/// within a few bytes of 64 KiB), inlined into the passes elsewhere (on v6-M the call and the spills around
/// it cost more than the work: measured below; riscv32imac's boards' build, 10 KB short of its limit, saves
/// the calls: ToF 10,463 → 9,082, LiDAR 7,579 → 7,384 instructions a point, +964 B of flash).
macro_rules! per_dim_step {
    ($item:item) => {
        #[cfg_attr(
            all(
                target_arch = "riscv32",
                not(target_feature = "f"),
                not(feature = "sparse-cooling")
            ),
            inline(never)
        )]
        #[cfg_attr(
            not(all(
                target_arch = "riscv32",
                not(target_feature = "f"),
                not(feature = "sparse-cooling")
            )),
            inline(always)
        )]
        $item
    };
}

mod bits;
#[cfg(feature = "sparse-cooling")]
mod small;
#[cfg(feature = "sparse-cooling")]
mod sparse;
use bits::*;

/// Fraction bits of a mean in code steps (|m| ≤ 160 steps → < 2²².)
const MEAN_FRAC: i32 = 14;

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

    /// A new mean scale for the largest |m| `max_abs` (steps with [`MEAN_FRAC`] fraction bits, ≤ 2²⁴):
    /// max|m|·headroom/q_max (`headroom` in units of 2⁻²¹, [`grid`]) in f16, rounded up so that max|m| fits;
    /// with it σ in steps ([`Self::steps_of`]). Zero for zero.
    #[cfg_attr(feature = "sparse-cooling", inline(never))]
    #[cfg_attr(not(feature = "sparse-cooling"), inline(always))]
    fn fresh_scale(&self, max_abs: i32, headroom: u32) -> (f16, i32) {
        if max_abs == 0 {
            return (f16::ZERO, 0);
        }
        // max·headroom/63 · s in 16-bit pieces (f16 keeps 11 bits): headroom/63 · 2²¹.
        let (t, e) = top16(max_abs as u32);
        let (p, pe) = top16(t * headroom);
        let bits = f32_bits(p * (self.s.m >> 8), e + pe - MEAN_FRAC - 21 + 8 + self.s.e);
        let mut s = f16::from_f32(f32::from_bits(bits));
        let mut sig = self.steps_of(s);
        if sig.saturating_mul(MU_QMAX) < max_abs {
            s = f16::from_bits(s.to_bits() + 1);
            sig = self.steps_of(s);
        }
        (s, sig)
    }

    /// An f16 mean scale σ in code steps, with [`MEAN_FRAC`] fraction bits.
    #[inline(never)]
    fn steps_of(&self, sigma: f16) -> i32 {
        let h = sigma.to_bits();
        let (e16, f) = (i32::from((h >> 10) & 0x1F), u32::from(h & 0x3FF));
        let (m, e) = match e16 {
            0 => (f, -24),              // subnormal (or zero)
            31 => return i32::MAX / 64, // never made by the encoder
            _ => (f | 0x400, e16 - 25),
        };
        // 11-bit × 20-bit mantissas: 2⁻²⁰ relative, within a u32.
        let v = shift(m * (self.inv_s.m >> 4), e + self.inv_s.e + 4 + MEAN_FRAC);
        v.min(i32::MAX as u32 / 64) as i32
    }
}

per_dim_step! {
/// One dimension's old and merged means (code steps with [`MEAN_FRAC`] fraction bits) and x = Σc − n₁m₀
/// (the same fraction bits), from the old mean code `q` on scale `sigma` (steps) and the sums' Σc: the merged
/// mean is m₀ + x/n (`rn`: 2³²/n).
fn merged_mean(q: u32, sigma: i32, sum: i32, n1: u32, rn: u32) -> (i32, i32, i32) {
    let q = (q as i32) << (32 - MU_BITS) >> (32 - MU_BITS);
    let m0 = q.wrapping_mul(sigma);
    let x = (sum << MEAN_FRAC).wrapping_sub((n1 as i32).wrapping_mul(m0));
    (
        m0,
        m0.wrapping_add(((mul32s(x, rn) + (1 << 31)) >> 32) as i32),
        x,
    )
}
}

per_dim_step! {
/// One dimension's codes: μ = m/σ by the reciprocal `r_sigma` (2³²/σ) to 1/256 of a step, plus a dither
/// below one step, floored (stochastic rounding); Ψ the minifloat key of `bits` less the voxel's `base`.
/// Bytes 0 and 1 of `dither` serve μ and Ψ, as in [`QuantVoxel::reencode`].
fn codes_of(m: i32, r_sigma: u32, bits: u32, base: i32, dither: u32) -> (u8, u8) {
    let u = ((mul32s(m, r_sigma) + (1 << 23)) >> 24) as i32;
    let q = (u + (dither & 0xFF) as i32) >> 8;
    let mu = q.clamp(-MU_QMAX - 1, MU_QMAX) as u8 & ((1 << MU_BITS) - 1) as u8;
    let psi = (psi_key(f32::from_bits(bits), (dither >> 8) as u8) as i32 - base)
        .clamp(0, PSI_CODE_MAX as i32) as u8;
    (mu, psi)
}
}

/// The mean grid's rules, as [`QuantVoxel::reencode`] (`fine` false) and [`QuantVoxel::reencode_fine`]
/// (true) keep them: the scale stays while max|m|·a ≥ σ·q_max·b, `within` = (a, b) (a quarter of the top
/// code, or 1/[`super::FINE_KEEP`]); a new scale is max|m|·headroom/q_max, `headroom` in units of 2⁻²¹
/// (1.25/63 or [`super::FINE_HEADROOM`]/63).
fn grid(fine: bool) -> ((i32, i32), u32) {
    if fine {
        ((5, 4), 34_953)
    } else {
        ((4, 1), 41_610)
    }
}

/// What one dimension's scatter merge needs from its voxel (see [`QuantVoxel::merge_codes_fixed`]).
struct ScatterUnits {
    /// Whether the codes hold earlier points.
    old: bool,
    old_shift: i32,
    inv_s2: u32,
    s2: Parts,
    /// The unit is c²·2^g.
    g: i32,
}

impl ScatterUnits {
    /// The units of a merge of `n` points, `n0` of them in the old codes: g chosen so that n·127²·1.25 < 2³¹.
    fn new(fix: &Int8Fix, n0: u32, n: u32) -> Self {
        let g = (32 - lz(n) as i32) - 16;
        Self {
            old: n0 > 0,
            old_shift: fix.inv_s2.e - 129 - g, // minifloat 2^(E−129)·(4+f) → units, with 1/s²
            inv_s2: fix.inv_s2.m,
            s2: fix.s2,
            g,
        }
    }

    /// The old scatter of minifloat key `k` (code plus base) in units: exponent k / 2^L, mantissa
    /// 1 + (k mod 2^L) / 2^L, L = [`PSI_STEPS_LOG2`].
    fn old_units(&self, k: u32) -> u32 {
        const STEPS: u32 = 1 << PSI_STEPS_LOG2;
        if !self.old || k < STEPS {
            0
        } else {
            // (2^L + f) · 1/s² mantissa < 2^(L+1) · 2²⁴; `old_shift` is for L = 2 (2^(E−129)·(4 + f)).
            shift(
                (STEPS + (k & (STEPS - 1))) * self.inv_s2,
                (k >> PSI_STEPS_LOG2) as i32 + self.old_shift + (2 - PSI_STEPS_LOG2 as i32),
            )
        }
    }
}

per_dim_step! {
/// One dimension's merged scatter as the f32 bit pattern of its value: `old` the old scatter in units
/// ([`ScatterUnits::old_units`]) plus what the new points add, S₁ + (n₀n₁/n)·d² = Σc² − m₀Σc − m·x (`sum`,
/// `sq`: Σc, Σc²; `m0`, `m`: the old and merged means, `x` = Σc − n₁m₀, all with [`MEAN_FRAC`] fraction
/// bits): two products, summed at full width in 2⁻²⁸ code² (the terms cancel) and then cut to units. It
/// replaced the new points' mean, N/n₁, d² and d²·n₀n₁/n, four products and two cuts (measured per point:
/// thumbv6m 1,951 → 1,901, riscv32imac 1,527 → 1,555, whose `mulh` had made those products cheap).
fn merged_scatter_bits(u: &ScatterUnits, old: u32, sum: i32, sq: u32, m0: i32, m: i32, x: i32) -> u32 {
    let g = u.g;
    // |m₀Σc| < 2⁴⁶ (then · 2¹⁴), |m·x| < 2⁶², Σc² < 2³² (· 2²⁸): no term or sum leaves an i64.
    let t = (i64::from(sq) << 28)
        .wrapping_sub(mul32ss(m0, sum) << MEAN_FRAC)
        .wrapping_sub(mul32ss(m, x));
    // g ∈ [−15, 15]: a shift by 13 to 43 bits, saturated to 32 bits (a rounding can leave t just below 0).
    let new = if t > 0 {
        shr_sat32(t as u64, (28 + g) as u32)
    } else {
        0
    };
    let total = old.saturating_add(new);
    if total == 0 {
        return 0;
    }
    // total · 2^g · s² as f32 bits, from 16-bit pieces (the minifloat key reads 2 + 8 bits of mantissa):
    // a 16 × 16-bit product in [2³⁰, 2³²), renormalised by one bit.
    let (t, te) = top16(total);
    let p = t * (u.s2.m >> 8);
    let hi = (p >> 31) as i32;
    let mant = (p << (1 - hi)) >> 8;
    let biased = 150 + 7 + hi + te + 8 + g + u.s2.e;
    if biased <= 0 {
        0
    } else if biased >= 255 {
        f32::MAX.to_bits()
    } else {
        ((biased as u32) << 23) | (mant & 0x7F_FFFF)
    }
}
}

impl<const D: usize, const P: usize> QuantVoxel<D, P> {
    /// These codes merged with int8 sums of scale `fix` (Chan's formula) and re-encoded, in integers: what
    /// [`Self::reencode`] of the decoded codes merged with [`CodeSums::to_obs`] gives, to the rounding of the
    /// last code step. Keeps the mean's scale when it still fits, as [`Self::reencode`] does.
    ///
    /// Two passes over the dimensions: the merged means and scatters (the latter as the f32 bit patterns of
    /// their values), then — once the mean's scale and the scatter's base are known — the codes with the
    /// dither stream `reencode` uses. Every product fits its width by the bounds of int8 codes (|Σc| ≤ 255·127).
    pub fn merge_codes_fixed(
        &self,
        sums: &CodeSums<D>,
        fix: &Int8Fix,
        fine: bool,
        dither: &mut Dither,
    ) -> Self {
        let mut out = *self;
        out.merge_codes_fixed_here(sums, fix, fine, dither);
        out
    }

    /// [`Self::merge_codes_fixed`] in place: what the map's cooling calls (the merged value returned, then
    /// copied into the slot, was two 104-byte copies a cooling).
    #[inline(never)]
    pub fn merge_codes_fixed_here(
        &mut self,
        sums: &CodeSums<D>,
        fix: &Int8Fix,
        fine: bool,
        dither: &mut Dither,
    ) {
        self.merge_in::<true>(sums, fix, fine, dither)
    }

    /// [`Self::merge_codes_fixed`] by the general merge alone (no short path): what the tests hold the
    /// short paths to.
    #[cfg(all(test, feature = "sparse-cooling"))]
    fn merge_general(
        &self,
        sums: &CodeSums<D>,
        fix: &Int8Fix,
        fine: bool,
        dither: &mut Dither,
    ) -> Self {
        let mut out = *self;
        out.merge_in::<false>(sums, fix, fine, dither);
        out
    }

    /// The merge, in place; `SHORT`: a sparse sensor's coolings take their short paths (feature
    /// `sparse-cooling`).
    #[inline(always)]
    fn merge_in<const SHORT: bool>(
        &mut self,
        sums: &CodeSums<D>,
        fix: &Int8Fix,
        fine: bool,
        dither: &mut Dither,
    ) {
        let n1 = sums.count;
        if n1 == 0 || fix.s.m == 0 {
            return;
        }
        let n0 = count_of(self.count.to_bits());
        #[cfg(feature = "sparse-cooling")]
        if SHORT && n0 == 0 && n1 == 1 {
            if let Some(first) = Self::encode_lone(sums, fix, fine, dither) {
                *self = first;
                return;
            }
        }
        let n = n0.saturating_add(n1).min(1 << 30);
        // The trip count hidden from the optimiser: rolled loops, ≈ 1.5 KB of code instead of ≈ 5 KB.
        #[cfg(not(feature = "sparse-cooling"))]
        let dims = core::hint::black_box(D);
        let sigma = if n0 > 0 {
            fix.steps_of(self.mu_scale)
        } else {
            0
        };

        // ---- pass 1, per dimension: the merged mean in code steps (MEAN_FRAC fraction bits) and the merged
        // scatter. With x = Σc − n₁m₀ the merged mean is m₀ + x/n, and the new points add
        // S₁ + (n₀n₁/n)·d² = Σc² − m₀Σc − m·x to the scatter (d = x/n₁, the distance of the two means; the
        // same algebra with Σc = x + n₁m₀). Division by a reciprocal (2³²/n): (2³² − 1)/n, a 32-bit division
        // or, on v6-M, a table entry for n < 256 (a 64-bit division links ≈ 1 KB of library code on a 32-bit
        // MCU). Scatters in units of c²·2^g, g chosen so that n·127²·1.25 < 2³¹; each ends as the f32 bit
        // pattern of its value (what the minifloat codes are cut from). One pass: the scatter needs only its
        // own dimension's means (no array of them).
        let rn = recip(n);
        let ctx = ScatterUnits::new(fix, n0, n);
        #[cfg(feature = "sparse-cooling")]
        if SHORT && n0 >= 2 && n1 <= sparse::SPARSE_MAX_NEW && sigma > 0 {
            if let Some(merged) = self.merge_sparse(sums, &ctx, n0, sigma, fine, dither) {
                *self = merged;
                return;
            }
        }
        // The rest of a young voxel's coolings (an 8×8 ToF's voxel of one point revisited, above all): `small`.
        #[cfg(feature = "sparse-cooling")]
        if SHORT && n0 <= small::SMALL_MAX_OLD && self.merge_small_here(sums, fix, n0, fine, dither)
        {
            return;
        }
        // The old scatters in units, one per Ψ code (32) instead of one per dimension (64): a voxel's codes
        // share their base, so the code alone picks the value.
        let base_old = u32::from(self.psi_base);
        let mut old_units = [0u32; 1 << super::PSI_BITS];
        if ctx.old {
            // Rolled (the trip count hidden, as `dims`): unrolled it costs riscv32imac ≈ 1 KB of flash.
            for c in 0..core::hint::black_box(old_units.len()) {
                if let Some(o) = old_units.get_mut(c) {
                    *o = ctx.old_units(c as u32 + base_old);
                }
            }
        }
        let mut max_abs = 0u32;
        let mut psi_max_bits = 0u32;
        let (mu_part, psi_part) = self.codes.split_at(super::section_len(D, MU_BITS));
        // Built in place (no zeroing of 512 bytes first: `__aeabi_memclr4` was ≈ 30 instructions per point
        // on thumbv6m).
        // A first visit of one point (most of a sparse sensor's coolings): its mean is its codes and its
        // scatter 0, exactly what the merge below computes for it (m₀ = 0, x = Σc, m = x, t = 0), without
        // the products. The test stays in the loop: hoisted out of it (the merged array built through a
        // branch) it grew both targets' stacks by 0.5–1 KiB and cost riscv32imac's ToF 324 a point.
        let lone = n0 == 0 && n1 == 1;
        // The old codes: on v6-M with the sparse path linked, unpacked eight at a time
        // (`bits::unpack_codes`; a packed read a code cost an M0 ≈ 12 instructions a section: ToF 12,402 →
        // 12,124 instructions a point); else read one at a time (riscv32imac: unpacked, +14 a point).
        #[cfg(all(feature = "sparse-cooling", target_abi = "eabi"))]
        let (mu_code, psi_code) = {
            let (mut qs, mut ks) = ([0u8; D], [0u8; D]);
            unpack_codes::<{ MU_BITS as usize }>(mu_part, &mut qs);
            unpack_codes::<{ super::PSI_BITS as usize }>(psi_part, &mut ks);
            (
                move |i: usize| u32::from(qs.get(i).copied().unwrap_or(0)),
                move |i: usize| u32::from(ks.get(i).copied().unwrap_or(0)),
            )
        };
        #[cfg(not(all(feature = "sparse-cooling", target_abi = "eabi")))]
        let (mu_code, psi_code) = (
            |i: usize| code_at(mu_part, MU_BITS, i),
            |i: usize| code_at(psi_part, super::PSI_BITS, i),
        );
        let merged: [(i32, u32); D] = core::array::from_fn(|i| {
            let (sum, sq) = (sums.sum(i), sums.square(i));
            if lone {
                let m = sum << MEAN_FRAC;
                max_abs = max_abs.max(m.unsigned_abs());
                return (m, 0);
            }
            let (m0, m, x) = merged_mean(mu_code(i), sigma, sum, n1, rn);
            max_abs = max_abs.max(m.unsigned_abs());
            let old = old_units.get(psi_code(i) as usize).copied().unwrap_or(0);
            let b = merged_scatter_bits(&ctx, old, sum, sq, m0, m, x);
            psi_max_bits = psi_max_bits.max(b);
            (m, b)
        });

        // ---- the mean's scale: kept while it fits (as `reencode`), else max|m|·1.25/q_max rounded up in f16.
        let max_abs = max_abs.min(1 << 24) as i32;
        let qmax = MU_QMAX;
        let (within, headroom) = grid(fine);
        let keep = sigma > 0
            && max_abs <= sigma.saturating_mul(qmax)
            && max_abs.saturating_mul(within.0) >= sigma.saturating_mul(qmax * within.1);
        let (mu_scale, sigma) = if keep {
            (self.mu_scale, sigma)
        } else {
            fix.fresh_scale(max_abs, headroom)
        };

        let top = (psi_max_bits.min(f32::MAX.to_bits()) >> PSI_SHIFT) + 1;
        let psi_base = top.saturating_sub(PSI_CODE_MAX) as u16;

        // ---- pass 2, codes, with the dither stream `reencode` uses (bytes 0, 1: μ, Ψ of a dimension; 2, 3:
        // the next). μ: m/σ by a reciprocal (2³²/σ) to 1/256 of a step, plus a dither below one step, floored.
        let r_sigma = if sigma > 0 {
            u32::MAX / sigma.unsigned_abs()
        } else {
            0
        };
        let base = psi_base as i32;
        let mut codes = [0u8; P];
        let (mu_out, psi_out) = codes.split_at_mut(super::section_len(D, MU_BITS));
        let mut d = 0;
        // With the sparse path linked (the boards' build, flash to spare): codes to bytes, packed eight at
        // a time (`bits::pack_codes`; a packed write a code cost an M0 ≈ 12 instructions a section).
        #[cfg(feature = "sparse-cooling")]
        {
            let (mut mu_codes, mut psi_codes) = ([0u8; D], [0u8; D]);
            let out = merged.iter().zip(mu_codes.iter_mut().zip(&mut psi_codes));
            for (i, (&(m, b), (mc, pc))) in out.enumerate() {
                d = if i % 2 == 0 { dither.next() } else { d >> 16 };
                (*mc, *pc) = codes_of(m, r_sigma, b, base, d);
            }
            pack_codes::<{ MU_BITS as usize }>(&mu_codes, mu_out);
            pack_codes::<{ super::PSI_BITS as usize }>(&psi_codes, psi_out);
        }
        #[cfg(not(feature = "sparse-cooling"))]
        for i in 0..dims {
            let Some(&(m, b)) = merged.get(i) else {
                break;
            };
            if i % 2 == 0 {
                d = dither.next();
            } else {
                d >>= 16;
            }
            let (mc, pc) = codes_of(m, r_sigma, b, base, d);
            set_code(mu_out, MU_BITS, i, mc);
            set_code(psi_out, super::PSI_BITS, i, pc);
        }
        *self = Self {
            count: f32::from_bits(f32_bits(n, 0)),
            mu_scale,
            psi_base,
            codes,
        };
    }
}

#[cfg(test)]
mod tests;
