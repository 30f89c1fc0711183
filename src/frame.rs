//! Frames on a byte link: COBS + CRC-32 + sequence numbers, in fixed buffers.
//!
//! A serial link flips bits, drops bytes, cuts frames short and repeats them. Each frame is therefore
//! self-contained and self-checking ([`crate::wire`] gives the layout): COBS makes 0x00 a pure delimiter,
//! so a receiver re-synchronises at the next 0x00 after any damage; a CRC-32 refuses damaged frames
//! whole; a per-session sequence number lets the receiver count every frame it never got.
//!
//! The sending side is [`FrameEncoder`]: it is the local map's [`EvictionSink`] (evicted voxels are
//! quantized at once into a fixed byte queue; a full queue refuses, and the map keeps the voxel), and each
//! [`FrameEncoder::tick`] spends a byte budget — session header when due, then evicted voxels, then the
//! live voxels the caller ranks most changed — so a slow link degrades by sending fewer live updates, never
//! by losing evicted voxels. It writes whole frames through [`embedded_io::Write`], so any HAL's UART works.
//!
//! The receiving side is [`FrameDecoder`] (bytes in arbitrary chunks → checked frame bodies) and
//! [`SeqTracker`] (lost, duplicate and late frames of one session).

use crate::key::VoxelKey;
use crate::obs::ObsStats;
use crate::sink::{Evicted, EvictionSink, SinkFull};
use crate::wire::{
    encode_body, encode_codes, encode_summary_head, wire_count, DeltaBase, FrameHeader, LinkStats,
    Message, SessionConfig, SummaryCodec, VoxelBatch, WireError, CRC32, PROTOCOL_VERSION,
};

/// Bytes a frame body of `body_len` bytes takes on the wire, at most: two delimiters, COBS overhead, CRC.
pub const fn wire_len(body_len: usize) -> usize {
    let n = body_len + 4;
    n + n / 254 + 1 + 2
}

/// Largest encoded header + `Voxels` message overhead (header ≤ 19 B, tag + count + length ≤ 7 B).
const VOXEL_FRAME_OVERHEAD: usize = 26;

/// How often the encoder repeats the session header and its link statistics.
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
}

impl EncoderSettings {
    /// Header every 32 frames, statistics every 64.
    pub const fn new(robot: u16, session: u32) -> Self {
        Self {
            robot,
            session,
            header_interval: 32,
            stats_interval: 64,
        }
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
    },
    feature_space: 0,
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
        config.validate(D)?;
        let entry_len = ENTRY_HEAD + config.codec.code_len(D);
        let capacity = QB / entry_len;
        let one = wire_len(VOXEL_FRAME_OVERHEAD + config.codec.max_summary_len(D));
        if capacity == 0 || one > N || wire_len(64) > N {
            return Err(WireError::BufferFull);
        }
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

