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
//! Codes are read and written as bit streams (no per-code address arithmetic). When the scale must change,
//! the scatter outgrows the table or a range would not fit 32 bits, it returns `None` and the general
//! path cools the voxel (the dither stream untouched).

use super::super::{Dither, QuantVoxel, MU_BITS, MU_QMAX, PSI_BITS, PSI_CODE_MAX};
use super::bits::*;
use super::ScatterUnits;
use crate::obs::{scatter_numerator, CodeSums};

/// Most new points this path takes (the bound of its 32-bit ranges; more go the general way).
pub(super) const SPARSE_MAX_NEW: u32 = 8;

/// Scatter keys from the voxel's base the table holds: its 32 codes and 8 keys of growth.
const KEYS: usize = 40;

impl<const D: usize, const P: usize> QuantVoxel<D, P> {
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
        // The values of the keys from the base up: four from the general path's conversion, the rest by
        // halving (an octave per 4 keys).
        let base_old = u32::from(self.psi_base);
        let mut table = [0u32; KEYS];
        for c in (0..KEYS).rev() {
            table[c] = match table.get(c + 4) {
                Some(&t) => t.div_ceil(2),
                None => ctx.old_units(c as u32 + base_old),
            };
        }
        if table[KEYS - 1] >= 1 << 30 {
            return None; // saturated: the table does not reach
        }

        let mut out = [0u8; P];
        let (mu_out, psi_out) = out.split_at_mut(super::super::section_len(D, MU_BITS));
        let (mu_in, psi_in) = self.codes.split_at(super::super::section_len(D, MU_BITS));
        let (mut mu_r, mut psi_r, mut mu_w) = (
            CodeReader::new(mu_in),
            CodeReader::new(psi_in),
            CodeWriter::new(mu_out),
        );
        let mut keys = [0u8; D];
        let (mut max_u, mut top) = (0u32, 0usize);
        let mut dith = dither.clone();
        let mut d = 0;
        for i in 0..core::hint::black_box(D) {
            d = if i % 2 == 0 { dith.next() } else { d >> 16 };
            let (sum, sq) = (sums.sum(i), sums.square(i));
            let q = (mu_r.next(MU_BITS) << (32 - MU_BITS)) as i32 >> (32 - MU_BITS);
            let t = sum.wrapping_mul(a).wrapping_sub(q.wrapping_mul(b));
            let u = (q << 8).wrapping_add(t.wrapping_add(half).wrapping_shr(dsh as u32));
            max_u = max_u.max(u.unsigned_abs());
            let code = ((u + (d & 0xFF) as i32) >> 8).clamp(-MU_QMAX - 1, MU_QMAX);
            mu_w.put(MU_BITS, code as u32 & ((1 << MU_BITS) - 1));

            let y =
                ((sum << super::MEAN_FRAC).wrapping_sub(q.wrapping_mul(n1sig)) + y_half) >> y_sh;
            let mut s = shl_sat(mul_q16(y.wrapping_mul(y) as u32, w), wsh);
            if n1 > 1 {
                s = s.saturating_add(shl_sat(mul_q16(scatter_numerator(n1, sum, sq), v), vsh));
            }
            let mut key = psi_r.next(PSI_BITS) as usize;
            let mut lo = table.get(key).copied().unwrap_or(u32::MAX);
            let s = s.saturating_add(lo);
            // Up from the old key (S only grows) to the one whose step holds S.
            let hi = loop {
                let next = table.get(key + 1).copied().unwrap_or(0);
                if next == 0 || s < next {
                    break next;
                }
                key += 1;
                lo = next;
            };
            if hi == 0 {
                return None; // above the table
            }
            top = top.max(key);
            // Dithered within the step as `psi_key`: up if (S − lo)/step ≥ (255.5 − byte)/256.
            let (r, st) = (s - lo, hi - lo);
            let (r, st) = if st >= 1 << 22 {
                (r >> 8, st >> 8)
            } else {
                (r, st)
            };
            let byte = (d >> 8) & 0xFF;
            key += usize::from(r << 9 >= (511 - 2 * byte) * st);
            if let Some(k) = keys.get_mut(i) {
                *k = key as u8;
            }
        }
        mu_w.finish();
        // The scale stays while the merged mean fits it and reaches a quarter of it (as `reencode`).
        let full = (MU_QMAX as u32) << 8;
        if max_u > full || max_u * 4 < full {
            return None;
        }
        // The base as `reencode` sets it: the floor key of the largest scatter plus one, less 31.
        let base = (base_old + top as u32 + 1).saturating_sub(PSI_CODE_MAX);
        let moved = base as i32 - base_old as i32;
        let mut psi_w = CodeWriter::new(psi_out);
        for &key in &keys {
            psi_w.put(
                PSI_BITS,
                (i32::from(key) - moved).clamp(0, PSI_CODE_MAX as i32) as u32,
            );
        }
        psi_w.finish();
        *dither = dith;
        Some(Self {
            count: f32::from_bits(f32_bits(n, 0)),
            mu_scale: self.mu_scale,
            psi_base: base as u16,
            codes: out,
        })
    }
}
