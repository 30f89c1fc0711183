//! Merging new f32 statistics into a voxel's codes in one pass: what the local map's cooling does when a
//! voxel seen before turns cold.
//!
//! Why: decode → merge → re-encode walks the 64 dimensions four times (decode into a scratch, Chan's merge
//! in it, the two maxima the encoder needs, the codes) and stores and reloads every value in between. On a
//! sparse sensor (8×8 ToF, scanning LiDAR) nearly every point cools a voxel, so that walk is paid per point.
//! Here one pass unpacks each dimension's codes, merges it with the new statistics by the same
//! [`update_dim`] (so the result is bit for bit what the three steps give: tested) and keeps the maxima as
//! it goes; the encoder then reads the merged values once.

use super::{section_len, Dither, QuantVoxel, MU_BITS, PSI_BITS, PSI_SHIFT};
use crate::obs::ObsStats;
use crate::stats::update_dim;

impl<const D: usize, const P: usize> QuantVoxel<D, P> {
    /// These codes merged with `new` (Chan's formula, exact up to f32 rounding) and re-encoded in place,
    /// keeping the mean's scale when it still fits: equal, bit for bit, to
    /// `self.reencode(&{ let mut s = self.decode(); s.merge(new); s }, dither)`. `scratch` receives the
    /// merged statistics (so the caller needs no 516-byte temporary). Empty `new` changes nothing.
    pub fn merge_here(
        &mut self,
        new: &ObsStats<D>,
        scratch: &mut ObsStats<D>,
        dither: &mut Dither,
    ) {
        if new.is_empty() {
            return;
        }
        if D % 8 != 0 {
            // Not in eights (no map of the project's): the three steps.
            self.decode_into(scratch);
            scratch.merge(new);
            self.reencode_here(scratch, dither);
            return;
        }
        let n0 = self.count;
        let total = n0 + new.count;
        let gain = new.count / total;
        let cross = n0 * gain;
        let scale = self.mu_scale.to_f32();
        let base = u32::from(self.psi_base);
        let (mu_part, psi_part) = self.codes.split_at(section_len(D, MU_BITS));
        let (mut mean_max, mut scatter_max) = (0u32, 0i32);
        // Whole eights as arrays, so every shift is a constant and the eight steps unroll (as `decode_into`).
        let (means, _) = scratch.mean.as_chunks_mut::<8>();
        let (scatters, _) = scratch.scatter.as_chunks_mut::<8>();
        let (ys, _) = new.mean.as_chunks::<8>();
        let (ss, _) = new.scatter.as_chunks::<8>();
        let (mus, _) = mu_part.as_chunks::<{ MU_BITS as usize }>();
        let (psis, _) = psi_part.as_chunks::<{ PSI_BITS as usize }>();
        let eights = means
            .iter_mut()
            .zip(scatters.iter_mut())
            .zip(ys.iter().zip(ss))
            .zip(mus.iter().zip(psis));
        for (((mean, scatter), (y, s)), (mu_src, psi_src)) in eights {
            let (mu, psi) = (le_u64(mu_src), le_u64(psi_src));
            let mut dim = |i: usize| {
                // The codes as `decode_into` reads them.
                let c = ((mu >> (i as u32 * MU_BITS)) as u32) << (32 - MU_BITS);
                let mut m = (c as i32 >> (32 - MU_BITS)) as f32 * scale;
                let p = ((psi >> (i as u32 * PSI_BITS)) as u32) & ((1 << PSI_BITS) - 1);
                let mut sc = f32::from_bits((p + base) << PSI_SHIFT);
                update_dim(&mut m, &mut sc, gain, cross, y[i], s[i]);
                mean_max = mean_max.max(m.to_bits() & 0x7FFF_FFFF);
                scatter_max = scatter_max.max(sc.to_bits() as i32);
                mean[i] = m;
                scatter[i] = sc;
            };
            // Unrolled by hand: constant shifts (LLVM unrolls the loop by two only, with variable 64-bit
            // shifts: ≈ 50 instructions a dimension on a Cortex-M4).
            dim(0);
            dim(1);
            dim(2);
            dim(3);
            dim(4);
            dim(5);
            dim(6);
            dim(7);
        }
        scratch.count = total;
        self.encode_in::<false>(
            scratch,
            mean_max.min(f32::MAX.to_bits()),
            scatter_max,
            dither,
        );
    }
}

/// Up to 8 bytes, little-endian (missing high bytes zero).
#[inline(always)]
fn le_u64<const N: usize>(src: &[u8; N]) -> u64 {
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

    /// The one-pass merge gives the codes decode → merge → re-encode gives, bit for bit, and the merged
    /// statistics in the scratch: single points and batches, small and large spreads, zero scatters.
    #[test]
    fn one_pass_merge_equals_decode_merge_encode() {
        let mut rng = Dither::new(29);
        let mut unit = || (rng.next() >> 8) as f32 / (1 << 24) as f32;
        let (mut a, mut b) = (Dither::new(4), Dither::new(4));
        let mut codes = QuantVoxel::<D, P>::EMPTY;
        for round in 0..600 {
            let spread = [0.01, 1.0, 100.0, 3.0][round % 4];
            let one = round % 3 != 0;
            let mut new = ObsStats::<D> {
                count: if one { 1.0 } else { 1.0 + (round % 7) as f32 },
                ..ObsStats::EMPTY
            };
            for i in 0..D {
                new.mean[i] = (unit() - 0.5) * spread;
                new.scatter[i] = if one { 0.0 } else { unit() * spread };
            }
            if codes.count == 0.0 {
                codes = QuantVoxel::encode(&new, &mut a);
                b = a.clone();
                continue;
            }
            let mut want = codes.decode();
            want.merge(&new);
            let want_codes = codes.reencode(&want, &mut a);
            let mut scratch = ObsStats::EMPTY;
            codes.merge_here(&new, &mut scratch, &mut b);
            assert_eq!(codes, want_codes, "round {round}");
            assert_eq!(scratch, want, "round {round}");
            if round % 50 == 49 {
                codes = QuantVoxel::EMPTY; // a new voxel now and then: fresh scales
            }
        }
    }
}
