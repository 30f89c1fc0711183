//! Wire messages: what a robot tells the base station, and the compact voxel summary.
//!
//! A serial link carries ~10 kB/s, and a voxel's f32 statistics at D = 64 are 516 bytes, so the summary
//! carries what was *observed* in the voxel — point count n, mean m, scatter S ([`crate::obs`]) — not its
//! posterior: the base station gathers posteriors through the kernel itself, so a voxel is sent once, not
//! once per neighbour it influences. It is quantized where it is cheap to be wrong and exact where merging
//! needs it: n travels exactly (a varint, so Σn is conserved by every merge), m is rotated by an orthonormal
//! Walsh–Hadamard transform (spreading the energy of the leading PCA components over all dimensions) and
//! uniformly quantized against a per-voxel scale, and S travels as its largest entry and the arithmetic
//! mean of each block of dimensions — arithmetic, because merging adds scatters, so block means merge
//! exactly. Keys and residency numbers are delta-coded against the previous summary in the frame.
//!
//! Everything else (frame header, session configuration, link statistics) is plain postcard with serde.
//! The format is written down below; `tests` at the bottom check the code against it.
//!
#![doc = include_str!("wire_spec.md")]

use crate::config::{ConfigError, KernelMode, MapConfig, Prior};
use crate::decode::Pca;
use crate::f32math;
use crate::key::VoxelKey;
use crate::obs::ObsStats;
use core::num::NonZeroUsize;
use serde::{Deserialize, Serialize};

/// Protocol version: byte 0 of every frame body. Bumped on any incompatible change.
pub const PROTOCOL_VERSION: u8 = 2;

/// CRC-32 used for frames, configuration ids and feature-space ids (ISO-HDLC: zlib, Ethernet, PNG).
pub const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// Why a frame body or a summary was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum WireError {
    /// Byte 0 of the body is not [`PROTOCOL_VERSION`].
    UnknownVersion(u8),
    /// The body does not parse as the format says (bad tag, bad varint, trailing bytes, …).
    Malformed,
    /// The body ends before the message does.
    Truncated,
    /// The frame's configuration id is not the one this receiver accepts.
    WrongConfig,
    /// A session configuration is invalid (bad map config, codec, or dimension ≠ the receiver's D).
    BadConfig,
    /// A summary's key is outside ±2³⁰.
    BadKey,
    /// A summary's point count is 0 or beyond 2²⁴ (where f32 stops counting exactly), or its statistics
    /// are not finite.
    BadCount,
    /// The output buffer is too small.
    BufferFull,
}

impl core::fmt::Display for WireError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::UnknownVersion(v) => write!(f, "unknown protocol version {v}"),
            Self::Malformed => f.write_str("malformed message"),
            Self::Truncated => f.write_str("message truncated"),
            Self::WrongConfig => f.write_str("frame from a session with another map configuration"),
            Self::BadConfig => f.write_str("invalid session configuration"),
            Self::BadKey => f.write_str("voxel key out of range"),
            Self::BadCount => f.write_str("voxel point count not in 1..=2^24"),
            Self::BufferFull => f.write_str("output buffer too small"),
        }
    }
}

impl core::error::Error for WireError {}

/// How voxel summaries are quantized. Part of the session configuration.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SummaryCodec {
    /// Bits per (rotated) mean component, 2..=8.
    pub mean_bits: u8,
    /// Number of blocks the scatter's block means are sent for, 1..=min(D, 64).
    pub psi_blocks: u8,
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
    };

    /// Whether this codec can encode D-dimensional voxels.
    pub fn validate(self, dim: usize) -> Result<(), WireError> {
        let blocks = usize::from(self.psi_blocks);
        if dim == 0 || dim > u16::MAX as usize {
            return Err(WireError::BadConfig);
        }
        if !(2..=8).contains(&self.mean_bits) || blocks == 0 || blocks > dim.min(64) {
            return Err(WireError::BadConfig);
        }
        Ok(())
    }

    /// Bytes of the quantized part (mean scale, mean codes, scatter) of a D-dimensional summary.
    pub const fn code_len(self, dim: usize) -> usize {
        1 + (dim * self.mean_bits as usize).div_ceil(8) + 1 + (self.psi_blocks as usize).div_ceil(2)
    }

    /// Largest wire size of one summary (5-byte key deltas and residency field, 4-byte count).
    pub const fn max_summary_len(self, dim: usize) -> usize {
        3 * 5 + 5 + 4 + self.code_len(dim)
    }
}

