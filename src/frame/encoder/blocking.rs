//! The tick over a blocking [`embedded_io::Write`] (a UART): the scheduler's plan-write-commit loop with
//! each write done at once, and the control messages a firmware forces outside the schedule (`asynch`
//! is the same over `embedded-io-async`).

use super::queue::LiveItem;
use super::scheduler::{Planned, PENDING_HEADER, PENDING_STATS, PENDING_UNKEPT};
use super::{FrameEncoder, TickError, TickReport};
use crate::sink::Evicted;
use crate::wire::Message;

impl<const D: usize, const QB: usize, const N: usize> FrameEncoder<D, QB, N> {
    /// Write the pending frame (if any), then a control message now, outside the tick's schedule, if all
    /// of it fits in `budget` bytes. `Ok(None)`: it did not fit, nothing was written.
    fn send_control<W: embedded_io::Write>(
        &mut self,
        w: &mut W,
        message: impl Fn(&Self) -> Message<'static>,
        kind: u8,
        budget: usize,
    ) -> Result<Option<usize>, W::Error> {
        if !self.is_configured() {
            return Ok(None);
        }
        let mut t = self.forced_tick();
        if self.has_pending() {
            if self.pending_len > budget {
                return Ok(None);
            }
            let r = w.write_all(self.planned_bytes(Planned::Pending));
            self.commit(&mut t, Planned::Pending, r.is_ok());
            r?;
        }
        let m = message(self);
        if !self.pend_message(m, kind) {
            return Ok(None);
        }
        if t.report.bytes + self.pending_len > budget {
            self.drop_pending();
            return Ok(if t.report.bytes > 0 {
                Some(t.report.bytes)
            } else {
                None
            });
        }
        if !self.can_keep(self.pending_len) {
            self.pending_kind |= PENDING_UNKEPT;
        }
        let r = w.write_all(self.planned_bytes(Planned::Pending));
        self.commit(&mut t, Planned::Pending, r.is_ok());
        r?;
        Ok(Some(t.report.bytes))
    }

    /// Force a session header now (as the first frame it is sent anyway), after a frame whose write
    /// failed. Returns bytes written (0 without a session).
    pub fn send_header<W: embedded_io::Write>(&mut self, w: &mut W) -> Result<usize, W::Error> {
        let sent = self.send_control(
            w,
            |s| Message::Session(s.config),
            PENDING_HEADER,
            usize::MAX,
        );
        sent.map(|n| n.unwrap_or(0))
    }

    /// Force a link-statistics frame now, after a frame whose write failed. Returns bytes written (0
    /// without a session).
    pub fn send_stats<W: embedded_io::Write>(&mut self, w: &mut W) -> Result<usize, W::Error> {
        self.send_stats_within(w, usize::MAX)
            .map(|n| n.unwrap_or(0))
    }

    /// [`Self::send_stats`] if the frames fit in `budget` bytes (`Ok(None)`: nothing was written).
    pub fn send_stats_within<W: embedded_io::Write>(
        &mut self,
        w: &mut W,
        budget: usize,
    ) -> Result<Option<usize>, W::Error> {
        self.send_control(w, |s| Message::Stats(s.stats), PENDING_STATS, budget)
    }

    /// Spend up to `budget` bytes: overdue re-sends (with a back channel), a frame whose write failed, the
    /// session header if due, link statistics if due, then queued evicted voxels (oldest first), then
    /// `live` voxels in the caller's order (most changed first). Only whole frames are written; without a
    /// session nothing is. With a back channel, live voxels travel in frames of their own (not kept), and
    /// no new kept frame is built while the re-send buffer is full.
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
        let Some(mut t) = self.begin_tick(budget, live_budget) else {
            return Ok(TickReport::default());
        };
        let mut live = live.into_iter().peekable();
        while let Some(p) = self.plan(&mut t, &mut live) {
            let r = w.write_all(self.planned_bytes(p));
            self.commit(&mut t, p, r.is_ok());
            r.map_err(|e| TickError::Write(e, t.report))?;
        }
        Ok(t.report)
    }
}
