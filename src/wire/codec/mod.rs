//! How a voxel's observations (n, m, S) become the ≈ 30 code bytes of a summary, and back: m rotated by a
//! Walsh–Hadamard transform and quantized against a per-voxel scale, S as its largest entry and block means
//! (they merge exactly). The bytes around them (keys, residency, count) are [`super::summary`]'s.
//!
//! Why a lead band ([`SummaryCodec::lead`]): features reach the robot PCA-reduced, so their leading
//! components carry the classes and most of the energy (on the demo's tile the first 5 of 64 hold ≈ 88 % of
//! ‖m‖², the other 59 hold equal shares of noise). One rotation over all 64 spreads that energy evenly and
//! spends the same bits on signal and noise; coding the leading components as a band of their own with more
//! bits is the classic transform coder's bit allocation (more bits where the variance is), and it is what
//! argmax agreement needs: on the demo's map 8 leading components at +3 bits reach 99.95 % for 4 B more
//! per summary, where one more bit everywhere reaches 99.88 % for 8 B (`demo --codec-study`). The other
//! components then grow by half a bit per doubling of n ([`SummaryCodec::rest_bits_for`]), which saves
//! 3.2 B per summary there for RMS ‖Δμ‖/‖μ‖ 0.042 instead of 0.039 against the robot's map.

use super::WireError;
use crate::f32math;
use crate::obs::ObsStats;
use core::num::NonZeroUsize;
use serde::{Deserialize, Serialize};

mod rice_codes;
mod stored;
mod transform;
mod wire_count;
pub use rice_codes::encode_rice;
pub(crate) use rice_codes::{decode_rice_at, encode_rice_at, rice_end};
#[cfg(feature = "stored-codes")]
pub use stored::write_stored;
pub use stored::STORED_MARK;
#[cfg(test)]
pub(super) use transform::hadamard;
use transform::{decode_band, encode_band, max_or_zero, rotate};
pub use wire_count::wire_count;

/// How voxel summaries are quantized. Part of the session configuration.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SummaryCodec {
    /// Bits per (rotated) mean component of a one-point summary, 2..=8.
    pub mean_bits: u8,
    /// Number of blocks the scatter's block means are sent for, 1..=min(D, 64).
    pub psi_blocks: u8,
    /// Most bits added to `mean_bits` for summaries of more points: one per doubling of the point count
    /// n, up to this many (and 8 in all). A receiver gathers means weighted by n, so a voxel of many points
    /// moves a posterior more than one of few: its mean gets the finer codes. 0 = every summary `mean_bits`.
    pub mean_bits_growth: u8,
    /// L: the first L (leading, e.g. PCA) mean components are coded as a band of their own, with its own
    /// scale and `lead_bits` more bits per component; 0 = one band of all D (L < D). With a lead band, the
    /// other components' bits grow by one per *two* doublings of n (see [`Self::rest_bits_for`]).
    pub lead: u8,
    /// Bits added per component of the lead band, 0..=6 (8 in all at most).
    pub lead_bits: u8,
    /// The mean bands are Rice-coded ([`super::rice`]) instead of packed: the steps are the sender's
    /// choice and `mean_bits`, `mean_bits_growth` and `lead_bits` are not used (`lead` is). Not a postcard
    /// field: it travels as the session message's 1-byte extension ([`super::encode_body`]), so sessions
    /// with packed codes send the bytes they always did. (Only with the `rice-codes` feature: a firmware
    /// built without it links none of this.)
    #[cfg(feature = "rice-codes")]
    #[serde(skip)]
    pub rice: bool,
}

impl Default for SummaryCodec {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl SummaryCodec {
    /// 3-bit means, 8 scatter blocks: at D = 64, 30 code bytes + 1–3 bytes of count + 4–6 bytes of key and
    /// residency deltas (see the README for the measured argmax agreement).
    pub const DEFAULT: Self = Self {
        mean_bits: 3,
        psi_blocks: 8,
        mean_bits_growth: 0,
        lead: 0,
        lead_bits: 0,
        #[cfg(feature = "rice-codes")]
        rice: false,
    };

