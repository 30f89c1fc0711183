//! A revisited voxel's cooling in one pass: its codes decoded, merged with the hot tier's f32 statistics
//! (Chan's formula) and the maxima the encoder needs taken, dimension by dimension, then encoded.
//!
//! Why: the general cooling ran four passes over the 64 dimensions — decode into a scratch set, merge into
//! it, find the largest |mᵢ| and Sᵢ, encode — each loading and storing what the last one stored. A sparse
//! sensor revisits most voxels a point or two at a time, so these passes are most of what its points cost
//! on a Cortex-M4F. Here the codes are read eight dimensions at a time (constant shifts), each value merged
//! where it lies in registers, and written once for the encoder. The arithmetic is the general path's
//! operation for operation ([`QuantVoxel::decode_into`], [`ObsStats::merge`], the maxima of
//! `reencode`), so the codes are the same bit for bit (test `one_pass_equals_decode_merge_encode`; the
//! QEMU boards' streams unchanged). Only where an FPU makes the f32 cooling the fast path (elsewhere it
//! is soft float whatever, and flash is short), with the sparse sensors' other short paths (feature
//! `sparse-cooling`: ≈ 2 KB of flash on the an386, which a minimal build does without).
//! `bash boards/profile-scenario.sh 5` / `6` (Cortex-M4F, f32 features): ToF 8×8 31.16 → 30.64 M
//! instructions, scanning LiDAR 278.66 → 269.40 M. A pass of 29.5 instructions a dimension against 32 for
//! the three (decode 11, merge 11.75, maxima 9): the arithmetic, the moves between the FPU's and the core's
//! registers for the maxima, and the stores the encoder reads are all still there.

use super::{max_magnitude_bits, section_len, Dither, QuantVoxel, MU_BITS, PSI_BITS, PSI_SHIFT};
use crate::obs::{CodeSums, ObsStats};
use crate::stats::update_dim;

impl<const D: usize, const P: usize> QuantVoxel<D, P> {
    /// These codes merged with `new` and re-encoded in place (`fine`: on the weighed map's grid, as
    /// [`Self::reencode_fine_here`]): what `decode_into(work)`, `work.merge(new)` and the re-encode give,
    /// bit for bit. `work` is scratch (left holding the merged statistics). Empty `new`: nothing changes
    /// (no re-encode, no dither drawn).
    pub(crate) fn merge_here(
        &mut self,
        fine: bool,
        new: &ObsStats<D>,
        work: &mut ObsStats<D>,
        dither: &mut Dither,
    ) {
        // Nothing to merge: the codes stay as they are (as the general cooling leaves them).
        if !(new.count > 0.0) {
            return;
        }
        // Dimensions beyond whole eights (none at D = 64): the passes one by one.
        if !D.is_multiple_of(8) {
            self.decode_into(work);
            work.merge(new);
            if fine {
                self.reencode_in::<true>(work, dither);
            } else {
                self.reencode_in::<false>(work, dither);
            }
            return;
        }
        let (mean_max, scatter_max) = self.merged_into(new, work);
        // One pass for both grids: only the encoder differs.
        if fine {
            self.encode_in::<true>(work, mean_max, scatter_max, dither);
        } else {
            self.encode_in::<false>(work, mean_max, scatter_max, dither);
        }
    }

    /// A first visit of one int8 point (`sums` of one point, codes of scale `scale`; these codes empty),
    /// encoded in place: its mean is scale·c, its scatter 0 — what the general cooling's merge of the sums
    /// into empty statistics gives exactly (m = 0 + 1·(scale·c·1), S = 0 + 0 + 0·d²) — without that
    /// merge's per-dimension work (≈ 21 instructions a dimension on a Cortex-M4F: the reciprocal, the
    /// scatter's numerator) or the scatter pass of the encoder. `work` is scratch (its mean left holding
    /// the point).
    pub(crate) fn encode_lone_codes_here(
        &mut self,
        fine: bool,
        sums: &CodeSums<D>,
        scale: f32,
        work: &mut ObsStats<D>,
        dither: &mut Dither,
    ) {
        debug_assert!(sums.count == 1 && !(self.count > 0.0));
        sums.for_each_dim(|i, sum, _| {
            if let Some(m) = work.mean.get_mut(i) {
                *m = scale * sum as f32;
            }
        });
        work.count = 1.0;
        let mean_max = max_magnitude_bits(&work.mean);
        if fine {
            self.encode_in::<true>(work, mean_max, 0, dither);
        } else {
            self.encode_in::<false>(work, mean_max, 0, dither);
        }
    }

