//! The sending side: evicted voxels are quantized at once into a fixed byte queue (the encoder is the
//! local map's [`EvictionSink`]; a full queue refuses and the map keeps the voxel), and each
//! [`FrameEncoder::tick`] spends a byte budget on whole frames — overdue re-sends, session header when due,
//! link statistics when due, queued voxels, then live ones — so a slow link sends fewer live updates, never
//! loses an evicted voxel.
//!
//! With a back channel ([`Resend`], protocol 3) part of the queue's bytes hold the frames sent but not yet
//! acknowledged (the `resend` module): frames of final voxels and control frames are kept and re-sent until
//! acknowledged; live updates travel in frames of their own that are not kept (a newer copy supersedes a
//! lost one). When that buffer is full, no new frame is built: the queue stops draining and the map keeps
//! its voxels.

use super::ack::Ack;
use super::resend::{Ring, ACK_WINDOW};
use super::wire_len;
use crate::key::VoxelKey;
use crate::local_map::LiveVoxel;
use crate::obs::ObsStats;
use crate::sink::{Evicted, EvictionSink, SinkFull};
use crate::wire::{
    encode_body, encode_codes, encode_summary_head, wire_count, DeltaBase, FrameHeader, LinkStats,
    Message, SessionConfig, SummaryCodec, VoxelBatch, WireError, CRC32, PROTOCOL_VERSION,
};

/// Largest encoded header + `Voxels` message overhead (header ≤ 19 B, tag + count + length ≤ 7 B).
const VOXEL_FRAME_OVERHEAD: usize = 26;

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

/// Why a tick stopped early.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TickError<E> {
    /// The writer failed; frames before it were written (see the report), the queue keeps the rest.
    Write(E, TickReport),
}

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
}

/// Fixed part of a queue entry: key (3 × i32), residency (u32), point count (u32), all little-endian.
const ENTRY_HEAD: usize = 20;

/// The fixed part of a queue entry.
fn entry_head(key: VoxelKey, residency: u32, count: u32) -> [u8; ENTRY_HEAD] {
    let [x, y, z] = key.as_array();
    let words = [x as u32, y as u32, z as u32, residency, count];
    let mut head = [0u8; ENTRY_HEAD];
    for (bytes, word) in head.chunks_exact_mut(4).zip(words) {
        bytes.copy_from_slice(&word.to_le_bytes());
    }
    head
}

