//! The sending side: evicted voxels are quantized at once into a fixed byte queue (the encoder is the
//! local map's [`EvictionSink`](crate::sink::EvictionSink); a full queue refuses and the map keeps the voxel), and each
//! [`FrameEncoder::tick`] spends a byte budget on whole frames — overdue re-sends, session header when due,
//! link statistics when due, queued voxels, then live ones — so a slow link sends fewer live updates, never
//! loses an evicted voxel.
//!
//! With a back channel ([`Resend`], protocol 3) part of the queue's bytes hold the frames sent but not yet
//! acknowledged (the `resend` module): frames of final voxels and control frames are kept and re-sent until
//! acknowledged; live updates travel in frames of their own that are not kept (a newer copy supersedes a
//! lost one). When that buffer is full, no new frame is built: the queue stops draining and the map keeps
//! its voxels.
//!
//! Here: the settings, the encoder's state and its session. Submodules, along the data's way: `queue`
//! (evicted voxels quantized into fixed entries), `scheduler` (what a tick's budget is spent on, re-sends
//! first) and `packer` (summaries into frames: CRC-32 and COBS).

use super::ack::Ack;
use super::resend::Ring;
use super::wire_len;
use crate::wire::{LinkStats, SessionConfig, SummaryCodec, WireError};
use queue::ENTRY_HEAD;

/// Largest encoded header + `Voxels` message overhead (header ≤ 19 B, tag + count + length ≤ 7 B).
pub(super) const VOXEL_FRAME_OVERHEAD: usize = 26;

/// How often the encoder repeats the session header and its link statistics.
///
/// ```
/// use latentbki::EncoderSettings;
///
/// // Robot 2, session 41; repeat the session header every 8 frames (a lossy radio), statistics every 64.
/// const LINK: EncoderSettings = EncoderSettings { header_interval: 8, ..EncoderSettings::new(2, 41) };
/// assert_eq!(LINK.stats_interval, 64);
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EncoderSettings {
    /// Robot id.
    pub robot: u16,
    /// Session id: a fresh number per boot (e.g. a boot counter or a random number).
    pub session: u32,
    /// A session header every this many frames (and as the first frame).
    pub header_interval: u32,
    /// Link statistics every this many frames.
    pub stats_interval: u32,
    /// Re-sends over a back channel (protocol 3); [`Resend::OFF`] without one.
    pub resend: Resend,
}

/// Keeping frames until the base station acknowledges them (a link with a back channel).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Resend {
    /// Bytes of the queue budget (`QB`) that hold unacknowledged frames; 0 = no back channel (frames are
    /// sent once and a lost one is counted lost by the receiver). At least one largest frame (`N`) + 11.
    pub bytes: u32,
    /// Ticks after which an unacknowledged frame is written again. A frame that a later frame's
    /// acknowledgement shows missing is written again after half of it (at least one tick).
    pub timeout_ticks: u32,
}

impl Resend {
    /// No back channel.
    pub const OFF: Self = Self {
        bytes: 0,
        timeout_ticks: 0,
    };
    /// Keep unacknowledged frames in `bytes` of the queue budget; re-send after `timeout_ticks` ticks.
    pub const fn new(bytes: u32, timeout_ticks: u32) -> Self {
        Self {
            bytes,
            timeout_ticks,
        }
    }
    /// Whether frames are kept for re-sending.
    pub const fn is_on(&self) -> bool {
        self.bytes > 0
    }
}

impl EncoderSettings {
    /// Header every 32 frames, statistics every 64.
    pub const fn new(robot: u16, session: u32) -> Self {
        Self {
            robot,
            session,
            header_interval: 32,
            stats_interval: 64,
            resend: Resend::OFF,
        }
    }

    /// The same with a back channel: keep unacknowledged frames and re-send them ([`Resend`]).
    pub const fn with_resend(self, resend: Resend) -> Self {
        Self { resend, ..self }
    }
}

/// What one [`FrameEncoder::tick`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TickReport {
    /// Frames written.
    pub frames: u32,
    /// Bytes written (≤ the budget).
    pub bytes: usize,
    /// Evicted voxels sent (removed from the queue).
    pub evicted_sent: u32,
    /// Leading live voxels consumed from the caller's iterator (sent, or skipped as non-finite): the caller
    /// marks exactly these as sent.
    pub live_sent: u32,
    /// Of `bytes`: bytes of frames that carried live voxels only.
    pub live_bytes: usize,
    /// Unacknowledged frames written again.
    pub resent: u32,
    /// Of `bytes`: bytes written again.
    pub resent_bytes: usize,
}

/// Why a tick stopped early. Deliberately not `#[non_exhaustive]`: a tick fails only when its writer does,
/// so with an infallible writer (`Error = Infallible`) `let Ok(report) = mapper.tick(…);` needs no error
/// path.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TickError<E> {
    /// The writer failed; frames before it were written (see the report), the queue keeps the rest.
    Write(E, TickReport),
}

impl<E: core::fmt::Debug> core::fmt::Display for TickError<E> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Write(e, r) => write!(
                f,
                "writing to the link failed ({e:?}) after {} frames ({} B); the queue keeps the rest",
                r.frames, r.bytes
            ),
        }
    }
}

