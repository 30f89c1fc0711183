//! A voxel's codes as bytes, borrowed as the map holds them ([`StoredCodes`]), and decoded from bytes by
//! the same unpacking [`QuantVoxel::decode_into`] uses: what a link that carries the store's own codes
//! (`wire::SummaryCodec::stored`) needs on both ends. The sender copies bytes (no decode, no float); the
//! receiver, which knows D but not the map's `P`, decodes them here.

use super::{section_len, unpack_into, QuantVoxel, Section, MU_BITS, PSI_BITS, PSI_SHIFT};
use super::{PSI_CODE_MAX, PSI_STEPS_LOG2};
use crate::obs::ObsStats;
use half::f16;

/// The layout constants of stored codes ([`MU_BITS`], [`PSI_BITS`], [`PSI_STEPS_LOG2`]): a receiver
/// decodes a sender's stored codes only if they are its own.
pub const STORED_LAYOUT: [u8; 3] = [MU_BITS as u8, PSI_BITS as u8, PSI_STEPS_LOG2 as u8];

/// Bytes of a D-dimensional voxel's packed mean codes.
pub const fn mean_codes_len(d: usize) -> usize {
    section_len(d, MU_BITS)
}

/// Bytes of a D-dimensional voxel's packed scatter codes.
pub const fn scatter_codes_len(d: usize) -> usize {
    section_len(d, PSI_BITS)
}

/// Largest scatter base whose codes all decode to finite values: (code + base) << PSI_SHIFT stays below
/// the all-ones exponent.
const PSI_BASE_MAX: u32 = (0x7F80_0000 >> PSI_SHIFT) - 1 - PSI_CODE_MAX;

/// A voxel's codes, borrowed as its map holds them: the exact count, the mean scale (f16 bits), the
/// scatter base, and the packed codes (mean section, then scatter section: [`super::packed_len`] bytes; or
/// the mean section alone, for a voxel of one point: its scatter codes are all zero on base 0).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StoredCodes<'a> {
    /// n, exact.
    pub count: f32,
    /// The mean codes' scale, as f16 bits.
    pub mean_scale: u16,
    /// The scatter codes' base.
    pub psi_base: u16,
    /// The packed codes: [`mean_codes_len`] bytes of mean codes, then [`scatter_codes_len`] of scatter.
    pub packed: &'a [u8],
}

impl<const D: usize, const P: usize> QuantVoxel<D, P> {
    /// Its codes, borrowed (nothing decoded).
    pub fn stored(&self) -> StoredCodes<'_> {
        StoredCodes {
            count: self.count,
            mean_scale: self.mu_scale.to_bits(),
            psi_base: self.psi_base,
            packed: &self.codes,
        }
    }
}

impl StoredCodes<'_> {
    /// Decode D-dimensional statistics (the weighed mean, as the codes hold it: a map with
    /// [`super::MeanWeights`] weighs it back) into `out`, by [`QuantVoxel::decode_into`]'s unpacking.
    /// `None` (and `out` untouched) unless the bytes are the codes of a valid voxel: `packed` of
    /// [`super::packed_len`]`(D)` bytes (or the mean section alone, on base 0), a finite non-negative
    /// scale, a scatter base whose codes are all finite, a finite non-negative count.
    pub fn decode_into<const D: usize>(&self, out: &mut ObsStats<D>) -> Option<()> {
        let scale = f16::from_bits(self.mean_scale);
        let mean_only = self.packed.len() == mean_codes_len(D) && self.psi_base == 0;
        let valid = (mean_only || self.packed.len() == mean_codes_len(D) + scatter_codes_len(D))
            && scale.is_finite()
            && !scale.is_sign_negative()
            && u32::from(self.psi_base) <= PSI_BASE_MAX
            && self.count.is_finite()
            && self.count >= 0.0;
        if !valid {
            return None;
        }
        let (mu_part, psi_part) = self.packed.split_at(mean_codes_len(D));
        out.count = self.count;
        unpack_into(
            mu_part,
            MU_BITS,
            &mut out.mean,
            Section::Mean(scale.to_f32()),
        );
        if mean_only {
            // What zero codes on base 0 decode to.
            out.scatter = [0.0; D];
        } else {
            let base = u32::from(self.psi_base);
            unpack_into(psi_part, PSI_BITS, &mut out.scatter, Section::Scatter(base));
        }
        Some(())
    }
}

#[cfg(test)]
mod tests {
    use super::super::{packed_len, Dither};
    use super::*;

    const D: usize = 64;
    const P: usize = packed_len(D);

    #[test]
    fn stored_codes_decode_as_the_voxel_does_and_bad_ones_are_refused() {
        let mut d = Dither::new(9);
        let s = ObsStats::<D> {
            count: 7.0,
            mean: core::array::from_fn(|i| ((i as f32) * 0.3).sin()),
            scatter: core::array::from_fn(|i| 0.1 + i as f32),
        };
        let q = QuantVoxel::<D, P>::encode(&s, &mut d);
        let mut out = ObsStats::EMPTY;
        assert_eq!(q.stored().decode_into(&mut out), Some(()));
        assert_eq!(out, q.decode());
        let bad = [
            StoredCodes {
                mean_scale: f16::INFINITY.to_bits(),
                ..q.stored()
            },
            StoredCodes {
                mean_scale: f16::NAN.to_bits(),
                ..q.stored()
            },
            StoredCodes {
                mean_scale: f16::from_f32(-1.0).to_bits(),
                ..q.stored()
            },
            StoredCodes {
                psi_base: PSI_BASE_MAX as u16 + 1,
                ..q.stored()
            },
            StoredCodes {
                count: f32::NAN,
                ..q.stored()
            },
            StoredCodes {
                packed: &q.codes[1..],
                ..q.stored()
            },
            StoredCodes {
                packed: &q.codes[..mean_codes_len(D)],
                ..q.stored()
            },
        ];
        for b in bad {
            let mut o = ObsStats::<D>::EMPTY;
            assert_eq!(b.decode_into(&mut o), None, "{b:?}");
        }
        // A voxel of one point: the mean section alone, on base 0.
        let one = QuantVoxel::<D, P>::encode(
            &ObsStats {
                count: 1.0,
                scatter: [0.0; D],
                ..s
            },
            &mut d,
        );
        let mean_only = StoredCodes {
            packed: &one.codes[..mean_codes_len(D)],
            ..one.stored()
        };
        assert_eq!(mean_only.decode_into(&mut out), Some(()));
        assert_eq!(out, one.decode());
        // The largest base: every code finite.
        let top = [0xFFu8; P];
        let b = StoredCodes {
            psi_base: PSI_BASE_MAX as u16,
            packed: &top,
            ..q.stored()
        };
        assert_eq!(b.decode_into(&mut out), Some(()));
        assert!(out.is_valid());
    }
}