/// Key, residency and point count of a queue entry's fixed part.
fn parse_entry_head(head: &[u8; ENTRY_HEAD]) -> (VoxelKey, u32, u32) {
    let word = |i: usize| u32::from_le_bytes([head[i], head[i + 1], head[i + 2], head[i + 3]]);
    (
        VoxelKey::new(word(0) as i32, word(4) as i32, word(8) as i32),
        word(12),
        word(16),
    )
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
    },
    feature_space: 0,
    int8_scale: 0.0,
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
        config.validate(D)?;
        let resend = settings.resend.bytes as usize;
        if settings.resend.is_on() && (resend > QB || resend < N + 11) {
            return Err(WireError::BufferFull);
        }
        let entry_len = ENTRY_HEAD + config.codec.code_len(D);
        let capacity = (QB - resend).checked_div(entry_len).unwrap_or(0);
        let one = wire_len(VOXEL_FRAME_OVERHEAD + config.codec.max_summary_len(D));
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

    /// End the session: queued voxels are dropped, nothing is sent and every voxel is refused until the
    /// next [`Self::configure`].
    pub fn close(&mut self) {
        self.config = NO_SESSION;
        self.config_id = 0;
        self.len = 0;
        self.entry_len = 0;
        self.capacity = 0;
        self.ring = Ring::EMPTY;
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

    /// Whether a new frame of `n` wire bytes may be sent now: without a back channel always; with one, if
    /// the re-send buffer can keep it and the oldest unacknowledged frame stays within the receiver's
    /// sequence window.
    fn can_keep(&self, n: usize) -> bool {
        let region = self.queue.get(QB - self.resend_len..).unwrap_or_default();
        self.in_window() && (!self.settings.resend.is_on() || self.ring.fits(region.len(), n))
    }

    /// Whether any new frame may be numbered now: with a back channel, the oldest unacknowledged frame
    /// must stay within the receiver's 64-frame sequence window of the newest, or its re-sent copy would
    /// arrive too old to be applied.
    fn in_window(&self) -> bool {
        let region = self.queue.get(QB - self.resend_len..).unwrap_or_default();
        !self.settings.resend.is_on()
            || self
                .ring
                .oldest_seq(region)
                .is_none_or(|oldest| self.seq.wrapping_sub(oldest) < ACK_WINDOW - 1)
    }

    /// Queue slot `i` places after the oldest entry (`i ≤ capacity`), wrapped around the ring.
    fn slot(&self, i: usize) -> usize {
        let s = self.head + i;
        if s >= self.capacity {
            s - self.capacity
        } else {
            s
        }
    }

    /// Where queue slot `slot` (< `capacity`) lies in `queue`.
    fn slot_bytes(&self, slot: usize) -> core::ops::Range<usize> {
        let at = slot * self.entry_len;
        at..at + self.entry_len
    }

    fn header(&self) -> FrameHeader {
        FrameHeader {
            version: PROTOCOL_VERSION,
            robot: self.settings.robot,
            session: self.settings.session,
            seq: self.seq,
            config_id: self.config_id,
        }
    }

    /// Serialize a control message as the next frame into `scratch`; returns its wire length.
    fn build_message(&mut self, message: Message<'_>) -> Result<usize, WireError> {
        let len = encode_body(&self.header(), &message, &mut self.body)?;
        self.finish(len)
    }

    /// Serialize the `count` summaries in `scratch[..used]` as the next frame into `scratch`.
    fn build_voxels(&mut self, count: u16, used: usize) -> Result<usize, WireError> {
        let header = self.header();
        let batch = VoxelBatch {
            count,
            summaries: self.scratch.get(..used).ok_or(WireError::BufferFull)?,
        };
        let len = encode_body(&header, &Message::Voxels(batch), &mut self.body)?;
        self.finish(len)
    }

    /// Append the CRC to `body[..len]`, COBS it into `scratch` between two delimiters.
    fn finish(&mut self, len: usize) -> Result<usize, WireError> {
        let body = self.body.get(..len).ok_or(WireError::BufferFull)?;
        let crc = CRC32.checksum(body);
        self.body
            .get_mut(len..len + 4)
            .ok_or(WireError::BufferFull)?
            .copy_from_slice(&crc.to_le_bytes());
        let body = self.body.get(..len + 4).ok_or(WireError::BufferFull)?;
        let (first, out) = self
            .scratch
            .split_first_mut()
            .ok_or(WireError::BufferFull)?;
        *first = 0;
        let n = cobs::try_encode(body, out).map_err(|_| WireError::BufferFull)?;
        *out.get_mut(n).ok_or(WireError::BufferFull)? = 0;
        Ok(n + 2)
    }

    /// Write the frame in `scratch[..n]` (`n ≤ N`), counting it; a `kept` frame stays in the re-send
    /// buffer until acknowledged (callers checked [`Self::can_keep`]). The sequence number advances even
    /// when the write fails (a partly written frame must never share its number with the next one).
    fn send<W: embedded_io::Write>(
        &mut self,
        w: &mut W,
        n: usize,
        kept: bool,
    ) -> Result<(), W::Error> {
        let seq = self.seq;
        self.seq = self.seq.wrapping_add(1);
        self.since_header = self.since_header.saturating_add(1);
        self.since_stats = self.since_stats.saturating_add(1);
        let frame = self.scratch.get(..n).unwrap_or_default();
        match w.write_all(frame) {
            Ok(()) => {
                self.stats.frames_sent = self.stats.frames_sent.wrapping_add(1);
                self.stats.bytes_sent = self.stats.bytes_sent.wrapping_add(n as u32);
                if kept && self.settings.resend.is_on() {
                    let region = self
                        .queue
                        .get_mut(QB - self.resend_len..)
                        .unwrap_or_default();
                    self.ring.push(region, seq, self.now, frame);
                }
                Ok(())
            }
            Err(e) => {
                self.stats.write_errors = self.stats.write_errors.saturating_add(1);
                Err(e)
            }
        }
    }

    fn control_frame<W: embedded_io::Write>(
        &mut self,
        w: &mut W,
        message: Message<'_>,
        budget: usize,
        report: &mut TickReport,
    ) -> Result<bool, TickError<W::Error>> {
        let Ok(n) = self.build_message(message) else {
            return Ok(false);
        };
        if report.bytes + n > budget || !self.can_keep(n) {
            return Ok(false);
        }
        self.send(w, n, true)
            .map_err(|e| TickError::Write(e, *report))?;
        report.frames += 1;
        report.bytes += n;
        Ok(true)
    }

    /// Force a session header now (as the first frame it is sent anyway). Returns bytes written (0
    /// without a session).
    pub fn send_header<W: embedded_io::Write>(&mut self, w: &mut W) -> Result<usize, W::Error> {
        if !self.is_configured() {
            return Ok(0);
        }
        let n = self
            .build_message(Message::Session(self.config))
            .unwrap_or(0);
        let kept = self.can_keep(n);
        self.send(w, n, kept)?;
        self.since_header = 0;
        Ok(n)
    }

    /// Force a link-statistics frame now. Returns bytes written (0 without a session).
    pub fn send_stats<W: embedded_io::Write>(&mut self, w: &mut W) -> Result<usize, W::Error> {
        if !self.is_configured() {
            return Ok(0);
        }
        let n = self.build_message(Message::Stats(self.stats)).unwrap_or(0);
        let kept = self.can_keep(n);
        self.send(w, n, kept)?;
        self.since_stats = 0;
        Ok(n)
    }

    /// Write again, oldest first, the unacknowledged frames that are due (timed out, or shown missing by a
    /// later frame's acknowledgement), within `budget`.
    fn resend_due<W: embedded_io::Write>(
        &mut self,
        w: &mut W,
        budget: usize,
        report: &mut TickReport,
    ) -> Result<(), TickError<W::Error>> {
        let timeout = self.settings.resend.timeout_ticks.max(1);
        loop {
            let region = self.queue.get(QB - self.resend_len..).unwrap_or_default();
            let Some((at, record)) = self.ring.due(region, self.now, timeout) else {
                return Ok(());
            };
            let frame = self.ring.frame(region, at, &record);
            if report.bytes + frame.len() > budget {
                return Ok(());
            }
            let n = frame.len();
            w.write_all(frame)
                .map_err(|e| TickError::Write(e, *report))?;
            let region = self
                .queue
                .get_mut(QB - self.resend_len..)
                .unwrap_or_default();
            self.ring.resent(region, at, self.now);
            report.frames += 1;
            report.bytes += n;
            report.resent += 1;
            report.resent_bytes += n;
            self.stats.bytes_sent = self.stats.bytes_sent.wrapping_add(n as u32);
            self.stats.resent = self.stats.resent.wrapping_add(1);
            self.resent_bytes = self.resent_bytes.wrapping_add(n as u32);
        }
    }

    /// Spend up to `budget` bytes: overdue re-sends (with a back channel), the session header if due, link
    /// statistics if due, then queued evicted voxels (oldest first), then `live` voxels in the caller's
    /// order (most changed first). Only whole frames are written; without a session nothing is. With a
    /// back channel, live voxels travel in frames of their own (not kept), and no new kept frame is built
    /// while the re-send buffer is full.
    pub fn tick<'a, W, I>(
        &mut self,
        w: &mut W,
        budget: usize,
        live: I,
    ) -> Result<TickReport, TickError<W::Error>>
    where
        W: embedded_io::Write,
        I: IntoIterator<Item = Evicted<'a, D>>,
    {
        self.tick_live(w, budget, usize::MAX, live)
    }

    /// [`Self::tick`] with at most `live_budget` of the `budget` bytes spent on frames of live voxels
    /// (with a back channel; without one, live voxels also fill the room queued voxels leave in a frame).
    pub fn tick_live<W, I>(
        &mut self,
        w: &mut W,
        budget: usize,
        live_budget: usize,
        live: I,
    ) -> Result<TickReport, TickError<W::Error>>
    where
        W: embedded_io::Write,
        I: IntoIterator,
        I::Item: LiveItem<D>,
    {
        let mut report = TickReport::default();
        if !self.is_configured() {
            return Ok(report);
        }
        self.now = self.now.wrapping_add(1);
        let reliable = self.settings.resend.is_on();
        if reliable {
            self.resend_due(w, budget, &mut report)?;
        }
        if self.seq == 0 || self.since_header >= self.settings.header_interval {
            if self.control_frame(w, Message::Session(self.config), budget, &mut report)? {
                self.since_header = 0;
            } else {
                return Ok(report); // nothing else may go before the header
            }
        }
        if self.since_stats >= self.settings.stats_interval
            && self.control_frame(w, Message::Stats(self.stats), budget, &mut report)?
        {
            self.since_stats = 0;
        }
        let mut live = live.into_iter().peekable();
        let smallest = wire_len(VOXEL_FRAME_OVERHEAD + self.config.codec.max_summary_len(D));
        loop {
            let mut limit = N.min(budget.saturating_sub(report.bytes));
            if limit < smallest {
                break;
            }
            // Fill one frame: queued evicted voxels first, then live ones.
            let mut used = 0usize;
            let mut count = 0u16;
            let mut from_queue = 0usize;
            let mut from_live = 0u32;
            let mut base = DeltaBase::default();
            let codec = self.config.codec;
            while from_queue < self.len && count < u16::MAX {
                let bytes = self.slot_bytes(self.slot(from_queue));
                let Some((head, codes)) = self
                    .queue
                    .get(bytes)
                    .and_then(|e| e.split_first_chunk::<ENTRY_HEAD>())
                else {
                    break;
                };
                let (key, residency, points) = parse_entry_head(head);
                let summary = (key, residency, points, Codes::<D>::Queued(codes));
                if !append(
                    &mut self.scratch,
                    &mut used,
                    &mut base,
                    limit,
                    codec,
                    summary,
                ) {
                    break;
                }
                count += 1;
                from_queue += 1;
            }
            // With a back channel a frame is either kept (final voxels) or live-only (not kept).
            if from_queue == self.len && (!reliable || count == 0) {
                if count == 0 {
                    limit = limit.min(live_budget.saturating_sub(report.live_bytes));
                    if limit < smallest {
                        break;
                    }
                }
                while let Some(item) = live.peek() {
                    if count == u16::MAX {
                        break;
                    }
                    let v = item.voxel();
                    // Consumed either way: sent, or skipped because the decoder would refuse it.
                    if let Some(n) = sendable(v.obs) {
                        let summary = (v.key, v.residency, n, Codes::Live(v.obs));
                        if !append(
                            &mut self.scratch,
                            &mut used,
                            &mut base,
                            limit,
                            codec,
                            summary,
                        ) {
                            break;
                        }
                        count += 1;
                    }
                    from_live += 1;
                    live.next();
                }
            }
            if count == 0 {
                report.live_sent += from_live; // only skipped (unsendable) items
                break;
            }
            let Ok(n) = self.build_voxels(count, used) else {
                break;
            };
            let kept = from_queue > 0;
            if (kept && !self.can_keep(n)) || !self.in_window() {
                break; // back-pressure: the re-send buffer is full
            }
            self.send(w, n, kept)
                .map_err(|e| TickError::Write(e, report))?;
            if !kept {
                report.live_bytes += n;
            }
            // Sent: drop the queue entries, count everything.
            self.head = self.slot(from_queue);
            self.len -= from_queue;
            report.frames += 1;
            report.bytes += n;
            report.evicted_sent += from_queue as u32;
            report.live_sent += from_live;
            self.stats.evicted_sent = self.stats.evicted_sent.wrapping_add(from_queue as u32);
            self.stats.live_sent = self
                .stats
                .live_sent
                .wrapping_add(count as u32 - from_queue as u32);
        }
        Ok(report)
    }
}