    /// Write the frame in `scratch[..n]` (`n ≤ N`), counting it. The sequence number advances even when
    /// the write fails (a partly written frame must never share its number with the next one).
    fn send<W: embedded_io::Write>(&mut self, w: &mut W, n: usize) -> Result<(), W::Error> {
        self.seq = self.seq.wrapping_add(1);
        self.since_header = self.since_header.saturating_add(1);
        self.since_stats = self.since_stats.saturating_add(1);
        match w.write_all(&self.scratch[..n.min(N)]) {
            Ok(()) => {
                self.stats.frames_sent = self.stats.frames_sent.wrapping_add(1);
                self.stats.bytes_sent = self.stats.bytes_sent.wrapping_add(n as u32);
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
        if report.bytes + n > budget {
            return Ok(false);
        }
        self.send(w, n).map_err(|e| TickError::Write(e, *report))?;
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
        self.send(w, n)?;
        self.since_header = 0;
        Ok(n)
    }

    /// Force a link-statistics frame now. Returns bytes written (0 without a session).
    pub fn send_stats<W: embedded_io::Write>(&mut self, w: &mut W) -> Result<usize, W::Error> {
        if !self.is_configured() {
            return Ok(0);
        }
        let n = self.build_message(Message::Stats(self.stats)).unwrap_or(0);
        self.send(w, n)?;
        self.since_stats = 0;
        Ok(n)
    }

    /// Spend up to `budget` bytes: the session header if due, link statistics if due, then queued evicted
    /// voxels (oldest first), then `live` voxels in the caller's order (most changed first). Only whole
    /// frames are written; without a session nothing is.
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
        let mut report = TickReport::default();
        if !self.is_configured() {
            return Ok(report);
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
        loop {
            let limit = N.min(budget.saturating_sub(report.bytes));
            if limit < wire_len(VOXEL_FRAME_OVERHEAD + self.config.codec.max_summary_len(D)) {
                break;
            }
            // Fill one frame: queued evicted voxels first, then live ones.
            let mut used = 0usize;
            let mut count = 0u16;
            let mut from_queue = 0usize;
            let mut from_live = 0u32;
            let mut base = DeltaBase::default();
            let fits = |used: usize| wire_len(VOXEL_FRAME_OVERHEAD + used) <= limit;
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
                let mut trial = base;
                let Some(Ok(h)) = self
                    .scratch
                    .get_mut(used..)
                    .map(|out| encode_summary_head(&mut trial, key, residency, true, points, out))
                else {
                    break;
                };
                let end = used + h + codes.len();
                if !fits(end) {
                    break;
                }
                let Some(out) = self.scratch.get_mut(used + h..end) else {
                    break;
                };
                out.copy_from_slice(codes);
                used = end;
                base = trial;
                count += 1;
                from_queue += 1;
            }
            if from_queue == self.len {
                while let Some(v) = live.peek() {
                    if count == u16::MAX {
                        break;
                    }
                    let Some(n) = sendable(v.obs) else {
                        live.next();
                        from_live += 1;
                        continue;
                    };
                    let mut trial = base;
                    let Some(Ok(h)) = self.scratch.get_mut(used..).map(|out| {
                        encode_summary_head(&mut trial, v.key, v.residency, false, n, out)
                    }) else {
                        break;
                    };
                    let Some(Ok(c)) = self
                        .scratch
                        .get_mut(used + h..)
                        .map(|out| encode_codes(self.config.codec, v.obs, out))
                    else {
                        break;
                    };
                    if !fits(used + h + c) {
                        break;
                    }
                    used += h + c;
                    base = trial;
                    count += 1;
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
            self.send(w, n).map_err(|e| TickError::Write(e, report))?;
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

/// A live voxel as the encoder takes it; convenience for callers holding `(key, obs, residency)` tuples.
pub fn live<const D: usize>(key: VoxelKey, obs: &ObsStats<D>, residency: u32) -> Evicted<'_, D> {
    Evicted {
        key,
        obs,
        residency,
    }
}

// ---------------------------------------------------------------------------------------------------------
// Receiving.

/// Why a run of bytes between delimiters was not a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameError {
    /// Not valid COBS.
    Cobs,
    /// Fewer than 5 bytes after decoding (no room for a body and a CRC).
    TooShort,
    /// CRC-32 mismatch.
    Crc,
    /// Longer than the decoder's buffer; discarded up to the next delimiter.
    Overflow,
}

/// Counters of a [`FrameDecoder`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DecoderStats {
    /// Frames that passed COBS and CRC.
    pub frames: u32,
    /// Refused: not COBS.
    pub cobs_errors: u32,
    /// Refused: too short.
    pub too_short: u32,
    /// Refused: CRC mismatch.
    pub crc_errors: u32,
    /// Refused: longer than the buffer.
    pub overflows: u32,
}

impl DecoderStats {
    /// All refused runs.
    pub fn refused(&self) -> u32 {
        self.cobs_errors
            .saturating_add(self.too_short)
            .saturating_add(self.crc_errors)
            .saturating_add(self.overflows)
    }
}

/// Result of [`FrameDecoder::feed`].
#[derive(Debug, PartialEq, Eq)]
pub enum Feed<'a, 'b> {
    /// All input consumed, no frame completed.
    NeedMore,
    /// A checked frame body (CRC removed); `rest` is the input not yet consumed.
    Frame {
        /// The body: header + message.
        body: &'a [u8],
        /// Unconsumed input.
        rest: &'b [u8],
    },
    /// A run of bytes was refused; `rest` is the input not yet consumed.
    Error {
        /// Why.
        error: FrameError,
        /// Unconsumed input.
        rest: &'b [u8],
    },
}

/// Accumulates bytes into frames. `N`: largest encoded frame (between delimiters) it accepts.
pub struct FrameDecoder<const N: usize> {
    buf: [u8; N],
    len: usize,
    overflow: bool,
    stats: DecoderStats,
}

impl<const N: usize> Default for FrameDecoder<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> FrameDecoder<N> {
    /// An empty decoder.
    pub const fn new() -> Self {
        Self {
            buf: [0; N],
            len: 0,
            overflow: false,
            stats: DecoderStats {
                frames: 0,
                cobs_errors: 0,
                too_short: 0,
                crc_errors: 0,
                overflows: 0,
            },
        }
    }

    /// Counters so far.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Consume input up to the end of the next frame (or of the input). Call again with `rest`.
    pub fn feed<'a, 'b>(&'a mut self, input: &'b [u8]) -> Feed<'a, 'b> {
        for (i, &byte) in input.iter().enumerate() {
            if byte != 0 {
                if self.len < N {
                    self.buf[self.len] = byte;
                    self.len += 1;
                } else {
                    self.overflow = true;
                }
                continue;
            }
            let rest = &input[i + 1..];
            let n = core::mem::take(&mut self.len);
            if core::mem::take(&mut self.overflow) {
                self.stats.overflows = self.stats.overflows.saturating_add(1);
                return Feed::Error {
                    error: FrameError::Overflow,
                    rest,
                };
            }
            if n == 0 {
                continue; // empty frame: back-to-back delimiters
            }
            let error = match cobs::decode_in_place(&mut self.buf[..n]) {
                Err(_) => {
                    self.stats.cobs_errors = self.stats.cobs_errors.saturating_add(1);
                    FrameError::Cobs
                }
                Ok(m) if m < 5 || m > n => {
                    self.stats.too_short = self.stats.too_short.saturating_add(1);
                    FrameError::TooShort
                }
                Ok(m) => {
                    let (body, crc) = self.buf[..m].split_at(m - 4);
                    if CRC32.checksum(body).to_le_bytes() == crc {
                        self.stats.frames = self.stats.frames.saturating_add(1);
                        return Feed::Frame { body, rest };
                    }
                    self.stats.crc_errors = self.stats.crc_errors.saturating_add(1);
                    FrameError::Crc
                }
            };
            return Feed::Error { error, rest };
        }
        Feed::NeedMore
    }
}

/// What [`SeqTracker::accept`] decided about a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SeqVerdict {
    /// The newest frame so far (frames skipped over are counted lost).
    New,
    /// An older frame not received before (it had been counted lost; no longer).
    Late,
    /// Received before: drop it.
    Duplicate,
    /// Older than the 64-frame window: drop it.
    TooOld,
}

/// Sequence numbers of one session: counts lost, duplicate and late frames (a 64-frame window).
/// Serializable so that a receiver can persist it with the frames it marks merged (the base station's
/// database).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SeqTracker {
    started: bool,
    highest: u32,
    window: u64,
    /// Frames accepted (new or late).
    pub received: u32,
    /// Frames never received: sequence numbers skipped and not filled in later.
    pub lost: u32,
    /// Frames received twice (dropped).
    pub duplicates: u32,
    /// Frames that arrived after a newer one (accepted).
    pub late: u32,
    /// Frames older than the window (dropped).
    pub too_old: u32,
}

impl SeqTracker {
    /// Record a frame's sequence number; say whether to accept it. The session starts at sequence 0, so
    /// a first frame numbered n means n frames were lost before it.
    pub fn accept(&mut self, seq: u32) -> SeqVerdict {
        if !self.started {
            self.started = true;
            self.highest = seq;
            self.window = 1;
            self.lost = self.lost.saturating_add(seq);
            self.received = self.received.saturating_add(1);
            return SeqVerdict::New;
        }
        let ahead = seq.wrapping_sub(self.highest);
        if ahead != 0 && ahead < 1 << 31 {
            self.lost = self.lost.saturating_add(ahead - 1);
            self.window = if ahead >= 64 { 0 } else { self.window << ahead };
            self.window |= 1;
            self.highest = seq;
            self.received = self.received.saturating_add(1);
            return SeqVerdict::New;
        }
        let back = self.highest.wrapping_sub(seq);
        if back >= 64 {
            self.too_old = self.too_old.saturating_add(1);
            return SeqVerdict::TooOld;
        }
        if self.window >> back & 1 == 1 {
            self.duplicates = self.duplicates.saturating_add(1);
            return SeqVerdict::Duplicate;
        }
        self.window |= 1 << back;
        self.lost = self.lost.saturating_sub(1);
        self.late = self.late.saturating_add(1);
        self.received = self.received.saturating_add(1);
        SeqVerdict::Late
    }

