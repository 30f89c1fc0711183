//! The messages a frame body carries — session header, voxel batch, link statistics — and the frame
//! header in front of them: plain postcard with serde, so the format is the struct definitions (written
//! out in `wire_spec.md`).

use super::{SummaryCodec, WireError, CRC32, PROTOCOL_VERSION};
use crate::config::{ConfigError, KernelMode, MapConfig, Prior};
use crate::decode::Pca;
use serde::{Deserialize, Serialize};

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
    /// Scale of the robot's int8 features (a code c is the feature value `int8_scale` · c), so a receiver
    /// knows the grid the statistics were computed on; 0 = f32 features. Finite and ≥ 0.
    pub int8_scale: f32,
    /// Half-life of the robot's map in mission-clock ticks when it forgets ([`crate::forget`]), 0 when it
    /// does not. Not a postcard field: it travels as the session message's 4-byte extension, present only
    /// when > 0 ([`encode_body`]), so a session that does not forget sends the same bytes as before. (Only
    /// with the `forgetting` feature: a firmware built without it carries none of this.)
    #[cfg(feature = "forgetting")]
    #[serde(skip)]
    pub half_life: f32,
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
            int8_scale: 0.0,
            #[cfg(feature = "forgetting")]
            half_life: 0.0,
        }
    }

    /// The same configuration for a map that forgets with `forgetting` (`None`: does not).
    #[cfg(feature = "forgetting")]
    pub fn with_forgetting(self, forgetting: Option<crate::forget::Forgetting>) -> Self {
        Self {
            half_life: forgetting.map_or(0.0, |f| f.half_life()),
            ..self
        }
    }

    /// How the session's maps forget (`None`: they do not; their summaries are unstamped).
    pub fn forgetting(&self) -> Option<crate::forget::Forgetting> {
        #[cfg(feature = "forgetting")]
        return crate::forget::Forgetting::new(self.half_life);
        #[cfg(not(feature = "forgetting"))]
        return None;
    }

    /// The same configuration for a robot whose features are int8 codes of `scale`
    /// ([`Self::int8_scale`]).
    pub const fn with_int8_scale(self, scale: f32) -> Self {
        Self {
            int8_scale: scale,
            ..self
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
        if !(self.int8_scale >= 0.0 && self.int8_scale.is_finite()) {
            return Err(WireError::BadConfig);
        }
        #[cfg(feature = "forgetting")]
        if !(self.half_life >= 0.0 && self.half_life.is_finite()) {
            return Err(WireError::BadConfig);
        }
        Ok(())
    }

    /// The configuration id: CRC-32 of its postcard encoding, followed by the half-life extension when the
    /// session forgets.
    pub fn id(&self) -> u32 {
        let mut buf = [0u8; 64];
        #[cfg(feature = "rice-codes")]
        if self.codec.rice {
            return self.rice_id(&mut buf);
        }
        match postcard::to_slice(self, &mut buf) {
            #[cfg(feature = "forgetting")]
            Ok(bytes) if self.half_life > 0.0 => {
                let mut digest = CRC32.digest();
                digest.update(bytes);
                digest.update(&self.half_life.to_le_bytes());
                digest.finalize()
            }
            Ok(bytes) => CRC32.checksum(bytes),
            Err(_) => 0, // cannot happen: the encoding is at most 44 bytes
        }
    }
}

#[cfg(feature = "rice-codes")]
impl SessionConfig {
    /// [`Self::id`] of a Rice session: CRC-32 of its postcard encoding, the half-life extension when it
    /// forgets, then the Rice extension byte — the bytes of its session message.
    fn rice_id(&self, buf: &mut [u8; 64]) -> u32 {
        let Ok(bytes) = postcard::to_slice(self, buf) else {
            return 0; // cannot happen: the encoding is at most 44 bytes
        };
        let mut digest = CRC32.digest();
        digest.update(bytes);
        #[cfg(feature = "forgetting")]
        if self.half_life > 0.0 {
            digest.update(&self.half_life.to_le_bytes());
        }
        digest.update(&[RICE_EXTENSION]);
        digest.finalize()
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
    /// Frames written again because their acknowledgement was overdue or showed them missing (protocol 3).
    pub resent: u32,
    /// Frames acknowledged by the base station.
    pub acked: u32,
    /// Acknowledgements refused: damaged bytes, malformed, or of another robot or session.
    pub bad_acks: u32,
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
        resent: 0,
        acked: 0,
        bad_acks: 0,
    };
}

/// Summaries packed as the format says ([`super::encode_summary`]); `count` of them, nothing after.
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

/// Serialize header + message into `out`; returns the body length. A session message of a session that
/// forgets ends with its half-life (f32 little-endian: the extension [`SessionConfig::half_life`]).
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
    #[allow(unused_mut)] // extended only with forgetting or Rice codes
    let mut end = h + m;
    #[cfg(feature = "forgetting")]
    if let Message::Session(c) = message {
        if c.half_life > 0.0 {
            out.get_mut(end..end + 4)
                .ok_or(WireError::BufferFull)?
                .copy_from_slice(&c.half_life.to_le_bytes());
            end += 4;
        }
    }
    #[cfg(feature = "rice-codes")]
    if let Message::Session(c) = message {
        if c.codec.rice {
            *out.get_mut(end).ok_or(WireError::BufferFull)? = RICE_EXTENSION;
            end += 1;
        }
    }
    Ok(end)
}

/// The byte that ends a session message whose codec Rice-codes its means ([`SummaryCodec::rice`]).
pub const RICE_EXTENSION: u8 = 1;

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
    #[allow(unused_mut)] // the extensions are read only with forgetting or Rice codes
    let (mut message, mut rest) = postcard::take_from_bytes::<Message<'_>>(rest).map_err(map)?;
    // The Rice extension: one byte, last, only after a session message (packed codes send none).
    #[cfg(feature = "rice-codes")]
    if let (Message::Session(c), [ext @ .., last]) = (&mut message, rest) {
        if ext.is_empty() || ext.len() == 4 {
            if *last != RICE_EXTENSION {
                return Err(WireError::Malformed);
            }
            c.codec.rice = true;
            rest = ext;
        }
    }
    match (&mut message, rest) {
        (_, []) => {}
        // The half-life extension: only after a session message, and only > 0 (0 is sent as no bytes).
        #[cfg(feature = "forgetting")]
        (Message::Session(c), &[a, b, c2, d]) => {
            c.half_life = f32::from_le_bytes([a, b, c2, d]);
            if !(c.half_life > 0.0) {
                return Err(WireError::Malformed);
            }
        }
        _ => return Err(WireError::Malformed),
    }
    Ok((header, message))
}
