//! The cooling a sparse sensor asks for almost every time: a few new points (a LiDAR beam's 1–2 in a voxel)
//! merged into a voxel that already holds many, on the grid it has.
//!
//! Why its own path: measured on the self-test's scanning LiDAR (int8, f = 3), 83 % of the coolings merge
//! 1–4 points into a voxel of 16 points or more. Then the mean's scale almost always stays, the merged mean
//! moves by a fraction of a code and the scatter by a fraction of a key step. So each dimension is updated
//! in the old code units instead of decoded to steps and re-encoded, in 32-bit products only:
//! - mean, in codes of the voxel's scale σ: m = q + (Σc·A − q·B)/2^K with A = 2^K/(σn), B = 2^K·n₁/n
//!   (per cooling), rounded to 1/256 of a code and dithered as [`QuantVoxel::reencode`];
//! - scatter, in the general path's units: the old value from its key (a table of the 40 keys above the
//!   voxel's base), plus S₁ + n₀/(n·n₁)·y² with y = Σc − n₁m₀; the new key found by walking the table up from
//!   the old one (S only grows), dithered linearly within its step as `psi_key` does.
//!
//! The codes are unpacked eight at a time into one byte each, computed in two loops over those bytes and
//! packed eight at a time: on a Cortex-M0 (8 low registers) the one loop over the packed bit streams that
//! did all of it kept ≈ 20 values live and spilled them. The first loop takes the means and each y² (it has
//! Σc and the old code at hand), so the scale is checked before any scatter work (an 8×8 ToF's small
//! voxels often need a new one); the second the scatters' growth and the keys. On the LiDAR's 42,335 sparse
//! coolings (`PROFILE_SCENARIO=lidar_f3_i8 bash boards/measure-targets.sh --profile thumbv6m`) this
//! function ran 492.0 M instructions with three loops (means 54, growth 43, keys 71 a dimension), 454.7 M
//! with these two (53 and 97; the rest ≈ 1,100 a cooling: set-up, table, unpacking Ψ). One loop for all
//! of it ran 463.1 M, and a merge refused for its scale paid for the scatters too (ToF 9,498 → 9,947 a
//! point).
//! When the scale must change, the scatter outgrows the table or a range would not fit 32 bits, it returns
//! `None` and the general path cools the voxel (the dither stream untouched).
//!
//! The other cooling a sparse sensor asks for: a first visit of one point (an 8×8 ToF's usual cooling, a
//! voxel per point), its codes straight from the point's ([`QuantVoxel::encode_lone`]).
//!
//! Both give the codes of the code they replaced bit for bit (the QEMU boards' streams unchanged).
//! `bash boards/measure-targets.sh --table thumbv6m`, instructions per point, f = 3, i8 features: ToF 8×8
//! 18,233 → 14,487, scanning LiDAR 11,848 → 9,934, depth frames 1,849 → 1,839. Then, each measured on the
//! main branch of its day: two loops instead of three and S's terms capped at 2³⁰ instead of saturated
//! ([`Shift`]: no saturating adds): ToF 9,498 → 9,430, LiDAR 8,483 → 8,077 (riscv32imac 7,787 → 7,761 and
//! 6,952 → 6,613); the new mean codes over the old ones: ToF 9,005 → 8,979, LiDAR 7,990 → 7,982; on v6-M
//! a keys loop without S₁ for one new point: LiDAR 7,886 → 7,800, ToF 8,775 → 8,726; `encode_lone`
//! without its clamp: ToF 8,726 → 8,534 (riscv32imac 7,216 → 7,128). Depth frames unchanged (1,556).

use super::super::{Dither, QuantVoxel, MU_BITS, MU_QMAX, PSI_BITS, PSI_CODE_MAX};
use super::bits::*;
use super::{Int8Fix, ScatterUnits};
use crate::obs::{scatter_numerator, CodeSums};

/// Most new points this path takes (the bound of its 32-bit ranges; more go the general way).
pub(super) const SPARSE_MAX_NEW: u32 = 8;

/// Scatter keys from the voxel's base the table holds: its 32 codes and 8 keys of growth.
const KEYS: usize = 40;