    /// Whether the mean bands are Rice-coded ([`Self::rice`]); always false without `rice-codes`.
    #[inline]
    pub const fn is_rice(self) -> bool {
        #[cfg(feature = "rice-codes")]
        return self.rice;
        #[cfg(not(feature = "rice-codes"))]
        return false;
    }

    /// Whether this codec can encode D-dimensional voxels.
    pub fn validate(self, dim: usize) -> Result<(), WireError> {
        let blocks = usize::from(self.psi_blocks);
        if dim == 0 || dim > u16::MAX as usize {
            return Err(WireError::BadConfig);
        }
        #[cfg(feature = "stored-codes")]
        if self.is_stored() {
            return Ok(());
        }
        if !(2..=8).contains(&self.mean_bits) || blocks == 0 || blocks > dim.min(64) {
            return Err(WireError::BadConfig);
        }
        if self.mean_bits_growth > 6 || self.lead_bits > 6 || usize::from(self.lead) >= dim {
            return Err(WireError::BadConfig);
        }
        Ok(())
    }

    /// Bits per mean component of a summary of `count` points: `mean_bits` + min(⌊log₂ n⌋,
    /// `mean_bits_growth`), at most 8.
    pub const fn bits_for(self, count: u32) -> u32 {
        self.grown_bits(if count > 1 { count.ilog2() } else { 0 })
    }

    /// `mean_bits` + min(`grow`, `mean_bits_growth`), at most 8: the width rule [`Self::bits_for`] and
    /// [`Self::rest_bits_for`] share, each with its own growth per doubling of the count.
    const fn grown_bits(self, grow: u32) -> u32 {
        let growth = self.mean_bits_growth as u32;
        let bits = self.mean_bits as u32 + if grow < growth { grow } else { growth };
        if bits < 8 {
            bits
        } else {
            8
        }
    }

    /// Bits per mean component outside the lead band of a summary of `count` points. Without a lead band,
    /// [`Self::bits_for`]. With one, `mean_bits` + min(⌈⌊log₂ n⌋/2⌉, `mean_bits_growth`), at most 8: those
    /// components carry the features' noise, whose energy in a mean of n points falls as 1/n while its
    /// weight in a gather grows as n, so half a bit per doubling keeps its error's share constant (the
    /// lead band's signal does not shrink with n: it takes a whole bit per doubling).
    pub const fn rest_bits_for(self, count: u32) -> u32 {
        if self.lead == 0 {
            return self.bits_for(count);
        }
        self.grown_bits(if count > 1 {
            count.ilog2().div_ceil(2)
        } else {
            0
        })
    }

    /// Bits per component of the lead band of a summary of `count` points: [`Self::bits_for`] +
    /// `lead_bits`, at most 8.
    pub const fn lead_bits_for(self, count: u32) -> u32 {
        let bits = self.bits_for(count) + self.lead_bits as u32;
        if bits < 8 {
            bits
        } else {
            8
        }
    }

    /// Bytes of the lead band (its scale and codes; 0 without one) of a summary of `count` points.
    pub const fn lead_len_for(self, count: u32) -> usize {
        band_len(self.lead as usize, self.lead_bits_for(count))
    }

    /// Bytes of the mean (lead band, then the other components' scale and codes) of a D-dimensional
    /// summary of `count` points (Rice-coded: the most they take, see [`Self::codes_len`]).
    pub const fn mean_len_for(self, dim: usize, count: u32) -> usize {
        if self.is_rice() {
            return super::rice::cap(dim, self.lead as usize);
        }
        let rest = dim.saturating_sub(self.lead as usize);
        self.lead_len_for(count) + band_len(rest, self.rest_bits_for(count))
    }

    /// Bytes of the quantized part (mean scale, mean codes, and — for n ≥ 2 — the scatter) of a
    /// D-dimensional summary of `count` points. A single point has no scatter, so none is sent. (Not
    /// inlined: one copy in flash for its callers on the robot.)
    #[inline(never)]
    pub const fn code_len_for(self, dim: usize, count: u32) -> usize {
        #[cfg(feature = "stored-codes")]
        if self.is_stored() {
            return stored::len(dim, count);
        }
        let mean = self.mean_len_for(dim, count);
        if count < 2 {
            mean
        } else {
            mean + 1 + (self.psi_blocks as usize).div_ceil(2)
        }
    }