impl<E: core::fmt::Debug> core::error::Error for TickError<E> {}

/// Streams voxel summaries as frames. `D`: feature dimension; `QB`: bytes of queue for evicted voxels;
/// `N`: largest frame on the wire (bytes, delimiters included).
///
/// It holds its buffers inline (≈ `QB` + 2 `N` bytes), so on a microcontroller it belongs in a `static`:
/// [`Self::EMPTY`] is all zero (the static lives in `.bss`) and [`Self::configure`] starts a session in
/// place, so the encoder is never built on the stack.
pub struct FrameEncoder<const D: usize, const QB: usize, const N: usize> {
    settings: EncoderSettings,
    config: SessionConfig,
    config_id: u32,
    seq: u32,
    since_header: u32,
    since_stats: u32,
    queue: [u8; QB],
    /// Oldest entry (< `capacity`).
    head: usize,
    len: usize,
    /// Bytes per queue entry; 0 while unconfigured.
    entry_len: usize,
    /// Entries the queue holds; 0 while unconfigured.
    capacity: usize,
    scratch: [u8; N],
    body: [u8; N],
    stats: LinkStats,
    /// Frames sent and not yet acknowledged, in the last `resend_len` bytes of `queue`.
    ring: Ring,
    /// Bytes at the end of `queue` that hold kept frames (0 without a back channel, so that
    /// [`Self::EMPTY`] stays all zero).
    resend_len: usize,
    /// Ticks so far (the re-send clock).
    now: u32,
    /// Bytes written again, wrapping.
    resent_bytes: u32,
    /// The frame in `scratch` whose write has not succeeded yet (`scheduler::PENDING_*`; 0: none), its wire
    /// length, the queue entries it carries and its live summaries. Plain fields, so that [`Self::EMPTY`]
    /// stays all zero.
    pending_kind: u8,
    pending_len: usize,
    pending_from_queue: usize,
    pending_live: u32,
}

#[cfg(feature = "async")]
mod asynch;
mod blocking;
mod packer;
mod queue;
mod scheduler;

pub use queue::{live, LiveItem};

/// Largest wire size of one summary of a session (a stamped one is [`queue::STAMP_EXTRA`] longer).
fn max_summary_len<const D: usize>(config: &SessionConfig) -> usize {
    let len = config.codec.max_summary_len(D);
    #[cfg(feature = "forgetting")]
    if queue::stamped(config) {
        return len + queue::STAMP_EXTRA;
    }
    len
}

/// A session configuration that validates for no dimension: the unconfigured encoder's.
const NO_SESSION: SessionConfig = SessionConfig {
    dim: 0,
    voxel_size: 0.0,
    kernel_length: 0.0,
    filter_size: 0,
    subvoxel_cells: 0,
    prior_lambda: 0.0,
    prior_mean: 0.0,
    prior_psi: 0.0,
    codec: SummaryCodec {
        mean_bits: 0,
        psi_blocks: 0,
        mean_bits_growth: 0,
        lead: 0,
        lead_bits: 0,
        #[cfg(feature = "rice-codes")]
        rice: false,
    },
    feature_space: 0,
    int8_scale: 0.0,
    #[cfg(feature = "forgetting")]
    half_life: 0.0,
};

impl<const D: usize, const QB: usize, const N: usize> FrameEncoder<D, QB, N> {
    /// An encoder without a session, all zero (so a `static` of it lives in `.bss`). It refuses every
    /// voxel and writes nothing until [`Self::configure`] starts a session.
    pub const EMPTY: Self = Self {
        settings: EncoderSettings {
            robot: 0,
            session: 0,
            header_interval: 0,
            stats_interval: 0,
            resend: Resend::OFF,
        },
        config: NO_SESSION,
        config_id: 0,
        seq: 0,
        since_header: 0,
        since_stats: 0,
        queue: [0; QB],
        head: 0,
        len: 0,
        entry_len: 0,
        capacity: 0,
        scratch: [0; N],
        body: [0; N],
        stats: LinkStats::ZERO,
        ring: Ring::EMPTY,
        resend_len: 0,
        now: 0,
        resent_bytes: 0,
        pending_kind: scheduler::PENDING_NONE,
        pending_len: 0,
        pending_from_queue: 0,
        pending_live: 0,
    };

    /// An encoder for one session. Fails if the configuration is invalid for D, if the queue cannot hold
    /// one voxel or if a frame of `N` bytes cannot carry one summary. (It is `QB` + 2 `N` bytes: on a
    /// microcontroller prefer a static [`Self::EMPTY`] and [`Self::configure`].)
    pub fn new(config: SessionConfig, settings: EncoderSettings) -> Result<Self, WireError> {
        let mut encoder = Self::EMPTY;
        encoder.configure(config, settings)?;
        Ok(encoder)
    }

