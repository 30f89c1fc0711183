//! The tick's schedule: what a byte budget is spent on, in order — overdue re-sends, a frame whose write
//! failed, the session header and link statistics when due, queued evicted voxels, then live ones — and
//! which new frames may be numbered while frames wait for acknowledgement.
//!
//! A tick is a loop of *plan one frame, write it, commit it*: [`FrameEncoder::plan`] says which bytes go
//! next (a kept frame again, or a new frame it built in `scratch`), the caller writes them (blocking
//! [`embedded_io::Write`] in `blocking`, `embedded_io_async` in `asynch`), and [`FrameEncoder::commit`] does what the
//! write means. So the blocking and the async tick share every decision and differ only in the `.await`.
//!
//! **A failed write consumes nothing.** A new frame is numbered, counted and its voxels leave the queue only
//! once it was written whole. Until then it stays in `scratch` as the *pending* frame, and the next tick
//! writes it again, byte for byte, before anything new: whatever part of the first attempt reached the link
//! (nothing, a cut frame its receiver refuses, or all of it but the last delimiter, which the next frame's
//! leading 0x00 completes), the receiver sees that frame once and its number never twice with other bytes,
//! so it counts no frame lost that was not.

use super::packer::{append, Codes};
use super::queue::{parse_entry_head, LiveItem, Weight, ENTRY_HEAD};
use super::{FrameEncoder, TickReport, VOXEL_FRAME_OVERHEAD};
use crate::frame::resend::ACK_WINDOW;
use crate::frame::wire_len;
use crate::wire::{DeltaBase, Message};

/// A summary as [`append`] takes it: key, residency, weight, codes.
type LiveSummary<'a, const D: usize> = (crate::key::VoxelKey, u32, Weight, Codes<'a, D>);

/// What the pending frame (built in `scratch`, not yet written whole) is.
pub(super) const PENDING_NONE: u8 = 0;
pub(super) const PENDING_HEADER: u8 = 1;
pub(super) const PENDING_STATS: u8 = 2;
/// Queued (final) voxels, maybe with live ones: kept for re-sending with a back channel.
const PENDING_KEPT_VOXELS: u8 = 3;
/// Live voxels only: never kept.
const PENDING_LIVE_VOXELS: u8 = 4;
/// Flag on a control frame sent out of the schedule when the re-send buffer cannot keep it.
pub(super) const PENDING_UNKEPT: u8 = 0x80;

/// Where a tick is in its order of business.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Phase {
    Resends,
    Pending,
    Header,
    Stats,
    Voxels,
    Done,
}

/// One tick in progress.
#[derive(Debug)]
pub(super) struct Tick {
    pub(super) phase: Phase,
    pub(super) budget: usize,
    pub(super) live_budget: usize,
    pub(super) report: TickReport,
    /// Live items of the caller's iterator the pending frame consumed in this tick (reported once written).
    live_consumed: u32,
}

/// The next bytes a tick writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Planned {
    /// A kept frame written again: the record at this offset of the re-send region.
    Resend(usize),
    /// The pending frame, `scratch[..pending_len]`.
    Pending,
}

impl<const D: usize, const QB: usize, const N: usize> FrameEncoder<D, QB, N> {
    /// Whether a new frame of `n` wire bytes may be sent now: without a back channel always; with one, if
    /// the re-send buffer can keep it and the oldest unacknowledged frame stays within the receiver's
    /// sequence window.
    pub(super) fn can_keep(&self, n: usize) -> bool {
        let region = self.queue.get(QB - self.resend_len..).unwrap_or_default();
        self.in_window() && (!self.settings.resend.is_on() || self.ring.fits(region.len(), n))
    }

    /// Whether any new frame may be numbered now: with a back channel, the oldest unacknowledged frame
    /// must stay within the receiver's 64-frame sequence window of the newest, or its re-sent copy would
    /// arrive too old to be applied.
    pub(super) fn in_window(&self) -> bool {
        let region = self.queue.get(QB - self.resend_len..).unwrap_or_default();
        !self.settings.resend.is_on()
            || self
                .ring
                .oldest_seq(region)
                .is_none_or(|oldest| self.seq.wrapping_sub(oldest) < ACK_WINDOW - 1)
    }

    /// Start a tick (`None` without a session: nothing is written).
    pub(super) fn begin_tick(&mut self, budget: usize, live_budget: usize) -> Option<Tick> {
        if !self.is_configured() {
            return None;
        }
        self.now = self.now.wrapping_add(1);
        let phase = if self.settings.resend.is_on() {
            Phase::Resends
        } else {
            Phase::Pending
        };
        Some(Tick {
            phase,
            budget,
            live_budget,
            report: TickReport::default(),
            live_consumed: 0,
        })
    }

