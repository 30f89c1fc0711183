//! The tick's schedule: what a byte budget is spent on, in order — overdue re-sends, the session header
//! and link statistics when due, queued evicted voxels, then live ones — and which new frames may be
//! numbered while frames wait for acknowledgement.

use super::packer::{append, Codes};
use super::queue::{parse_entry_head, LiveItem, Weight, ENTRY_HEAD};
use super::{FrameEncoder, TickError, TickReport, VOXEL_FRAME_OVERHEAD};
use crate::frame::resend::ACK_WINDOW;
use crate::frame::wire_len;
use crate::sink::Evicted;
use crate::wire::{DeltaBase, Message};

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

    /// Write the frame in `scratch[..n]` (`n ≤ N`), counting it; a `kept` frame stays in the re-send
    /// buffer until acknowledged (callers checked [`Self::can_keep`]). The sequence number advances even
    /// when the write fails (a partly written frame must never share its number with the next one).
    pub(super) fn send<W: embedded_io::Write>(
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

    pub(super) fn control_frame<W: embedded_io::Write>(
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
    pub(super) fn resend_due<W: embedded_io::Write>(
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
        let smallest = wire_len(VOXEL_FRAME_OVERHEAD + self.frame_reserve());
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
                    if let Some(weight) = self.weight(&v) {
                        let summary = (v.key, v.residency, weight, Codes::Live(v.obs));
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