impl<const D: usize, const P: usize> QuantVoxel<D, P> {
    /// A first visit of one point (a ToF's usual cooling: a voxel per point): its mean is its codes c on a
    /// fresh scale, its scatter 0 — Ψ codes 0 on base 0, what the general merge computes for it (m₀ = 0,
    /// x = Σc, t = 0), without its passes. The codes are the general merge's, bit for bit: with m = c·2¹⁴,
    /// ⌊(m·r + 2²³)/2²⁴⌋ = ⌊(c·r + 2⁹)/2¹⁰⌋ for r = 2³²/σ, a 32-bit product since |c| ≤ 127 and r < 2²⁴
    /// (else `None`: the general merge takes it).
    #[inline(never)]
    pub(super) fn encode_lone(
        sums: &CodeSums<D>,
        fix: &Int8Fix,
        fine: bool,
        dither: &mut Dither,
    ) -> Option<Self> {
        let mut max_c = 0;
        sums.for_each_dim(|_, sum, _| max_c = max_c.max(sum.unsigned_abs()));
        let max_abs = (max_c << super::MEAN_FRAC).min(1 << 24) as i32;
        let (mu_scale, sigma) = fix.fresh_scale(max_abs, super::grid(fine).1);
        let r = if sigma > 0 {
            u32::MAX / sigma.unsigned_abs()
        } else {
            0
        };
        if r >= 1 << 24 {
            return None;
        }
        // Built in place (`from_fn`: no zeroing first, which is a library call on these MCUs). When σ·63 ≥
        // max|m| (what `fresh_scale` aims at) the clamp is no change: |Σc·r| ≤ 63·2¹⁸, so |u| ≤ 63·256 and
        // the code is within ±63; a loop without it (thumbv6m ToF 8×8: 8,726 → 8,534 instructions a point).
        let mut d = 0;
        let mut code = |i: usize, clamped: bool| {
            d = if i.is_multiple_of(2) {
                dither.next()
            } else {
                d >> 16
            };
            let u = (sums.sum(i).wrapping_mul(r as i32) + (1 << 9)) >> 10;
            let q = (u + (d & 0xFF) as i32) >> 8;
            let q = if clamped {
                q.clamp(-MU_QMAX - 1, MU_QMAX)
            } else {
                q
            };
            q as u8 & ((1 << MU_BITS) - 1) as u8
        };
        let mu_codes: [u8; D] = if sigma.saturating_mul(MU_QMAX) >= max_abs {
            core::array::from_fn(|i| code(i, false))
        } else {
            core::array::from_fn(|i| code(i, true))
        };
        let mut codes = [0u8; P];
        let (mu_out, _) = codes.split_at_mut(super::super::section_len(D, MU_BITS));
        pack_codes::<{ MU_BITS as usize }>(&mu_codes, mu_out);
        Some(Self {
            count: 1.0,
            mu_scale,
            psi_base: 0,
            codes,
        })
    }