/// [`SessionConfig::feature_space`] of features that are not tied to a PCA (e.g. a self-test's codebook).
pub const NO_FEATURE_SPACE: u32 = 0;

/// Everything two maps must agree on before their summaries can be merged. Sent in the session header;
/// its CRC-32 ([`Self::id`]) is in every frame header.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SessionConfig {
    /// Feature dimension D.
    pub dim: u16,
    /// Voxel edge length (m).
    pub voxel_size: f32,
    /// Kernel length ℓ (m).
    pub kernel_length: f32,
    /// Filter size f.
    pub filter_size: u8,
    /// Sub-voxel cells per axis; 0 = voxel-offset kernel.
    pub subvoxel_cells: u8,
    /// Prior λ₀.
    pub prior_lambda: f32,
    /// Prior μ₀.
    pub prior_mean: f32,
    /// Prior Ψ₀.
    pub prior_psi: f32,
    /// How summaries are quantized.
    pub codec: SummaryCodec,
    /// Id of the feature space (the PCA the features were compressed with): [`feature_space_id`];
    /// [`NO_FEATURE_SPACE`] = features are not PCA-compressed.
    pub feature_space: u32,
}

impl SessionConfig {
    /// The session configuration of a D-dimensional map.
    pub fn new(map: &MapConfig, dim: usize, codec: SummaryCodec, feature_space: u32) -> Self {
        let p = map.prior();
        Self {
            dim: dim.min(u16::MAX as usize) as u16,
            voxel_size: map.voxel_size(),
            kernel_length: map.kernel_length(),
            filter_size: map.filter_size(),
            subvoxel_cells: match map.mode() {
                KernelMode::VoxelOffset => 0,
                KernelMode::SubVoxel { cells } => cells,
            },
            prior_lambda: p.lambda,
            prior_mean: p.mean,
            prior_psi: p.psi,
            codec,
            feature_space,
        }
    }

    /// The map configuration it describes (validated).
    pub fn map_config(&self) -> Result<MapConfig, ConfigError> {
        let prior = Prior {
            lambda: self.prior_lambda,
            mean: self.prior_mean,
            psi: self.prior_psi,
        };
        let mode = KernelMode::from_subvoxel_cells(self.subvoxel_cells);
        MapConfig::new(
            self.voxel_size,
            self.kernel_length,
            self.filter_size,
            prior,
            mode,
        )
    }

    /// Check the whole configuration, for a receiver whose maps are `dim`-dimensional.
    pub fn validate(&self, dim: usize) -> Result<(), WireError> {
        if usize::from(self.dim) != dim {
            return Err(WireError::BadConfig);
        }
        self.codec.validate(dim)?;
        self.map_config().map_err(|_| WireError::BadConfig)?;
        Ok(())
    }

    /// The configuration id: CRC-32 of its postcard encoding.
    pub fn id(&self) -> u32 {
        let mut buf = [0u8; 64];
        match postcard::to_slice(self, &mut buf) {
            Ok(bytes) => CRC32.checksum(bytes),
            Err(_) => 0, // cannot happen: the encoding is at most 40 bytes
        }
    }
}

/// Id of a PCA feature space: CRC-32 over its mean then its components (row-major), as f32 little-endian.
pub fn feature_space_id<const D: usize, const F: usize>(pca: &Pca<D, F>) -> u32 {
    let mut digest = CRC32.digest();
    for v in pca.mean.iter().chain(pca.components.iter().flatten()) {
        digest.update(&v.to_le_bytes());
    }
    digest.finalize()
}

/// Header of every frame body. `version` is byte 0 in every protocol version.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FrameHeader {
    /// [`PROTOCOL_VERSION`].
    pub version: u8,
    /// Which robot.
    pub robot: u16,
    /// Which session of that robot (a fresh number per boot): residency numbers and sequence numbers
    /// restart with a session.
    pub session: u32,
    /// Frame sequence number within the session, from 0, +1 per frame.
    pub seq: u32,
    /// [`SessionConfig::id`] of the session.
    pub config_id: u32,
}

/// Link statistics the robot reports about itself.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LinkStats {
    /// Frames written before this one.
    pub frames_sent: u32,
    /// Final (evicted) summaries written.
    pub evicted_sent: u32,
    /// Live summaries written.
    pub live_sent: u32,
    /// Evictions refused because the queue was full (the map kept those voxels).
    pub refused: u32,
    /// Evicted voxels dropped because they were not finite (never sent).
    pub invalid: u32,
    /// Frames the writer failed to send.
    pub write_errors: u32,
    /// Bytes written, wrapping.
    pub bytes_sent: u32,
    /// Most summaries ever waiting in the queue.
    pub queue_peak: u32,
}