    /// The decoded codes merged with `new` (count > 0) into `work`; returns the encoder's maxima (the
    /// largest |mᵢ| bits, at most f32::MAX's, and the largest Sᵢ bits as i32).
    #[inline(always)]
    fn merged_into(&self, new: &ObsStats<D>, work: &mut ObsStats<D>) -> (u32, i32) {
        // As `combine` (stats.rs) with k = 1: k̄ = n₁, gain = k̄/(n₀ + k̄), cross = n₀·gain; S̄ = 1·S₁.
        let (weight, k_bar) = (self.count, new.count);
        let total = weight + k_bar;
        let gain = k_bar / total;
        let cross = weight * gain;
        let scale = super::scale_to_f32(self.mu_scale);
        let base = u32::from(self.psi_base);
        let (mu_part, psi_part) = self.codes.split_at(section_len(D, MU_BITS));
        let (mu8s, _) = mu_part.as_chunks::<{ MU_BITS as usize }>();
        let (psi8s, _) = psi_part.as_chunks::<{ PSI_BITS as usize }>();
        let (wm8s, _) = work.mean.as_chunks_mut::<8>();
        let (ws8s, _) = work.scatter.as_chunks_mut::<8>();
        let (nm8s, _) = new.mean.as_chunks::<8>();
        let (ns8s, _) = new.scatter.as_chunks::<8>();
        let mut mean_max = 0u32;
        let mut scatter_max = 0i32;
        let codes = mu8s.iter().zip(psi8s);
        let outs = wm8s.iter_mut().zip(ws8s.iter_mut());
        let ins = nm8s.iter().zip(ns8s);
        for (((mu8, psi8), (wm, ws)), (nm, ns)) in codes.zip(outs).zip(ins) {
            // Unrolled by hand: every code's shift a constant (a Cortex-M4 shifts a u64 by a variable in
            // ≈ 8 instructions; rolled, the pass cost 50 a dimension).
            let (macc, pacc) = (le_u64(mu8), le_u64(psi8));
            let mut dim = |j: usize| {
                let c = ((macc >> (j as u32 * MU_BITS)) & ((1 << MU_BITS) - 1)) as u32;
                let k = ((pacc >> (j as u32 * PSI_BITS)) & ((1 << PSI_BITS) - 1)) as u32;
                // The decode (`unpack_into`): the sign-extended code times the scale; the key's bits.
                let mut m = ((c << (32 - MU_BITS)) as i32 >> (32 - MU_BITS)) as f32 * scale;
                let mut s = f32::from_bits((k + base) << PSI_SHIFT);
                update_dim(&mut m, &mut s, gain, cross, nm[j], 1.0 * ns[j]);
                wm[j] = m;
                ws[j] = s;
                // The maxima (`reencode_in`), on the bit patterns.
                mean_max = mean_max.max(m.to_bits() & 0x7FFF_FFFF);
                scatter_max = scatter_max.max(s.to_bits() as i32);
            };
            dim(0);
            dim(1);
            dim(2);
            dim(3);
            dim(4);
            dim(5);
            dim(6);
            dim(7);
        }
        work.count = total;
        (mean_max.min(f32::MAX.to_bits()), scatter_max)
    }
}

/// Up to 8 bytes as a little-endian u64 (the rest zero).
#[inline(always)]
fn le_u64(src: &[u8]) -> u64 {
    let mut bytes = [0u8; 8];
    for (b, s) in bytes.iter_mut().zip(src) {
        *b = *s;
    }
    u64::from_le_bytes(bytes)
}

#[cfg(test)]
mod tests {
    use super::super::{packed_len, Dither, QuantVoxel};
    use crate::obs::ObsStats;

    const D: usize = 64;
    const P: usize = packed_len(D);

    /// A small deterministic generator for the cases.
    fn lcg(state: &mut u32) -> f32 {
        *state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (*state >> 8) as f32 / (1u32 << 24) as f32
    }

    fn stats(state: &mut u32, count: f32, spread: f32, scatter: f32) -> ObsStats<D> {
        ObsStats {
            count,
            mean: core::array::from_fn(|_| (lcg(state) - 0.5) * spread),
            scatter: core::array::from_fn(|_| {
                let u = lcg(state);
                if scatter == 0.0 || u < 0.1 {
                    0.0
                } else {
                    u * scatter
                }
            }),
        }
    }