    /// Highest sequence number seen (if any).
    pub fn highest(&self) -> Option<u32> {
        self.started.then_some(self.highest)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::MapConfig;
    use crate::wire::parse_body;

    type Enc = FrameEncoder<8, 1024, 256>;

    fn config() -> SessionConfig {
        SessionConfig::new(&MapConfig::default(), 8, SummaryCodec::DEFAULT, 0)
    }

    fn voxel(i: i32) -> ObsStats<8> {
        ObsStats {
            count: 1.0 + i as f32,
            mean: core::array::from_fn(|d| (d as f32 - 3.5) * 0.1 + i as f32 * 0.01),
            scatter: [1.5; 8],
        }
    }

    /// A Write into a fixed buffer.
    struct Buf {
        data: [u8; 8192],
        len: usize,
    }
    impl embedded_io::ErrorType for Buf {
        type Error = embedded_io::ErrorKind;
    }
    impl embedded_io::Write for Buf {
        fn write(&mut self, b: &[u8]) -> Result<usize, Self::Error> {
            let n = b.len().min(self.data.len() - self.len);
            if n == 0 && !b.is_empty() {
                return Err(embedded_io::ErrorKind::OutOfMemory);
            }
            self.data[self.len..self.len + n].copy_from_slice(&b[..n]);
            self.len += n;
            Ok(n)
        }
        fn flush(&mut self) -> Result<(), Self::Error> {
            Ok(())
        }
    }

    #[test]
    fn queue_refuses_when_full_and_tick_respects_the_budget() {
        let mut enc = Enc::new(config(), EncoderSettings::new(1, 2)).unwrap();
        let cap = enc.capacity();
        let stats: [ObsStats<8>; 64] = core::array::from_fn(|i| voxel(i as i32));
        for (i, s) in stats.iter().enumerate().take(cap) {
            assert_eq!(
                enc.evict(live(VoxelKey::new(i as i32, 0, 0), s, i as u32)),
                Ok(())
            );
        }
        assert_eq!(
            enc.evict(live(VoxelKey::new(99, 0, 0), &stats[0], 99)),
            Err(SinkFull)
        );
        assert_eq!(enc.stats().refused, 1);
        let mut out = Buf {
            data: [0; 8192],
            len: 0,
        };
        let r = enc.tick(&mut out, 100, core::iter::empty()).unwrap();
        assert!(r.bytes <= 100 && r.bytes == out.len);
        assert_eq!(r.frames, 1, "only the session header fits in 100 bytes");
        let r2 = enc.tick(&mut out, 10_000, core::iter::empty()).unwrap();
        assert_eq!(r2.evicted_sent as usize, cap);
        assert_eq!(enc.queued(), 0);
        // Decode everything: a header, then exactly the queued voxels in order.
        let mut dec = FrameDecoder::<256>::new();
        let mut input = &out.data[..out.len];
        let mut keys = heapless::Vec::<i32, 64>::new();
        let mut seqs = heapless::Vec::<u32, 16>::new();
        loop {
            match dec.feed(input) {
                Feed::NeedMore => break,
                Feed::Error { error, .. } => panic!("{error:?}"),
                Feed::Frame { body, rest } => {
                    let (h, m) = parse_body(body).unwrap();
                    seqs.push(h.seq).unwrap();
                    if let Message::Voxels(b) = m {
                        for s in b.iter::<8>(SummaryCodec::DEFAULT) {
                            let s = s.unwrap();
                            assert!(s.is_final);
                            assert_eq!(s.obs.count, stats[s.key.x as usize].count);
                            keys.push(s.key.x).unwrap();
                        }
                    }
                    input = rest;
                }
            }
        }
        assert!(keys.iter().copied().eq(0..cap as i32));
        assert!(seqs.iter().copied().eq(0..seqs.len() as u32));
    }

    #[test]
    fn live_voxels_follow_evicted_ones_and_report_a_prefix() {
        let mut enc = Enc::new(config(), EncoderSettings::new(1, 2)).unwrap();
        let s = voxel(1);
        enc.evict(live(VoxelKey::new(0, 0, 0), &s, 1)).unwrap();
        let lives: [ObsStats<8>; 40] = core::array::from_fn(|i| voxel(i as i32));
        let mut out = Buf {
            data: [0; 8192],
            len: 0,
        };
        let budget = 600;
        let r = enc
            .tick(
                &mut out,
                budget,
                lives
                    .iter()
                    .enumerate()
                    .map(|(i, s)| live(VoxelKey::new(i as i32, 1, 0), s, 100 + i as u32)),
            )
            .unwrap();
        assert_eq!(r.evicted_sent, 1);
        assert!(
            r.live_sent > 0 && (r.live_sent as usize) < lives.len(),
            "{r:?}"
        );
        assert!(r.bytes <= budget);
    }

    #[test]
    fn live_voxels_the_decoder_would_refuse_are_skipped_not_sent() {
        // n = 0 (nothing observed) and NaN among good live voxels: a sent one would make the
        // base station refuse the whole frame, final summaries included.
        let mut enc = Enc::new(config(), EncoderSettings::new(1, 2)).unwrap();
        enc.evict(live(VoxelKey::new(0, 0, 0), &voxel(1), 1))
            .unwrap();
        let mut lives: [ObsStats<8>; 6] = core::array::from_fn(|i| voxel(i as i32));
        lives[1].count = 0.0;
        lives[4].mean[2] = f32::NAN;
        let mut out = Buf {
            data: [0; 8192],
            len: 0,
        };
        let r = enc
            .tick(
                &mut out,
                10_000,
                lives
                    .iter()
                    .enumerate()
                    .map(|(i, s)| live(VoxelKey::new(i as i32, 1, 0), s, 10 + i as u32)),
            )
            .unwrap();
        assert_eq!((r.evicted_sent, r.live_sent), (1, 6), "{r:?}");
        let mut dec = FrameDecoder::<256>::new();
        let mut input = &out.data[..out.len];
        let mut live_keys = heapless::Vec::<i32, 8>::new();
        while let Feed::Frame { body, rest } = dec.feed(input) {
            if let (_, Message::Voxels(b)) = parse_body(body).unwrap() {
                for s in b.iter::<8>(SummaryCodec::DEFAULT) {
                    let s = s.expect("every summary sent is one the decoder accepts");
                    if !s.is_final {
                        live_keys.push(s.key.x).unwrap();
                    }
                }
            }
            input = rest;
        }
        assert_eq!(live_keys.as_slice(), &[0, 2, 3, 5]);
    }

    #[test]
    fn an_empty_encoder_refuses_and_configure_starts_afresh() {
        let buf = || Buf {
            data: [0; 8192],
            len: 0,
        };
        let s = voxel(3);
        let mut enc = Enc::EMPTY;
        assert!(!enc.is_configured());
        assert_eq!(
            enc.evict(live(VoxelKey::new(1, 2, 3), &s, 7)),
            Err(SinkFull)
        );
        let mut out = buf();
        let r = enc.tick(&mut out, 10_000, core::iter::empty()).unwrap();
        assert_eq!((r.frames, out.len), (0, 0));
        assert_eq!(enc.send_header(&mut out), Ok(0));
        assert_eq!(enc.send_stats(&mut out), Ok(0));
        assert_eq!(out.len, 0);
        // A used encoder reconfigured in place writes exactly what a new one writes.
        let run = |enc: &mut Enc| {
            let mut out = buf();
            for i in 0..5 {
                enc.evict(live(VoxelKey::new(i, -i, 2 * i), &s, i as u32))
                    .unwrap();
            }
            enc.tick(&mut out, 10_000, core::iter::empty()).unwrap();
            enc.send_stats(&mut out).unwrap();
            out
        };
        let fresh = run(&mut Enc::new(config(), EncoderSettings::new(1, 2)).unwrap());
        let mut reused = Enc::new(config(), EncoderSettings::new(9, 9)).unwrap();
        run(&mut reused);
        reused.evict(live(VoxelKey::new(9, 9, 9), &s, 99)).unwrap();
        reused
            .configure(config(), EncoderSettings::new(1, 2))
            .unwrap();
        assert_eq!((reused.queued(), reused.next_seq()), (0, 0));
        let again = run(&mut reused);
        assert_eq!(fresh.data[..fresh.len], again.data[..again.len]);
        // A configuration that does not fit leaves it without a session.
        let bad = SessionConfig { dim: 9, ..config() };
        assert!(reused.configure(bad, EncoderSettings::new(1, 2)).is_err());
        assert!(!reused.is_configured());
        assert_eq!(
            reused.evict(live(VoxelKey::new(1, 2, 3), &s, 7)),
            Err(SinkFull)
        );
    }

    #[test]
    fn decoder_resyncs_after_garbage_and_counts_it() {
        let mut enc = Enc::new(config(), EncoderSettings::new(1, 2)).unwrap();
        let mut a = Buf {
            data: [0; 8192],
            len: 0,
        };
        enc.send_header(&mut a).unwrap();
        let first = a.len;
        enc.send_header(&mut a).unwrap();
        // Corrupt one byte in the first frame, feed byte by byte.
        a.data[first / 2] ^= 0x10;
        let mut dec = FrameDecoder::<256>::new();
        let (mut ok, mut bad) = (0, 0);
        for b in &a.data[..a.len] {
            match dec.feed(core::slice::from_ref(b)) {
                Feed::Frame { body, .. } => {
                    assert_eq!(parse_body(body).unwrap().0.seq, 1);
                    ok += 1;
                }
                Feed::Error { .. } => bad += 1,
                Feed::NeedMore => {}
            }
        }
        assert_eq!((ok, bad), (1, 1));
        // Overflow: a run longer than the buffer is refused, the next frame still decodes.
        let mut dec = FrameDecoder::<16>::new();
        assert!(matches!(dec.feed(&[1u8; 40]), Feed::NeedMore));
        assert!(matches!(
            dec.feed(&[0]),
            Feed::Error {
                error: FrameError::Overflow,
                ..
            }
        ));
        assert_eq!(dec.stats().overflows, 1);
    }

    #[test]
    fn seq_tracker_counts_loss_duplicates_and_late_frames() {
        let mut t = SeqTracker::default();
        assert_eq!(t.accept(2), SeqVerdict::New); // 0, 1 lost
        assert_eq!(t.accept(3), SeqVerdict::New);
        assert_eq!(t.accept(3), SeqVerdict::Duplicate);
        assert_eq!(t.accept(7), SeqVerdict::New); // 4, 5, 6 lost
        assert_eq!(t.lost, 5);
        assert_eq!(t.accept(5), SeqVerdict::Late);
        assert_eq!(t.accept(5), SeqVerdict::Duplicate);
        assert_eq!(t.lost, 4);
        assert_eq!(t.accept(200), SeqVerdict::New);
        assert_eq!(t.accept(100), SeqVerdict::TooOld);
        assert_eq!(t.lost, 4 + 192);
        assert_eq!((t.received, t.duplicates, t.late, t.too_old), (5, 2, 1, 1));
    }
}