    /// Start a session in place: everything of the previous one (queued voxels, sequence numbers,
    /// counters) is dropped, and the next [`Self::tick`] begins with a session header. Fails as
    /// [`Self::new`] does, and then leaves the encoder without a session.
    pub fn configure(
        &mut self,
        config: SessionConfig,
        settings: EncoderSettings,
    ) -> Result<(), WireError> {
        self.config = NO_SESSION;
        self.config_id = 0;
        self.settings = settings;
        self.seq = 0;
        self.since_header = 0;
        self.since_stats = 0;
        self.head = 0;
        self.len = 0;
        self.entry_len = 0;
        self.capacity = 0;
        self.stats = LinkStats::ZERO;
        self.ring = Ring::EMPTY;
        self.resend_len = 0;
        self.now = 0;
        self.resent_bytes = 0;
        self.drop_pending();
        config.validate(D)?;
        let resend = settings.resend.bytes as usize;
        if settings.resend.is_on() && (resend > QB || resend < N + 11) {
            return Err(WireError::BufferFull);
        }
        let entry_len = ENTRY_HEAD + queue::stamp_len(&config) + config.codec.code_len(D);
        let capacity = (QB - resend).checked_div(entry_len).unwrap_or(0);
        let one = wire_len(VOXEL_FRAME_OVERHEAD + max_summary_len::<D>(&config));
        if capacity == 0 || one > N || wire_len(64) > N {
            return Err(WireError::BufferFull);
        }
        self.resend_len = resend;
        self.config = config;
        self.config_id = config.id();
        self.entry_len = entry_len;
        self.capacity = capacity;
        Ok(())
    }

    /// Largest wire size of one summary of the session.
    pub(super) fn max_summary_len(&self) -> usize {
        max_summary_len::<D>(&self.config)
    }

    /// Bytes of a summary a tick must have left to begin another frame: the largest one with a head of
    /// at most a packed head's 24 bytes. In a Rice session only keys or residencies ~2²⁰ apart make a
    /// longer head; such a summary waits for the next frame (a frame of `N` holds the longest,
    /// [`Self::max_summary_len`]).
    pub(super) fn frame_reserve(&self) -> usize {
        let codec = self.config.codec;
        if !codec.is_rice() {
            return self.max_summary_len();
        }
        self.max_summary_len() - codec.max_summary_len(D)
            + crate::wire::codec::PACKED_HEAD_MAX
            + codec.code_len(D)
    }

    /// End the session: queued voxels are dropped, nothing is sent and every voxel is refused until the
    /// next [`Self::configure`].
    pub fn close(&mut self) {
        self.config = NO_SESSION;
        self.config_id = 0;
        self.len = 0;
        self.entry_len = 0;
        self.capacity = 0;
        self.ring = Ring::EMPTY;
        self.drop_pending();
    }

    pub(super) fn drop_pending(&mut self) {
        self.pending_kind = scheduler::PENDING_NONE;
        self.pending_len = 0;
        self.pending_from_queue = 0;
        self.pending_live = 0;
    }

    /// Whether a session is configured.
    pub fn is_configured(&self) -> bool {
        self.capacity > 0
    }
    /// The session configuration.
    pub fn config(&self) -> &SessionConfig {
        &self.config
    }
    /// Evicted voxels waiting to be sent.
    pub fn queued(&self) -> usize {
        self.len
    }
    /// How many evicted voxels the queue holds.
    pub fn capacity(&self) -> usize {
        self.capacity
    }
    /// The encoder's counters (also sent as `Stats` frames).
    pub fn stats(&self) -> LinkStats {
        self.stats
    }
    /// Sequence number of the next frame.
    pub fn next_seq(&self) -> u32 {
        self.seq
    }
    /// The session's settings.
    pub fn settings(&self) -> &EncoderSettings {
        &self.settings
    }
    /// Frames sent and not yet acknowledged (0 without a back channel).
    pub fn unacknowledged(&self) -> usize {
        self.ring.frames()
    }
    /// Bytes written again so far (re-sends), wrapping; included in `stats().bytes_sent`.
    pub fn resent_bytes(&self) -> u32 {
        self.resent_bytes
    }
    /// Wire bytes of the frames sent and not yet acknowledged.
    pub fn unacknowledged_bytes(&self) -> usize {
        self.ring.bytes()
    }

    /// Apply an acknowledgement of this session (others are ignored and counted): acknowledged frames are
    /// freed, frames it shows missing are re-sent once half the timeout passed. Returns frames newly acknowledged.
    pub fn acknowledge(&mut self, ack: &Ack) -> u32 {
        if ack.robot != self.settings.robot || ack.session != self.settings.session {
            self.stats.bad_acks = self.stats.bad_acks.saturating_add(1);
            return 0;
        }
        let region = self
            .queue
            .get_mut(QB - self.resend_len..)
            .unwrap_or_default();
        let n = self.ring.ack(region, ack.highest, ack.received);
        self.stats.acked = self.stats.acked.wrapping_add(n);
        n
    }

    /// Count acknowledgements refused before they reached [`Self::acknowledge`] (bad bytes, other robots).
    pub fn count_bad_acks(&mut self, n: u32) {
        self.stats.bad_acks = self.stats.bad_acks.saturating_add(n);
    }
}