impl LinkStats {
    /// All counters zero (the same as `default()`, usable in `const` context).
    pub const ZERO: Self = Self {
        frames_sent: 0,
        evicted_sent: 0,
        live_sent: 0,
        refused: 0,
        invalid: 0,
        write_errors: 0,
        bytes_sent: 0,
        queue_peak: 0,
    };
}

/// Summaries packed as the format says ([`encode_summary`]); `count` of them, nothing after.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct VoxelBatch<'a> {
    /// How many summaries.
    pub count: u16,
    /// The packed summaries.
    pub summaries: &'a [u8],
}

/// A frame's message.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Message<'a> {
    /// Session header: the configuration (sent first and periodically).
    Session(SessionConfig),
    /// Voxel summaries.
    #[serde(borrow)]
    Voxels(VoxelBatch<'a>),
    /// Link statistics.
    Stats(LinkStats),
}

/// Serialize header + message into `out`; returns the body length.
pub fn encode_body(
    header: &FrameHeader,
    message: &Message<'_>,
    out: &mut [u8],
) -> Result<usize, WireError> {
    let h = postcard::to_slice(header, out)
        .map_err(|_| WireError::BufferFull)?
        .len();
    let rest = out.get_mut(h..).ok_or(WireError::BufferFull)?;
    let m = postcard::to_slice(message, rest)
        .map_err(|_| WireError::BufferFull)?
        .len();
    Ok(h + m)
}

/// Parse a frame body (CRC already checked): version first, then header and message, nothing after.
pub fn parse_body(body: &[u8]) -> Result<(FrameHeader, Message<'_>), WireError> {
    match body.first() {
        None => return Err(WireError::Truncated),
        Some(&v) if v != PROTOCOL_VERSION => return Err(WireError::UnknownVersion(v)),
        Some(_) => {}
    }
    let map = |e: postcard::Error| match e {
        postcard::Error::DeserializeUnexpectedEnd => WireError::Truncated,
        _ => WireError::Malformed,
    };
    let (header, rest) = postcard::take_from_bytes::<FrameHeader>(body).map_err(map)?;
    let (message, rest) = postcard::take_from_bytes::<Message<'_>>(rest).map_err(map)?;
    if !rest.is_empty() {
        return Err(WireError::Malformed);
    }
    Ok((header, message))
}

// ---------------------------------------------------------------------------------------------------------
// Voxel summaries.

/// A voxel as the base station sees it after decoding.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Summary<const D: usize> {
    /// Which voxel.
    pub key: VoxelKey,
    /// Residency number (see [`crate::sink::Evicted`]).
    pub residency: u32,
    /// Whether the voxel has left the robot's map (its last word on this residency), or is a live update
    /// of a voxel still resident (to be replaced by newer ones).
    pub is_final: bool,
    /// What was observed in the voxel during this residency. n is exact; m and S are quantized.
    pub obs: ObsStats<D>,
    /// The mean's scale and the largest scatter entry were sent with the codec's top code (255): each value
    /// was clamped there (the mean's scale at ≈ 6.0e4, S at ≈ 9.6e5) or lies within 1/8 octave below it.
    /// Receivers count it.
    pub at_ceiling: Ceiling,
}

/// Which of a summary's log-coded values were sent with the top code (see [`Summary::at_ceiling`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Ceiling {
    /// The mean's scale code was 255.
    pub mean_scale: bool,
    /// The largest-scatter code was 255.
    pub psi: bool,
}

/// Key and residency of the previous summary in a frame (deltas are taken against it).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DeltaBase {
    key: VoxelKey,
    residency: u32,
}

fn put(out: &mut [u8], at: &mut usize, bytes: &[u8]) -> Result<(), WireError> {
    let end = *at + bytes.len();
    out.get_mut(*at..end)
        .ok_or(WireError::BufferFull)?
        .copy_from_slice(bytes);
    *at = end;
    Ok(())
}

/// postcard's varint: LEB128, 7 bits per byte, least significant first.
fn put_varint(out: &mut [u8], at: &mut usize, mut v: u64) -> Result<(), WireError> {
    loop {
        let byte = (v & 0x7f) as u8;
        v >>= 7;
        if v == 0 {
            return put(out, at, &[byte]);
        }
        put(out, at, &[byte | 0x80])?;
    }
}