    /// Bytes of the quantized part at the start of `codes`, a summary of `count` points: packed,
    /// [`Self::code_len_for`]; Rice-coded, what its bit stream takes (read from it), plus the scatter.
    pub fn codes_len(self, dim: usize, count: u32, codes: &[u8]) -> Result<usize, WireError> {
        if !self.is_rice() {
            return Ok(self.code_len_for(dim, count));
        }
        Ok(rice_end::<0>(self, dim, count, codes, 0)?.div_ceil(8))
    }

    /// Bytes of the scatter of a summary of `count` points (none for one point).
    pub const fn scatter_len(self, count: u32) -> usize {
        if count < 2 || (cfg!(feature = "stored-codes") && self.is_stored()) {
            0
        } else {
            1 + (self.psi_blocks as usize).div_ceil(2)
        }
    }

    /// The largest quantized part of a D-dimensional summary (any point count).
    pub const fn code_len(self, dim: usize) -> usize {
        self.code_len_for(dim, MAX_COUNT)
    }

    /// Largest wire size of one summary: packed, 5-byte key deltas and residency field, a 4-byte count,
    /// then the codes; Rice-coded, a head of at most [`super::rice::HEAD_MAX_BITS`] bits, then codes of
    /// at most [`Self::code_len`] bytes in the same bit stream.
    pub const fn max_summary_len(self, dim: usize) -> usize {
        if self.is_rice() {
            return super::rice::HEAD_MAX_BITS.div_ceil(8) + self.code_len(dim);
        }
        PACKED_HEAD_MAX + self.code_len(dim)
    }
}

/// Most bytes of a packed summary's head: 5-byte key deltas and residency field, a 4-byte count.
pub const PACKED_HEAD_MAX: usize = 3 * 5 + 5 + 4;

/// log₂ steps per code of the μ scale and of Ψ's largest entry.
const SCALE_STEPS_PER_OCTAVE: u32 = 8;
/// Code 0 means "zero"; code c ≥ 1 means 2^((c − SCALE_OFFSET) / 8).
const SCALE_OFFSET: i32 = 128;
const PSI_OFFSET: i32 = 96;
/// Ψ's block means relative to its maximum: 2^(−c/2), c = 0..=15.
const BLOCK_STEPS_PER_OCTAVE: u32 = 2;

// Powers and logarithms come from `f32math` (f32 only; libm's `log2f`/`exp2f` evaluate in f64, soft-float
// on the device): codes are exact with respect to the decoder's values, `log_value(log_code_up(x)) ≥ x`.

/// Smallest code whose value is ≥ x (x > 0), in 1..=255.
fn log_code_up(x: f32, offset: i32) -> u8 {
    let c = f32math::log2_steps_up(x, SCALE_STEPS_PER_OCTAVE).saturating_add(offset);
    c.clamp(1, 255) as u8
}

#[inline(never)]
fn log_value(code: u8, offset: i32) -> f32 {
    if code == 0 {
        0.0
    } else {
        f32math::pow2_steps(i32::from(code) - offset, SCALE_STEPS_PER_OCTAVE)
    }
}

/// The nearest whole number of `steps`-per-octave steps in log₂ `ratio` (ratio ≥ 1), clamped to 0..=top.
fn ratio_steps(log_ratio: f32, steps: u32, top: u8) -> u8 {
    libm::roundf(log_ratio * steps as f32).clamp(0.0, f32::from(top)) as u8
}

pub(super) fn block_range(dim: usize, blocks: NonZeroUsize, b: usize) -> core::ops::Range<usize> {
    (b * dim / blocks)..((b + 1) * dim / blocks)
}

/// Largest point count a summary carries: f32 counts exactly up to 2²⁴.
pub const MAX_COUNT: u32 = 1 << 24;

/// The size class of a stamped summary's codes ([`super::summary`]: forgetting): its weight n rounded
/// up, at least 2 (a faded voxel's scatter is sent even below two points' weight), at most
/// [`MAX_COUNT`]. `None` unless n is finite and in (0, [`MAX_COUNT`]].
pub fn stamped_class(n: f32) -> Option<u32> {
    (n > 0.0 && n <= MAX_COUNT as f32).then(|| (libm::ceilf(n) as u32).clamp(2, MAX_COUNT))
}

/// Write the quantized part (mean scale, mean codes, scatter) of observation statistics into
/// `out[..codec.code_len(D)]`.
pub fn encode_codes<const D: usize>(
    codec: SummaryCodec,
    stats: &ObsStats<D>,
    out: &mut [u8],
) -> Result<usize, WireError> {
    encode_codes_as(codec, stats, wire_count(stats.count).unwrap_or(1), out)
}

/// [`encode_codes`] with the codes sized for a summary of `count` points (a stamped summary's
/// [`stamped_class`]).
pub fn encode_codes_as<const D: usize>(
    codec: SummaryCodec,
    stats: &ObsStats<D>,
    count: u32,
    out: &mut [u8],
) -> Result<usize, WireError> {
    codec.validate(D)?;
    let blocks = NonZeroUsize::new(usize::from(codec.psi_blocks)).ok_or(WireError::BadConfig)?;
    let len = codec.code_len_for(D, count);
    let lead = usize::from(codec.lead);
    if codec.is_rice() {
        return encode_rice(codec, super::rice::Policy::DEFAULT, stats, count, out);
    }
    #[cfg(feature = "stored-codes")]
    if codec.is_stored() {
        // Stored codes are the map's: statistics are not encoded into them here (see `stored`).
        return Err(WireError::BadConfig);
    }
    let out = out.get_mut(..len).ok_or(WireError::BufferFull)?;
    out.fill(0);
    // μ: the lead band (if any), then the other components, each after its scale byte.
    let mut t = stats.mean;
    let mut tmp = [0.0f32; D];
    let mut at = 0;
    for (band, bits) in [
        (0..lead, codec.lead_bits_for(count)),
        (lead..D, codec.rest_bits_for(count)),
    ] {
        let n = band_len(band.len(), bits);
        let (Some(v), Some(scratch), Some(o)) = (
            t.get_mut(band.clone()),
            tmp.get_mut(band),
            out.get_mut(at..at + n),
        ) else {
            return Err(WireError::BufferFull);
        };
        encode_band(v, scratch, bits, o);
        at += n;
    }
    encode_scatter::<D>(
        blocks,
        &stats.scatter,
        out.get_mut(at..).unwrap_or_default(),
    );
    Ok(len)
}

/// Write the scatter (largest entry, block means) into `out` (zeroed; empty for a one-point summary).
fn encode_scatter<const D: usize>(blocks: NonZeroUsize, scatter: &[f32; D], out: &mut [u8]) {
    // A single point has no scatter: nothing is sent for it.
    let [max_byte, block_bytes @ ..] = out else {
        return;
    };
    // S: largest entry (rounded up) and block means relative to it.
    let psi_max = max_or_zero(scatter);
    if psi_max > 0.0 && psi_max.is_finite() {
        let max_code = log_code_up(psi_max, PSI_OFFSET);
        *max_byte = max_code;
        let sent_max = log_value(max_code, PSI_OFFSET);
        let log_sent_max = f32math::log2(sent_max);
        for b in 0..blocks.get() {
            let r = block_range(D, blocks, b);
            let n = r.len().max(1) as f32;
            let block = scatter.get(r).unwrap_or_default();
            let mean = block
                .iter()
                .map(|&p| if p > 0.0 { p } else { 0.0 })
                .sum::<f32>()
                / n;
            let c = if mean > 0.0 {
                ratio_steps(
                    log_sent_max - f32math::log2(mean),
                    BLOCK_STEPS_PER_OCTAVE,
                    15,
                )
            } else {
                15
            };
            if let Some(byte) = block_bytes.get_mut(b / 2) {
                *byte |= c << (4 * (b % 2));
            }
        }
    }
}

/// Decode the quantized part written by [`encode_codes`] into statistics of `count` points.
pub fn decode_codes<const D: usize>(
    codec: SummaryCodec,
    count: f32,
    bytes: &[u8],
) -> Result<ObsStats<D>, WireError> {
    let n = wire_count(count).ok_or(WireError::BadCount)?;
    decode_codes_as(codec, n, count, bytes)
}

/// Decode codes sized for a summary of `n` points ([`encode_codes_as`]) into statistics of weight
/// `count`.
pub fn decode_codes_as<const D: usize>(
    codec: SummaryCodec,
    n: u32,
    count: f32,
    bytes: &[u8],
) -> Result<ObsStats<D>, WireError> {
    codec.validate(D)?;
    let bytes = bytes
        .get(..codec.codes_len(D, n, bytes)?)
        .ok_or(WireError::Truncated)?;
    let mut t = [0.0f32; D];
    let mut tmp = [0.0f32; D];
    let lead = usize::from(codec.lead);
    let mut at = 0;
    if codec.is_rice() {
        return decode_rice_at(codec, (n, count), bytes, 0).map(|(obs, _, _)| obs);
    }
    #[cfg(feature = "stored-codes")]
    if codec.is_stored() {
        return stored::decode(n, count, bytes);
    }
    for (band, bits) in [
        (0..lead, codec.lead_bits_for(n)),
        (lead..D, codec.rest_bits_for(n)),
    ]
    .into_iter()
    .filter(|_| !codec.is_rice())
    {
        let len = band_len(band.len(), bits);
        let (Some(v), Some(scratch), Some(b)) = (
            t.get_mut(band.clone()),
            tmp.get_mut(band),
            bytes.get(at..at + len),
        ) else {
            return Err(WireError::Truncated);
        };
        decode_band(b, bits, v, scratch);
        at += len;
    }
    let psi_at = at;
    let psi_max = log_value(bytes.get(psi_at).copied().unwrap_or(0), PSI_OFFSET);
    let mut scatter = [0.0f32; D];
    let blocks = NonZeroUsize::new(usize::from(codec.psi_blocks)).ok_or(WireError::BadConfig)?;
    if psi_max > 0.0 {
        for b in 0..blocks.get() {
            let c = bytes.get(psi_at + 1 + b / 2).copied().unwrap_or(0) >> (4 * (b % 2)) & 0x0f;
            let v = psi_max * f32math::pow2_steps(-i32::from(c), BLOCK_STEPS_PER_OCTAVE);
            for p in scatter
                .get_mut(block_range(D, blocks, b))
                .unwrap_or_default()
            {
                *p = v;
            }
        }
    }
    Ok(ObsStats {
        count,
        mean: t,
        scatter,
    })
}

/// Largest error of a decoded mean, ‖μ̂ − μ‖₂, from a summary's codes (as [`encode_codes`] wrote them)
/// and its point count: per band √(its length) × half a quantization step, added in quadrature.
pub fn mean_error_bound(codec: SummaryCodec, dim: usize, codes: &[u8], count: u32) -> f32 {
    let lead = usize::from(codec.lead);
    if codec.is_rice() {
        // Rounding to the nearest multiple of the step: half a step per component (a sender coarsens
        // its steps rather than clamp a value).
        let mut r = super::rice::BitReader {
            bytes: codes,
            bit: 0,
        };
        let steps = super::rice::read_steps(&mut r, lead > 0, count).unwrap_or([0; 2]);
        let mut sq = 0.0;
        for (&code, len) in steps.iter().zip([lead, dim - lead]) {
            let e = log_value(code, SCALE_OFFSET) / 2.0;
            sq += len as f32 * e * e;
        }
        return libm::sqrtf(sq);
    }
    #[cfg(feature = "stored-codes")]
    if codec.is_stored() {
        return stored::error_bound(dim, codes);
    }
    let band = |scale_code: Option<&u8>, len: usize, bits: u32| {
        let scale = log_value(scale_code.copied().unwrap_or(0), SCALE_OFFSET);
        let e = scale / (1u32 << bits) as f32;
        len as f32 * e * e
    };
    let mut sq = band(
        codes.get(codec.lead_len_for(count)),
        dim - lead,
        codec.rest_bits_for(count),
    );
    if lead > 0 {
        sq += band(codes.first(), lead, codec.lead_bits_for(count));
    }
    libm::sqrtf(sq)
}

/// Bytes of a band of `len` components at `bits` each: its scale byte and its packed codes (none for an
/// empty band).
const fn band_len(len: usize, bits: u32) -> usize {
    if len == 0 {
        0
    } else {
        1 + (len * bits as usize).div_ceil(8)
    }
}