    /// A tick that writes only what is pending, then forced control frames ([`Self::send_header`]).
    pub(super) fn forced_tick(&self) -> Tick {
        Tick {
            phase: Phase::Pending,
            budget: usize::MAX,
            live_budget: 0,
            report: TickReport::default(),
            live_consumed: 0,
        }
    }

    /// The bytes of a planned write.
    pub(super) fn planned_bytes(&self, p: Planned) -> &[u8] {
        match p {
            Planned::Resend(at) => {
                let region = self.queue.get(QB - self.resend_len..).unwrap_or_default();
                self.ring.frame_at(region, at)
            }
            Planned::Pending => self.scratch.get(..self.pending_len).unwrap_or_default(),
        }
    }

    /// Build the pending frame from a control message. Returns false if it cannot be built.
    pub(super) fn pend_message(&mut self, message: Message<'_>, kind: u8) -> bool {
        match self.build_message(message) {
            Ok(n) => {
                self.pending_len = n;
                self.pending_kind = kind;
                self.pending_from_queue = 0;
                self.pending_live = 0;
                true
            }
            Err(_) => false,
        }
    }

    /// What the tick writes next, in its order: due re-sends, the pending frame, the session header when
    /// due (nothing new goes before it), link statistics when due, then frames of queued and live voxels.
    /// `None`: the tick is over.
    pub(super) fn plan<I>(
        &mut self,
        t: &mut Tick,
        live: &mut core::iter::Peekable<I>,
    ) -> Option<Planned>
    where
        I: Iterator,
        I::Item: LiveItem<D>,
    {
        let left = t.budget.saturating_sub(t.report.bytes);
        loop {
            match t.phase {
                Phase::Resends => {
                    let timeout = self.settings.resend.timeout_ticks.max(1);
                    let region = self.queue.get(QB - self.resend_len..).unwrap_or_default();
                    match self.ring.due(region, self.now, timeout) {
                        Some((at, record)) if record.len <= left => {
                            return Some(Planned::Resend(at))
                        }
                        _ => t.phase = Phase::Pending,
                    }
                }
                Phase::Pending => {
                    if self.pending_kind == PENDING_NONE {
                        t.phase = Phase::Header;
                    } else if self.pending_len <= left {
                        return Some(Planned::Pending);
                    } else {
                        t.phase = Phase::Done; // nothing new goes before it
                    }
                }
                Phase::Header => {
                    if self.seq != 0 && self.since_header < self.settings.header_interval {
                        t.phase = Phase::Stats;
                        continue;
                    }
                    if self.pend_message(Message::Session(self.config), PENDING_HEADER)
                        && self.pending_len <= left
                        && self.can_keep(self.pending_len)
                    {
                        t.phase = Phase::Stats;
                        return Some(Planned::Pending);
                    }
                    self.drop_pending();
                    t.phase = Phase::Done; // nothing else may go before the header
                }
                Phase::Stats => {
                    t.phase = Phase::Voxels;
                    if self.since_stats >= self.settings.stats_interval
                        && self.pend_message(Message::Stats(self.stats), PENDING_STATS)
                    {
                        if self.pending_len <= left && self.can_keep(self.pending_len) {
                            return Some(Planned::Pending);
                        }
                        self.drop_pending();
                    }
                }
                Phase::Voxels => {
                    return self.plan_voxels(t, left, live);
                }
                Phase::Done => return None,
            }
        }
    }