fn take<'a>(bytes: &'a [u8], at: &mut usize, n: usize) -> Result<&'a [u8], WireError> {
    let end = at.checked_add(n).ok_or(WireError::Truncated)?;
    let s = bytes.get(*at..end).ok_or(WireError::Truncated)?;
    *at = end;
    Ok(s)
}

fn take_varint(bytes: &[u8], at: &mut usize, max_bytes: usize) -> Result<u64, WireError> {
    let mut v = 0u64;
    for i in 0..max_bytes {
        let b = take(bytes, at, 1)?[0];
        v |= u64::from(b & 0x7f) << (7 * i);
        if b & 0x80 == 0 {
            return Ok(v);
        }
    }
    Err(WireError::Malformed)
}

const fn zigzag(v: i32) -> u32 {
    ((v << 1) ^ (v >> 31)) as u32
}

const fn unzigzag(v: u32) -> i32 {
    ((v >> 1) as i32) ^ -((v & 1) as i32)
}

/// One stage of the Walsh–Hadamard transform in constant geometry: pairs (2j, 2j + 1) of `from` become
/// their sum at j and their difference at j + n/2 of `to` (both of length n). log₂ n stages are the
/// transform in Sylvester order, each output the same tree of sums and differences as the in-place
/// butterflies (so the same bits), but every stage is one short loop instead of log₂ n nested ones.
#[inline(never)]
fn hadamard_stage(from: &[f32], to: &mut [f32]) {
    let (from, to) = core::hint::black_box((from, to));
    let (sums, diffs) = to.split_at_mut(to.len() / 2);
    for ((pair, s), d) in from.chunks_exact(2).zip(sums).zip(diffs) {
        if let [x, y] = *pair {
            *s = x + y;
            *d = x - y;
        }
    }
}

/// Orthonormal Walsh–Hadamard transform (its own inverse) when D is a power of two; identity otherwise.
/// Returns the largest |entry| of the result (NaN entries ignored; 0 for none).
fn hadamard<const D: usize>(v: &mut [f32; D]) -> f32 {
    if D < 2 || !D.is_power_of_two() {
        return scale_all(v, 1.0);
    }
    let mut tmp = [0.0f32; D];
    let stages = D.trailing_zeros();
    for _ in 0..stages / 2 {
        hadamard_stage(v, &mut tmp);
        hadamard_stage(&tmp, v);
    }
    if stages % 2 == 1 {
        hadamard_stage(v, &mut tmp);
        *v = tmp;
    }
    scale_all(v, 1.0 / libm::sqrtf(D as f32))
}

// The summary codec runs once per voxel sent, not per point: its loops over D stay loops instead of being
// unrolled D times into flash (≈ 6 KB at D = 64). They take slices, are not inlined, and hide the length
// (a constant everywhere, which the optimizer would propagate) behind `black_box`; only code size and a
// few instructions per voxel depend on that, never a result. Maxima are comparisons, not `f32::max`,
// which thumbv7em lowers to a call to `fmaxf` per element.

/// `v *= k`, element-wise; returns the largest |v| after it (NaN entries ignored; 0 for none).
#[inline(never)]
fn scale_all(v: &mut [f32], k: f32) -> f32 {
    let v = core::hint::black_box(v);
    let mut peak = 0.0f32;
    for x in v {
        *x *= k;
        let a = libm::fabsf(*x);
        if a > peak {
            peak = a;
        }
    }
    peak
}

/// The largest v, at least 0 (NaN entries ignored), as `fold(0, max)`.
#[inline(never)]
fn max_or_zero(values: &[f32]) -> f32 {
    core::hint::black_box(values)
        .iter()
        .fold(0.0f32, |a, &v| if v > a { v } else { a })
}

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

fn block_range(dim: usize, blocks: NonZeroUsize, b: usize) -> core::ops::Range<usize> {
    (b * dim / blocks)..((b + 1) * dim / blocks)
}

/// Largest point count a summary carries: f32 counts exactly up to 2²⁴.
pub const MAX_COUNT: u32 = 1 << 24;

/// The count as the wire carries it, if it is a whole number in 1..=[`MAX_COUNT`].
pub fn wire_count(count: f32) -> Option<u32> {
    let n = count as u32; // saturating; NaN → 0
    ((1..=MAX_COUNT).contains(&n) && n as f32 == count).then_some(n)
}