    /// These codes (of `n0` ≥ 2 points on scale `sigma` > 0, in steps with [`super::MEAN_FRAC`] fraction
    /// bits) merged with at most [`SPARSE_MAX_NEW`] points' sums, on the same mean scale; `None` if the
    /// scale must change or a range does not fit (nothing consumed from `dither` then).
    #[inline(never)]
    pub(super) fn merge_sparse(
        &self,
        sums: &CodeSums<D>,
        ctx: &ScatterUnits,
        n0: u32,
        sigma: i32,
        fine: bool,
        dither: &mut Dither,
    ) -> Option<Self> {
        let n1 = sums.count;
        let n = n0 + n1;
        let rn = recip(n);

        // ---- the mean: delta·2^K = Σc·A − q·B. A < 2^(21 − bits(n₁)) keeps |Σc·A| < 2²⁸; K ≤ 39 keeps the
        // rounding shift within an i32; K ≥ 20 keeps the error of A and B below 2⁻¹¹ code.
        let p = mul32(u32::MAX / sigma.unsigned_abs(), rn); // 2⁵⁰/(σn), σ in steps
        let p_bits = match (p >> 32) as u32 {
            0 => bit_len(p as u32),
            hi => 32 + bit_len(hi),
        } as i32;
        let mut sh = p_bits - (21 - bit_len(n1) as i32);
        let mut k = 50 - sh;
        if k > 39 {
            sh += k - 39;
            k = 39;
        }
        if sh < 0 || k < 20 {
            return None;
        }
        let a = shr_sat32(p, sh as u32) as i32;
        let nr = n1.wrapping_mul(rn); // 2³²·n₁/n (n₁ < n)
        let b = if k >= 32 {
            if nr >> (56 - k) != 0 {
                return None;
            }
            nr << (k - 32)
        } else {
            nr >> (32 - k)
        } as i32; // < 2²⁴: |q·B| < 2³⁰
        let (half, dsh) = (1i32 << (k - 9), k - 8);

        // ---- the scatter: units of the general path (steps²·2^g); y = Σc − n₁qσ formed with σ's 14 fraction
        // bits, kept with F, the most that keeps |y| < 46,340 (y² in a u32).
        let g = ctx.g;
        if (n1 as i32).wrapping_mul(sigma) >= 1 << 24 {
            return None; // |n₁·q·σ| < 2³⁰ below
        }
        let n1sig = (n1 as i32) * sigma;
        let mut f = 6;
        while (n1 as i32) * (127 << f) + ((64 * n1sig) >> (14 - f)) >= 46_000 {
            if f == 0 {
                return None;
            }
            f -= 1;
        }
        let (y_half, y_sh) = (1i32 << (13 - f), (14 - f) as u32);
        // n₀/(n·n₁)·y²: y² · w (w 16 bits) · 2^wsh. S₁ = num/n₁ (num = n₁Σc² − (Σc)²): num · v · 2^vsh.
        let (w, we) = top16((mul32(n0.wrapping_mul(rn), recip(n1)) >> 32) as u32);
        let wsh = we - 16 - 2 * f - g;
        let (v, ve) = top16(recip(n1));
        let vsh = ve - 16 - g;
        // The old scatters' values by key, from the base up: four from the general path's conversion, the
        // rest by halving (an octave per 4 keys): k halvings at once, ⌈t/2^k⌉ (the same as one at a time).
        let base_old = u32::from(self.psi_base);
        let tops: [u32; 4] =
            core::array::from_fn(|j| ctx.old_units((KEYS - 4 + j) as u32 + base_old));
        let table: [u32; KEYS] = core::array::from_fn(|c| {
            let k = (KEYS - 1 - c) / 4;
            let t = tops.get(c + 4 * k + 4 - KEYS).copied().unwrap_or(0);
            (t + (1 << k) - 1) >> k
        });
        if table[KEYS - 1] >= 1 << 30 {
            return None; // saturated: the table does not reach
        }

        // The codes unpacked to a byte each. Two loops over the dimensions: the means (then the scale
        // checked, before any scatter work) with each y² kept, the new codes written over the old ones;
        // the scatters' growth and keys, likewise. Bytes 0 and 1 of each dimension's 16 dither bits serve
        // μ and Ψ.
        let (mu_in, psi_in) = self.codes.split_at(super::super::section_len(D, MU_BITS));
        let mut qs = [0u8; D];
        unpack_codes::<{ MU_BITS as usize }>(mu_in, &mut qs);
        let mut max_u = 0u32;
        let mut dith = dither.clone();
        let mut d = 0;
        // Built in place (`from_fn`: no zeroing first, a library call on these MCUs).
        let y2: [u32; D] = core::array::from_fn(|i| {
            d = if i % 2 == 0 { dith.next() } else { d >> 16 };
            let (sum, q) = (
                sums.sum(i),
                i32::from((qs.get(i).copied().unwrap_or(0) << 1) as i8 >> 1),
            );
            // The mean. No clamp: while max|u| ≤ 63·256 (else `None` below) the code is within ±63.
            let t = sum.wrapping_mul(a).wrapping_sub(q.wrapping_mul(b));
            let u = (q << 8).wrapping_add(t.wrapping_add(half).wrapping_shr(dsh as u32));
            max_u = max_u.max(u.unsigned_abs());
            if let Some(c) = qs.get_mut(i) {
                *c = (u.wrapping_add((d & 0xFF) as i32) >> 8) as u8 & ((1 << MU_BITS) - 1) as u8;
            }
            let y =
                ((sum << super::MEAN_FRAC).wrapping_sub(q.wrapping_mul(n1sig)) + y_half) >> y_sh;
            y.wrapping_mul(y) as u32
        });
        // The scale stays while the merged mean fits it and reaches a quarter of it (as `reencode`; 1/1.25
        // on the fine grid, as `reencode_fine`).
        let full = (MU_QMAX as u32) << 8;
        let ((ka, kb), _) = super::grid(fine);
        if max_u > full || max_u * (ka as u32) < full * (kb as u32) {
            return None;
        }

        let mut keys = [0u8; D];
        unpack_codes::<{ PSI_BITS as usize }>(psi_in, &mut keys);
        let (by_w, by_v) = (Shift::new(wsh), Shift::new(vsh));
        let mut top = 0usize;
        let mut dith = dither.clone();
        // The key of dimension i whose S grew by `add`: up from the old one (S only grows) to the one whose
        // step holds S, dithered within it; false above the table.
        let mut key_of = |k: &mut u8, add: u32, byte: u32| -> bool {
            // A 5-bit code: the mask is no change, but tells the compiler the table holds it.
            let mut key = usize::from(*k) & PSI_CODE_MAX as usize;
            let mut lo = table.get(key).copied().unwrap_or(0);
            let s = add + lo;
            let hi = loop {
                let next = table.get(key + 1).copied().unwrap_or(0);
                if next == 0 || s < next {
                    break next;
                }
                key += 1;
                lo = next;
            };
            if hi == 0 {
                return false; // above the table
            }
            top = top.max(key);
            // Dithered within the step as `psi_key`: up if (S − lo)/step ≥ (255.5 − byte)/256.
            let (r, st) = (s - lo, hi - lo);
            let (r, st) = if st >= 1 << 22 {
                (r >> 8, st >> 8)
            } else {
                (r, st)
            };
            key += usize::from(r << 9 >= (511 - 2 * byte) * st);
            *k = key as u8;
            true
        };
        // What the new points add to each scatter, in units: n₀/(n·n₁)·y², plus S₁ when there are two or
        // more (S₁ = 0 for one). Each term at most 2³⁰ (`Shift`): S = add + lo without overflow, and S ≥ 2³⁰
        // walks past the table (< 2³⁰) to `None` as a saturated S did. On v6-M one new point takes a loop
        // without S₁ (its registers freed: LiDAR 7,886 → 7,800 instructions a point), two dimensions a turn
        // (one dither draw each, no test of the parity: 7,797 → 7,682, ToF 8,534 → 8,484); riscv32imac keeps
        // one loop (there the second loop cost 6,358 → 6,453). The host's tests take the v6-M loop too.
        if (cfg!(target_abi = "eabi") || cfg!(test)) && n1 == 1 {
            // Two dimensions a turn, one draw of the dither stream each (bytes 1 and 3).
            let (mut kc, mut yc) = (keys.chunks_exact_mut(2), y2.chunks_exact(2));
            for (kp, yp) in (&mut kc).zip(&mut yc) {
                if let ([k0, k1], &[y0, y1]) = (kp, yp) {
                    let d = dith.next();
                    if !key_of(k0, by_w.apply(mul_q16(y0, w)), (d >> 8) & 0xFF)
                        || !key_of(k1, by_w.apply(mul_q16(y1, w)), d >> 24)
                    {
                        return None;
                    }
                }
            }
            if let (Some(k), Some(&y)) = (kc.into_remainder().first_mut(), yc.remainder().first()) {
                let d = dith.next();
                if !key_of(k, by_w.apply(mul_q16(y, w)), (d >> 8) & 0xFF) {
                    return None;
                }
            }
        } else {
            let mut d = 0;
            for (i, (k, &y2)) in keys.iter_mut().zip(&y2).enumerate() {
                d = if i.is_multiple_of(2) {
                    dith.next()
                } else {
                    d >> 16
                };
                let mut add = by_w.apply(mul_q16(y2, w));
                if n1 > 1 {
                    let (sum, sq) = (sums.sum(i), sums.square(i));
                    add += by_v.apply(mul_q16(scatter_numerator(n1, sum, sq), v));
                }
                if !key_of(k, add, (d >> 8) & 0xFF) {
                    return None;
                }
            }
        }

        // ---- both sections packed; the base as `reencode` sets it: the floor key of the largest scatter
        // plus one, less 31.
        let base = (base_old + top as u32 + 1).saturating_sub(PSI_CODE_MAX);
        let moved = base as i32 - base_old as i32;
        if moved != 0 {
            for k in keys.iter_mut() {
                *k = (i32::from(*k) - moved).clamp(0, PSI_CODE_MAX as i32) as u8;
            }
        }
        let mut out = [0u8; P];
        let (mu_out, psi_out) = out.split_at_mut(super::super::section_len(D, MU_BITS));
        pack_codes::<{ MU_BITS as usize }>(&qs, mu_out);
        pack_codes::<{ PSI_BITS as usize }>(&keys, psi_out);
        *dither = dith;
        Some(Self {
            count: f32::from_bits(f32_bits(n, 0)),
            mu_scale: self.mu_scale,
            psi_base: base as u16,
            codes: out,
        })
    }
}