    /// Fill one frame: queued evicted voxels first, then live ones; with a back channel a frame is either
    /// kept (final voxels) or live-only (not kept).
    fn plan_voxels<I>(
        &mut self,
        t: &mut Tick,
        left: usize,
        live: &mut core::iter::Peekable<I>,
    ) -> Option<Planned>
    where
        I: Iterator,
        I::Item: LiveItem<D>,
    {
        let reliable = self.settings.resend.is_on();
        let smallest = wire_len(VOXEL_FRAME_OVERHEAD + self.frame_reserve());
        let mut limit = N.min(left);
        if limit < smallest {
            t.phase = Phase::Done;
            return None;
        }
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
            let (key, residency, word) = parse_entry_head(head);
            let weight = match codes.first_chunk::<4>() {
                #[cfg(feature = "forgetting")]
                Some(t) if self.stamped() => Weight::Stamped {
                    n: f32::from_bits(word),
                    time: u32::from_le_bytes(*t),
                },
                _ => Weight::Count(word),
            };
            let codes = codes.get(self.stamp_len()..).unwrap_or_default();
            let summary = (key, residency, weight, Codes::<D>::Queued(codes));
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
        if from_queue == self.len && (!reliable || count == 0) {
            if count == 0 {
                limit = limit.min(t.live_budget.saturating_sub(t.report.live_bytes));
            }
            while limit >= smallest && count < u16::MAX {
                let Some(item) = live.peek() else { break };
                // Consumed either way: sent, or skipped because the decoder would refuse it (or the
                // session cannot carry it: statistics in a session of stored codes, or codes in another).
                if let Some(summary) = self.live_summary(item) {
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
        t.phase = Phase::Done;
        if count == 0 {
            t.report.live_sent += from_live; // only skipped (unsendable) items
            return None;
        }
        let n = self.build_voxels(count, used).ok()?;
        let kept = from_queue > 0;
        if (kept && !self.can_keep(n)) || !self.in_window() {
            return None; // back-pressure: the re-send buffer is full
        }
        self.pending_len = n;
        self.pending_kind = if kept {
            PENDING_KEPT_VOXELS
        } else {
            PENDING_LIVE_VOXELS
        };
        self.pending_from_queue = from_queue;
        self.pending_live = u32::from(count) - from_queue as u32;
        t.live_consumed = from_live;
        t.phase = Phase::Voxels; // the next frame
        Some(Planned::Pending)
    }

    /// A live item as the summary this session sends of it, or `None` to skip it.
    fn live_summary<'a>(&self, item: &'a impl LiveItem<D>) -> Option<LiveSummary<'a, D>> {
        #[cfg(feature = "stored-codes")]
        if self.config.codec.is_stored() {
            let v = item.stored()?;
            let weight = self.stored_weight(&v).filter(|_| !v.weighed)?;
            return Some((v.key, v.residency, weight, Codes::LiveStored(v.codes)));
        }
        let v = item.voxel()?;
        let weight = self.weight(&v)?;
        Some((v.key, v.residency, weight, Codes::Live(v.obs)))
    }

    /// Account for a planned write: `ok` if every byte was written. A failed re-send stays due; a failed
    /// new frame stays pending (nothing of it is counted, its number is not used up).
    pub(super) fn commit(&mut self, t: &mut Tick, p: Planned, ok: bool) {
        let n = self.planned_bytes(p).len();
        if !ok {
            self.stats.write_errors = self.stats.write_errors.saturating_add(1);
            t.phase = Phase::Done;
            return;
        }
        t.report.frames += 1;
        t.report.bytes += n;
        self.stats.bytes_sent = self.stats.bytes_sent.wrapping_add(n as u32);
        match p {
            Planned::Resend(at) => {
                let region = self
                    .queue
                    .get_mut(QB - self.resend_len..)
                    .unwrap_or_default();
                self.ring.resent(region, at, self.now);
                t.report.resent += 1;
                t.report.resent_bytes += n;
                self.stats.resent = self.stats.resent.wrapping_add(1);
                self.resent_bytes = self.resent_bytes.wrapping_add(n as u32);
            }
            Planned::Pending => self.commit_pending(t, n),
        }
    }

    /// The pending frame of `n` bytes was written whole: number it, keep it, count it.
    fn commit_pending(&mut self, t: &mut Tick, n: usize) {
        let kind = self.pending_kind & !PENDING_UNKEPT;
        let seq = self.seq;
        self.seq = self.seq.wrapping_add(1);
        self.since_header = self.since_header.saturating_add(1);
        self.since_stats = self.since_stats.saturating_add(1);
        self.stats.frames_sent = self.stats.frames_sent.wrapping_add(1);
        let kept = kind != PENDING_LIVE_VOXELS && self.pending_kind & PENDING_UNKEPT == 0;
        if kept && self.settings.resend.is_on() {
            let (queue, scratch) = (&mut self.queue, &self.scratch);
            let region = queue.get_mut(QB - self.resend_len..).unwrap_or_default();
            self.ring
                .push(region, seq, self.now, scratch.get(..n).unwrap_or_default());
        }
        match kind {
            PENDING_HEADER => self.since_header = 0,
            PENDING_STATS => self.since_stats = 0,
            _ => {
                let from_queue = self.pending_from_queue;
                self.head = self.slot(from_queue);
                self.len -= from_queue.min(self.len);
                if kind == PENDING_LIVE_VOXELS {
                    t.report.live_bytes += n;
                }
                t.report.evicted_sent += from_queue as u32;
                t.report.live_sent += t.live_consumed;
                self.stats.evicted_sent = self.stats.evicted_sent.wrapping_add(from_queue as u32);
                self.stats.live_sent = self.stats.live_sent.wrapping_add(self.pending_live);
            }
        }
        t.live_consumed = 0;
        self.pending_kind = PENDING_NONE;
        self.pending_len = 0;
        self.pending_from_queue = 0;
        self.pending_live = 0;
    }

    /// Whether a frame whose write failed waits to be written again (first thing the next tick does).
    pub fn has_pending(&self) -> bool {
        self.pending_kind != PENDING_NONE
    }

    /// Frames written since the last link statistics (0 right after a statistics frame).
    pub fn frames_since_stats(&self) -> u32 {
        self.since_stats
    }
}
