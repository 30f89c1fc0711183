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
//! The format is written down below; `tests` check the code against it. Submodules: [`messages`] (frame
//! header, session configuration, link statistics, the message enum: postcard), [`summary`] (a voxel
//! summary's bytes), [`codec`] (its quantized codes) and [`rice`] (a *Rice session*'s summaries: one bit
//! stream of variable-length codes each, announced by a byte after the session message; feature
//! `rice-codes`).
//!
#![doc = include_str!("../wire_spec.md")]

pub mod codec;
pub mod messages;
pub mod rice;
pub mod summary;

#[cfg(feature = "stored-codes")]
pub use codec::write_stored;
pub use codec::{
    decode_codes, decode_codes_as, encode_codes, encode_codes_as, encode_rice, mean_error_bound,
    stamped_class, wire_count, SummaryCodec, MAX_COUNT,
};
pub use messages::{
    encode_body, feature_space_id, parse_body, FrameHeader, LinkStats, Message, SessionConfig,
    VoxelBatch, NO_FEATURE_SPACE,
};
pub use summary::{
    decode_summary, encode_rice_head, encode_rice_summary, encode_stamped_head, encode_summary,
    encode_summary_head, Ceiling, DeltaBase, Summary, SummaryIter,
};

/// Protocol version: byte 0 of every frame body. Bumped on any incompatible change.
pub const PROTOCOL_VERSION: u8 = 5;

/// CRC-32 used for frames, configuration ids and feature-space ids (ISO-HDLC: zlib, Ethernet, PNG).
pub const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// Why a frame body or a summary was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
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

#[cfg(test)]
mod tests;