/// Write the quantized part (mean scale, mean codes, scatter) of observation statistics into
/// `out[..codec.code_len(D)]`.
pub fn encode_codes<const D: usize>(
    codec: SummaryCodec,
    stats: &ObsStats<D>,
    out: &mut [u8],
) -> Result<usize, WireError> {
    codec.validate(D)?;
    let blocks = NonZeroUsize::new(usize::from(codec.psi_blocks)).ok_or(WireError::BadConfig)?;
    let len = codec.code_len(D);
    let out = out.get_mut(..len).ok_or(WireError::BufferFull)?;
    out.fill(0);
    let bits = u32::from(codec.mean_bits);
    let (scale_byte, rest) = out.split_first_mut().ok_or(WireError::BufferFull)?;
    let (mean_bytes, psi_bytes) = rest
        .split_at_mut_checked((D * bits as usize).div_ceil(8))
        .ok_or(WireError::BufferFull)?;
    let [max_byte, block_bytes @ ..] = psi_bytes else {
        return Err(WireError::BufferFull);
    };
    // μ: rotate, scale, mid-rise uniform codes, packed LSB first.
    let mut t = stats.mean;
    let peak = hadamard(&mut t);
    let levels = 1u32 << bits;
    let scale_code = if peak > 0.0 && peak.is_finite() {
        log_code_up(peak, SCALE_OFFSET)
    } else {
        0
    };
    *scale_byte = scale_code;
    let scale = log_value(scale_code, SCALE_OFFSET);
    if scale > 0.0 {
        let half = (levels / 2) as f32;
        let top = levels - 1;
        // Bits not yet stored (LSB first) and how many.
        let (mut pending, mut n) = (0u32, 0u32);
        let mut bytes = mean_bytes.iter_mut();
        for &v in &t {
            // The float-to-int cast truncates and saturates (NaN → 0), so here it is floor clamped at 0:
            // a component a rounding step below −scale still gets code 0.
            let q = (((v / scale + 1.0) * half) as u32).min(top);
            pending |= q << n;
            n += bits;
            if n >= 8 {
                if let Some(b) = bytes.next() {
                    *b = pending as u8;
                }
                pending >>= 8;
                n -= 8;
            }
        }
        if let Some(b) = bytes.next() {
            *b = pending as u8;
        }
    }
    // S: largest entry (rounded up) and block means relative to it.
    let psi_max = max_or_zero(&stats.scatter);
    if psi_max > 0.0 && psi_max.is_finite() {
        let max_code = log_code_up(psi_max, PSI_OFFSET);
        *max_byte = max_code;
        let sent_max = log_value(max_code, PSI_OFFSET);
        let log_sent_max = f32math::log2(sent_max);
        for b in 0..blocks.get() {
            let r = block_range(D, blocks, b);
            let n = r.len().max(1) as f32;
            let block = stats.scatter.get(r).unwrap_or_default();
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
    Ok(len)
}

/// Decode the quantized part written by [`encode_codes`] into statistics of `count` points.
pub fn decode_codes<const D: usize>(
    codec: SummaryCodec,
    count: f32,
    bytes: &[u8],
) -> Result<ObsStats<D>, WireError> {
    codec.validate(D)?;
    let bytes = bytes.get(..codec.code_len(D)).ok_or(WireError::Truncated)?;
    let bits = usize::from(codec.mean_bits);
    let levels = 1u32 << bits;
    let scale = log_value(bytes[0], SCALE_OFFSET);
    let mut t = [0.0f32; D];
    if scale > 0.0 {
        let half = (levels / 2) as f32;
        let mut bit = 8usize;
        for v in t.iter_mut() {
            let mut q = 0u32;
            for k in 0..bits {
                q |= u32::from(bytes[(bit + k) / 8] >> ((bit + k) % 8) & 1) << k;
            }
            *v = scale * ((q as f32 + 0.5) / half - 1.0);
            bit += bits;
        }
        hadamard(&mut t);
    }
    let psi_at = 1 + (D * bits).div_ceil(8);
    let psi_max = log_value(bytes[psi_at], PSI_OFFSET);
    let mut scatter = [0.0f32; D];
    let blocks = NonZeroUsize::new(usize::from(codec.psi_blocks)).ok_or(WireError::BadConfig)?;
    if psi_max > 0.0 {
        for b in 0..blocks.get() {
            let c = bytes[psi_at + 1 + b / 2] >> (4 * (b % 2)) & 0x0f;
            let v = psi_max * f32math::pow2_steps(-i32::from(c), BLOCK_STEPS_PER_OCTAVE);
            for p in &mut scatter[block_range(D, blocks, b)] {
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

/// Largest error of a decoded mean, ‖μ̂ − μ‖₂, for the μ scale code sent: √D × half a quantization step.
pub fn mean_error_bound(codec: SummaryCodec, dim: usize, scale_code: u8) -> f32 {
    let scale = log_value(scale_code, SCALE_OFFSET);
    libm::sqrtf(dim as f32) * scale / (1u32 << codec.mean_bits) as f32
}

/// Write one summary: key deltas, residency delta with the final flag, point count, codes. `codes` come
/// from [`encode_codes`]. Returns the bytes written and advances `base`.
#[allow(clippy::too_many_arguments)]
pub fn encode_summary(
    base: &mut DeltaBase,
    key: VoxelKey,
    residency: u32,
    is_final: bool,
    count: u32,
    codes: &[u8],
    out: &mut [u8],
) -> Result<usize, WireError> {
    let mut at = encode_summary_head(base, key, residency, is_final, count, out)?;
    put(out, &mut at, codes)?;
    Ok(at)
}

/// Write a summary's head (key deltas, residency delta with the final flag, point count) and advance
/// `base`; the caller appends the codes ([`encode_codes`]) right after. Returns the bytes written.
pub fn encode_summary_head(
    base: &mut DeltaBase,
    key: VoxelKey,
    residency: u32,
    is_final: bool,
    count: u32,
    out: &mut [u8],
) -> Result<usize, WireError> {
    let mut at = 0;
    for (k, b) in key.as_array().iter().zip(base.key.as_array()) {
        put_varint(out, &mut at, u64::from(zigzag(k.wrapping_sub(b))))?;
    }
    let dres = u64::from(zigzag(residency.wrapping_sub(base.residency) as i32));
    put_varint(out, &mut at, dres << 1 | u64::from(is_final))?;
    put_varint(out, &mut at, u64::from(count))?;
    *base = DeltaBase { key, residency };
    Ok(at)
}

/// Read one summary from `bytes` (starting at `*at`), validating it.
pub fn decode_summary<const D: usize>(
    codec: SummaryCodec,
    base: &mut DeltaBase,
    bytes: &[u8],
    at: &mut usize,
) -> Result<Summary<D>, WireError> {
    let mut k = [0i32; 3];
    for (i, b) in k.iter_mut().zip(base.key.as_array()) {
        let z = u32::try_from(take_varint(bytes, at, 5)?).map_err(|_| WireError::Malformed)?;
        *i = b.wrapping_add(unzigzag(z));
    }
    let key = VoxelKey::new(k[0], k[1], k[2]);
    if !key.in_range() {
        return Err(WireError::BadKey);
    }
    let rf = take_varint(bytes, at, 5)?;
    let z = u32::try_from(rf >> 1).map_err(|_| WireError::Malformed)?;
    let residency = base.residency.wrapping_add(unzigzag(z) as u32);
    let is_final = rf & 1 == 1;
    let count = take_varint(bytes, at, 4)?;
    if !(1..=u64::from(MAX_COUNT)).contains(&count) {
        return Err(WireError::BadCount);
    }
    let codes = take(bytes, at, codec.code_len(D))?;
    let obs = decode_codes::<D>(codec, count as f32, codes)?;
    let psi_at = 1 + (D * usize::from(codec.mean_bits)).div_ceil(8);
    let at_ceiling = Ceiling {
        mean_scale: codes.first() == Some(&u8::MAX),
        psi: codes.get(psi_at) == Some(&u8::MAX),
    };
    *base = DeltaBase { key, residency };
    Ok(Summary {
        key,
        residency,
        is_final,
        obs,
        at_ceiling,
    })
}

impl<'a> VoxelBatch<'a> {
    /// Iterate over the summaries; the iterator checks that exactly `count` are present.
    pub fn iter<const D: usize>(&self, codec: SummaryCodec) -> SummaryIter<'a, D> {
        SummaryIter {
            codec,
            bytes: self.summaries,
            at: 0,
            left: self.count,
            base: DeltaBase::default(),
            failed: false,
        }
    }
}

/// Iterator over a [`VoxelBatch`]'s summaries. Yields an error (and then stops) on the first bad summary,
/// on missing summaries or on trailing bytes.
pub struct SummaryIter<'a, const D: usize> {
    codec: SummaryCodec,
    bytes: &'a [u8],
    at: usize,
    left: u16,
    base: DeltaBase,
    failed: bool,
}

impl<const D: usize> Iterator for SummaryIter<'_, D> {
    type Item = Result<Summary<D>, WireError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        if self.left == 0 {
            if self.at != self.bytes.len() {
                self.failed = true;
                return Some(Err(WireError::Malformed));
            }
            return None;
        }
        self.left -= 1;
        let r = decode_summary::<D>(self.codec, &mut self.base, self.bytes, &mut self.at);
        self.failed = r.is_err();
        Some(r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample<const D: usize>(seed: u32) -> ObsStats<D> {
        // A small deterministic generator (xorshift) so the test needs no RNG crate.
        let mut s = seed.wrapping_mul(2_654_435_761).max(1);
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            (s as f32 / u32::MAX as f32) * 2.0 - 1.0
        };
        ObsStats {
            count: (3.0 + 10.0 * libm::fabsf(next())) as u32 as f32,
            mean: core::array::from_fn(|i| next() / (1.0 + i as f32 * 0.1)),
            scatter: core::array::from_fn(|i| {
                1.0 + 5.0 * libm::fabsf(next()) / (1.0 + i as f32 * 0.2)
            }),
        }
    }

    #[test]
    fn varints_match_postcard() {
        for v in [0u32, 1, 127, 128, 300, 16_383, 16_384, u32::MAX] {
            let mut ours = [0u8; 10];
            let mut at = 0;
            put_varint(&mut ours, &mut at, u64::from(v)).unwrap();
            let mut theirs = [0u8; 10];
            let t = postcard::to_slice(&v, &mut theirs).unwrap();
            assert_eq!(&ours[..at], &*t, "varint of {v}");
        }
        for v in [0i32, -1, 1, -64, 64, i32::MIN, i32::MAX] {
            let mut theirs = [0u8; 10];
            let t = postcard::to_slice(&v, &mut theirs).unwrap();
            let mut ours = [0u8; 10];
            let mut at = 0;
            put_varint(&mut ours, &mut at, u64::from(zigzag(v))).unwrap();
            assert_eq!(&ours[..at], &*t, "zigzag of {v}");
            assert_eq!(unzigzag(zigzag(v)), v);
        }
    }

    #[test]
    fn hadamard_is_orthonormal_and_self_inverse() {
        let v: [f32; 8] = [1.0, -2.0, 0.5, 3.0, 0.0, 0.25, -1.0, 2.0];
        let mut t = v;
        hadamard(&mut t);
        let n0: f32 = v.iter().map(|x| x * x).sum();
        let n1: f32 = t.iter().map(|x| x * x).sum();
        assert!((n0 - n1).abs() < 1e-5);
        hadamard(&mut t);
        for (a, b) in v.iter().zip(&t) {
            assert!((a - b).abs() < 1e-6);
        }
    }

    #[test]
    fn default_summary_is_at_most_36_bytes_at_d64_for_neighbouring_keys() {
        let codec = SummaryCodec::DEFAULT;
        assert_eq!(codec.code_len(64), 30);
        let mut codes = [0u8; 64];
        let n = encode_codes(codec, &sample::<64>(1), &mut codes).unwrap();
        let mut base = DeltaBase::default();
        let mut out = [0u8; 64];
        encode_summary(
            &mut base,
            VoxelKey::new(100, -40, 7),
            5000,
            true,
            35,
            &codes[..n],
            &mut out,
        )
        .unwrap();
        let len = encode_summary(
            &mut base,
            VoxelKey::new(101, -40, 7),
            5003,
            true,
            35,
            &codes[..n],
            &mut out,
        )
        .unwrap();
        // 3 key deltas + residency + count + 30 code bytes.
        assert_eq!(len, 3 + 1 + 1 + 30);
        assert!(len <= 36);
    }

    #[test]
    fn summary_round_trip_within_bounds() {
        let codec = SummaryCodec::DEFAULT;
        let mut buf = [0u8; 512];
        let mut at = 0;
        let mut base = DeltaBase::default();
        let keys = [
            VoxelKey::new(-5, 3, 1 << 29),
            VoxelKey::new(-(1 << 30) + 1, (1 << 30) - 1, 0),
            VoxelKey::new(0, 0, 0),
        ];
        let mut sent = [ObsStats::<64>::EMPTY; 3];
        for (i, key) in keys.iter().enumerate() {
            sent[i] = sample::<64>(i as u32 + 7);
            let mut codes = [0u8; 64];
            let n = encode_codes(codec, &sent[i], &mut codes).unwrap();
            at += encode_summary(
                &mut base,
                *key,
                u32::MAX - i as u32,
                i == 1,
                sent[i].count as u32,
                &codes[..n],
                &mut buf[at..],
            )
            .unwrap();
        }
        let batch = VoxelBatch {
            count: 3,
            summaries: &buf[..at],
        };
        let got: heapless::Vec<Summary<64>, 3> =
            batch.iter::<64>(codec).map(|r| r.unwrap()).collect();
        for (i, s) in got.iter().enumerate() {
            assert_eq!(s.key, keys[i]);
            assert_eq!(s.residency, u32::MAX - i as u32);
            assert_eq!(s.is_final, i == 1);
            assert_eq!(s.obs.count, sent[i].count);
            let err: f32 = libm::sqrtf(
                s.obs
                    .mean
                    .iter()
                    .zip(&sent[i].mean)
                    .map(|(a, b)| (a - b) * (a - b))
                    .sum(),
            );
            let mut codes = [0u8; 64];
            encode_codes(codec, &sent[i], &mut codes).unwrap();
            assert!(
                err <= mean_error_bound(codec, 64, codes[0]) * 1.0001,
                "mean error {err}"
            );
            // The largest block mean is sent relative to the largest entry, rounded up.
            let true_max = sent[i].scatter.iter().fold(0.0f32, |a, &b| a.max(b));
            let got_max = s.obs.scatter.iter().fold(0.0f32, |a, &b| a.max(b));
            assert!(got_max <= true_max * 1.0906, "{got_max} vs {true_max}");
        }
        // One summary fewer than the count says, or one byte too many: refused.
        let short = VoxelBatch {
            count: 4,
            summaries: &buf[..at],
        };
        assert!(short
            .iter::<64>(codec)
            .any(|r| r == Err(WireError::Truncated)));
        let long = VoxelBatch {
            count: 2,
            summaries: &buf[..at],
        };
        assert!(long
            .iter::<64>(codec)
            .any(|r| r == Err(WireError::Malformed)));
    }

    #[test]
    fn block_means_of_the_scatter_merge_additively() {
        let codec = SummaryCodec {
            mean_bits: 8,
            psi_blocks: 8,
        };
        let s = sample::<64>(3);
        let mut codes = [0u8; 128];
        encode_codes(codec, &s, &mut codes).unwrap();
        let d = decode_codes::<64>(codec, s.count, &codes).unwrap();
        assert_eq!(d.count, s.count);
        for b in 0..8 {
            let r = block_range(64, NonZeroUsize::new(8).unwrap(), b);
            let exact: f32 = s.scatter[r.clone()].iter().sum();
            let got: f32 = d.scatter[r].iter().sum();
            // Half an octave step: within 2^(±1/4).
            assert!(
                got / exact < 1.19 && exact / got < 1.19,
                "block {b}: {got} vs {exact}"
            );
        }
    }

    #[test]
    fn body_round_trip_and_version_check() {
        let config = SessionConfig::new(
            &MapConfig::default(),
            64,
            SummaryCodec::DEFAULT,
            0xdead_beef,
        );
        let header = FrameHeader {
            version: PROTOCOL_VERSION,
            robot: 7,
            session: 99,
            seq: 12,
            config_id: config.id(),
        };
        let mut buf = [0u8; 128];
        let n = encode_body(&header, &Message::Session(config), &mut buf).unwrap();
        let (h, m) = parse_body(&buf[..n]).unwrap();
        assert_eq!((h, m), (header, Message::Session(config)));
        assert_eq!(m, Message::Session(config));
        assert!(config.validate(64).is_ok());
        assert_eq!(config.validate(32), Err(WireError::BadConfig));
        buf[0] = 1;
        assert_eq!(parse_body(&buf[..n]), Err(WireError::UnknownVersion(1)));
        buf[0] = PROTOCOL_VERSION;
        assert_eq!(parse_body(&buf[..n - 1]), Err(WireError::Truncated));
        assert_eq!(parse_body(&buf[..n + 1]), Err(WireError::Malformed));
        // Another voxel size is another configuration id.
        let other = MapConfig::new(0.2, 0.5, 3, Prior::default(), KernelMode::VoxelOffset).unwrap();
        assert_ne!(
            SessionConfig::new(&other, 64, SummaryCodec::DEFAULT, 0xdead_beef).id(),
            config.id()
        );
    }
}