/// Where a summary's quantized part comes from: an evicted voxel's, encoded when it was queued, or a live
/// voxel's statistics, encoded now.
enum Codes<'a, const D: usize> {
    Queued(&'a [u8]),
    Live(&'a ObsStats<D>),
}

/// Append one summary — (key, residency, point count, codes) — to the frame being filled in
/// `out[..*used]` if the frame still fits in `limit` wire bytes; `base` is the delta-coding state. Both
/// kinds of summary go through here; a queued one is marked evicted (closed), a live one is not.
fn append<const D: usize>(
    out: &mut [u8],
    used: &mut usize,
    base: &mut DeltaBase,
    limit: usize,
    codec: SummaryCodec,
    (key, residency, count, codes): (VoxelKey, u32, u32, Codes<'_, D>),
) -> bool {
    let mut trial = *base;
    let evicted = matches!(codes, Codes::Queued(_));
    let Some(Ok(h)) = out
        .get_mut(*used..)
        .map(|o| encode_summary_head(&mut trial, key, residency, evicted, count, o))
    else {
        return false;
    };
    let at = *used + h;
    let c = match codes {
        Codes::Queued(codes) => {
            // The queue entry has room for the largest codes; this summary's are the leading ones.
            let codes = codes.get(..codec.code_len_for(D, count)).unwrap_or(codes);
            match out.get_mut(at..at + codes.len()) {
                Some(o) => {
                    o.copy_from_slice(codes);
                    codes.len()
                }
                None => return false,
            }
        }
        Codes::Live(obs) => match out.get_mut(at..).map(|o| encode_codes(codec, obs, o)) {
            Some(Ok(c)) => c,
            _ => return false,
        },
    };
    if wire_len(VOXEL_FRAME_OVERHEAD + at + c) > limit {
        return false;
    }
    *used = at + c;
    *base = trial;
    true
}

/// The wire count of statistics the decoder accepts (valid, a whole count in 1..=2²⁴), or `None`: the
/// encoder never sends what the base station would refuse — a refused summary takes its whole frame with it.
fn sendable<const D: usize>(obs: &ObsStats<D>) -> Option<u32> {
    if obs.is_valid() {
        wire_count(obs.count)
    } else {
        None
    }
}

impl<const D: usize, const QB: usize, const N: usize> EvictionSink<D> for FrameEncoder<D, QB, N> {
    /// Quantize the voxel into the queue now; refuse when the queue is full (or there is no session). A
    /// non-finite voxel is counted as invalid and dropped (the map must not keep retrying it).
    fn evict(&mut self, voxel: Evicted<'_, D>) -> Result<(), SinkFull> {
        let Some(count) = sendable(voxel.obs) else {
            self.stats.invalid = self.stats.invalid.saturating_add(1);
            return Ok(());
        };
        if self.len == self.capacity {
            self.stats.refused = self.stats.refused.saturating_add(1);
            return Err(SinkFull);
        }
        let bytes = self.slot_bytes(self.slot(self.len));
        let codec = self.config.codec;
        let written = self
            .queue
            .get_mut(bytes)
            .and_then(|e| e.split_first_chunk_mut::<ENTRY_HEAD>())
            .map(|(head, codes)| {
                *head = entry_head(voxel.key, voxel.residency, count);
                encode_codes(codec, voxel.obs, codes)
            });
        if !matches!(written, Some(Ok(_))) {
            // Cannot happen: the codec was validated for D and the queue sized for whole entries.
            self.stats.invalid = self.stats.invalid.saturating_add(1);
            return Ok(());
        }
        self.len += 1;
        self.stats.queue_peak = self.stats.queue_peak.max(self.len as u32);
        Ok(())
    }
}

/// A voxel the encoder can stream live: a borrowed [`Evicted`] view, or a decoded [`LiveVoxel`] from the
/// local map.
pub trait LiveItem<const D: usize> {
    /// The voxel, borrowed.
    fn voxel(&self) -> Evicted<'_, D>;
}

impl<const D: usize> LiveItem<D> for Evicted<'_, D> {
    fn voxel(&self) -> Evicted<'_, D> {
        *self
    }
}

impl<const D: usize> LiveItem<D> for LiveVoxel<D> {
    fn voxel(&self) -> Evicted<'_, D> {
        live(self.key, &self.obs, self.residency)
    }
}

/// A live voxel as the encoder takes it; convenience for callers holding `(key, obs, residency)` tuples.
pub fn live<const D: usize>(key: VoxelKey, obs: &ObsStats<D>, residency: u32) -> Evicted<'_, D> {
    Evicted {
        key,
        obs,
        residency,
    }
}