    /// The one pass gives the general cooling's codes bit for bit — decode, Chan's merge, the re-encode —
    /// on both grids, for voxels of one point and of many, new sets of one point and of many, means that
    /// keep the scale and means that move it (up and down), and the dither state after.
    #[test]
    fn one_pass_equals_decode_merge_encode() {
        let mut state = 7u32;
        let mut cases = 0;
        for fine in [false, true] {
            for &(n0, spread0, scatter0) in &[
                (1.0, 2.0, 0.0),
                (2.0, 0.5, 0.3),
                (17.0, 1.0, 4.0),
                (400.0, 0.01, 1e-3),
                (3.0, 200.0, 9e4),
            ] {
                for &(n1, spread1, scatter1) in &[
                    (1.0, 2.0, 0.0),
                    (1.0, 0.001, 0.0),
                    (3.0, 1.0, 0.5),
                    (50.0, 40.0, 100.0),
                    (0.0, 1.0, 0.0),
                ] {
                    for seed in 1..6u32 {
                        let old = stats(&mut state, n0, spread0, scatter0);
                        let new = stats(&mut state, n1, spread1, scatter1);
                        let mut dither = Dither::new(seed * 97);
                        let start = if fine {
                            QuantVoxel::<D, P>::EMPTY.reencode_fine(&old, &mut dither)
                        } else {
                            QuantVoxel::<D, P>::EMPTY.reencode(&old, &mut dither)
                        };
                        let (mut d_ref, mut d_one) = (dither.clone(), dither.clone());
                        let mut merged = start.decode();
                        merged.merge(&new);
                        let reference = if fine {
                            start.reencode_fine(&merged, &mut d_ref)
                        } else {
                            start.reencode(&merged, &mut d_ref)
                        };
                        let mut one = start;
                        let mut work = ObsStats::EMPTY;
                        one.merge_here(fine, &new, &mut work, &mut d_one);
                        if n1 > 0.0 {
                            assert_eq!(
                                one, reference,
                                "fine {fine}, n0 {n0}, n1 {n1}, seed {seed}"
                            );
                            assert_eq!(d_one.next(), d_ref.next(), "the same dither consumed");
                            assert_eq!(work, merged, "the merged statistics left in `work`");
                        } else {
                            // Nothing merged: the codes and the dither untouched.
                            assert_eq!(one, start, "fine {fine}, n0 {n0}, seed {seed}");
                            assert_eq!(d_one.next(), dither.clone().next());
                        }
                        cases += 1;
                    }
                }
            }
        }
        assert_eq!(cases, 250);
    }

    /// A first visit of one int8 point gives the general cooling's codes bit for bit: empty statistics
    /// merged with the sums ([`ObsStats::merge_codes`]) and re-encoded, on both grids, codes from −128 to
    /// 127 (zeros among them) and scales small and large; the same dither consumed.
    #[test]
    fn one_int8_point_equals_the_general_cooling() {
        let mut state = 11u32;
        let mut cases = 0;
        for fine in [false, true] {
            for &scale in &[1e-4f32, 0.0123, 0.5, 3.0, 700.0] {
                for seed in 1..21u32 {
                    let codes: [i8; D] = core::array::from_fn(|i| match (seed + i as u32) % 9 {
                        0 => -128,
                        1 => 127,
                        2 => 0,
                        _ => ((lcg(&mut state) - 0.5) * 255.0) as i8,
                    });
                    let mut sums = crate::obs::CodeSums::<D>::EMPTY;
                    sums.add(&codes);
                    let dither = Dither::new(seed * 31);
                    let (mut d_ref, mut d_one) = (dither.clone(), dither.clone());
                    let mut merged = ObsStats::EMPTY;
                    merged.merge_codes(&sums, scale);
                    let empty = QuantVoxel::<D, P>::EMPTY;
                    let reference = if fine {
                        empty.reencode_fine(&merged, &mut d_ref)
                    } else {
                        empty.reencode(&merged, &mut d_ref)
                    };
                    let mut one = empty;
                    let mut work = ObsStats {
                        count: 9.0,
                        mean: [3.0; D],
                        scatter: [5.0; D],
                    };
                    one.encode_lone_codes_here(fine, &sums, scale, &mut work, &mut d_one);
                    assert_eq!(one, reference, "fine {fine}, scale {scale}, seed {seed}");
                    assert_eq!(d_one.next(), d_ref.next(), "the same dither consumed");
                    cases += 1;
                }
            }
        }
        assert_eq!(cases, 200);
    }
}
