//! Stored codes ([`SummaryCodec::STORED`]): a summary's code section is the voxel's codes as the robot's
//! map holds them ([`crate::quant::StoredCodes`]), so an eviction copies bytes — no decode, no float, no
//! re-encode — and the base station decodes them with the map's own unpacking. Why: a sparse sensor (an
//! 8×8 ToF) evicts about a voxel every second point, and decoding a voxel and coding it again for the wire
//! cost ≈ 3,000 instructions per eviction on a Cortex-M4F and tens of thousands in soft float on an MCU
//! without an FPU. The price is bytes: ≈ 100 per summary at D = 64 against ≈ 55 for 6-bit packed codes.
//!
//! Layout (D-dimensional, little-endian): the mean scale (f16 bits, 2 B), the scatter base (u16, 2 B), the
//! packed mean codes ([`crate::quant::mean_codes_len`]), the packed scatter codes
//! ([`crate::quant::scatter_codes_len`]). A summary of one point (unstamped count 1) has no scatter: the
//! scale and the mean codes only. The layout constants (code widths, scatter steps per octave) are part of
//! the protocol version (`wire_spec.md`).

use super::SummaryCodec;
#[cfg(feature = "stored-codes")]
use super::WireError;
#[cfg(feature = "stored-codes")]
use crate::obs::ObsStats;
#[cfg(feature = "stored-codes")]
use crate::quant::{mean_codes_len, scatter_codes_len, StoredCodes};

/// [`SummaryCodec::mean_bits`] of [`SummaryCodec::STORED`]: 255, no packed width.
pub const STORED_MARK: u8 = u8::MAX;

impl SummaryCodec {
    /// The map's own codes, verbatim (`wire::codec`'s stored codes, `wire_spec.md`): `mean_bits` [`STORED_MARK`] marks the
    /// mode (no packed codec has it), the other fields are not used. Feature `stored-codes`.
    pub const STORED: Self = Self {
        mean_bits: STORED_MARK,
        ..Self::DEFAULT
    };

    /// Whether summaries carry the map's own codes ([`Self::STORED`]); always false without
    /// `stored-codes` (a session asking for them is then refused: its `mean_bits` are out of range).
    #[inline]
    pub const fn is_stored(self) -> bool {
        cfg!(feature = "stored-codes") && self.mean_bits == STORED_MARK && !self.is_rice()
    }
}

/// Bytes of stored codes of a D-dimensional summary of `count` points (the scale and the mean codes; with
/// two points or more, the scatter base and codes too).
#[cfg(feature = "stored-codes")]
pub(super) const fn len(dim: usize, count: u32) -> usize {
    let mean = 2 + mean_codes_len(dim);
    if count < 2 {
        mean
    } else {
        mean + 2 + scatter_codes_len(dim)
    }
}

/// Write a D-dimensional voxel's codes as a summary of `class` points (`len(D, class)` bytes) into `out`. One
/// point has no scatter (its codes are all zero on base 0), so none is sent.
#[cfg(feature = "stored-codes")]
pub fn write_stored<const D: usize>(
    codes: &StoredCodes<'_>,
    class: u32,
    out: &mut [u8],
) -> Result<usize, WireError> {
    if codes.packed.len() != mean_codes_len(D) + scatter_codes_len(D) {
        return Err(WireError::BadConfig);
    }
    let out = out.get_mut(..len(D, class)).ok_or(WireError::BufferFull)?;
    let (scale, rest) = out.split_at_mut(2);
    scale.copy_from_slice(&codes.mean_scale.to_le_bytes());
    match rest.split_first_chunk_mut::<2>() {
        Some((base, rest)) if class >= 2 => {
            base.copy_from_slice(&codes.psi_base.to_le_bytes());
            copy_exactly(rest, codes.packed)?;
        }
        _ => copy_exactly(
            rest,
            codes.packed.get(..mean_codes_len(D)).unwrap_or_default(),
        )?,
    }
    Ok(out.len())
}

/// `dst` ← `src`, refused unless their lengths agree (never `copy_from_slice`'s panic: the firmware's
/// `panic-never` build proves the eviction path has none).
#[cfg(feature = "stored-codes")]
fn copy_exactly(dst: &mut [u8], src: &[u8]) -> Result<(), WireError> {
    if dst.len() != src.len() {
        return Err(WireError::BadConfig);
    }
    for (d, s) in dst.iter_mut().zip(src) {
        *d = *s;
    }
    Ok(())
}

/// Decode stored codes sized for a summary of `n` points into statistics of weight `count`.
#[cfg(feature = "stored-codes")]
pub(super) fn decode<const D: usize>(
    n: u32,
    count: f32,
    bytes: &[u8],
) -> Result<ObsStats<D>, WireError> {
    let scale = bytes.get(..2).ok_or(WireError::Truncated)?;
    let mean_scale = u16::from_le_bytes([scale[0], scale[1]]);
    let (psi_base, packed) = if n < 2 {
        (0, bytes.get(2..len(D, n)).ok_or(WireError::Truncated)?)
    } else {
        let base = bytes.get(2..4).ok_or(WireError::Truncated)?;
        (
            u16::from_le_bytes([base[0], base[1]]),
            bytes.get(4..len(D, n)).ok_or(WireError::Truncated)?,
        )
    };
    let codes = StoredCodes {
        count,
        mean_scale,
        psi_base,
        packed,
    };
    let mut obs = ObsStats::EMPTY;
    codes.decode_into(&mut obs).ok_or(WireError::Malformed)?;
    Ok(obs)
}

/// Largest error of a decoded mean: stochastic rounding lands on one of a value's two neighbouring codes,
/// so within one step (the scale) per component.
#[cfg(feature = "stored-codes")]
pub(super) fn error_bound(dim: usize, codes: &[u8]) -> f32 {
    let scale = match codes {
        [a, b, ..] => half::f16::from_bits(u16::from_le_bytes([*a, *b])).to_f32(),
        _ => 0.0,
    };
    libm::sqrtf(dim as f32) * scale
}

#[cfg(all(test, feature = "stored-codes"))]
mod tests;
