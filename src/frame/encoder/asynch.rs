//! The tick over `embedded-io-async` (feature `async`): the same plan-write-commit loop as the blocking
//! tick (`blocking`), the write awaited. Every decision — re-sends first, the pending frame, header,
//! statistics, queued then live voxels, what a failed write leaves — is the scheduler's, so an async
//! firmware writes the bytes a blocking one writes.

use super::queue::LiveItem;
use super::scheduler::{Planned, PENDING_STATS, PENDING_UNKEPT};
use super::{FrameEncoder, TickError, TickReport};
use crate::sink::Evicted;
use crate::wire::Message;

impl<const D: usize, const QB: usize, const N: usize> FrameEncoder<D, QB, N> {
    /// [`Self::tick`] over an async writer.
    pub async fn tick_async<'a, W, I>(
        &mut self,
        w: &mut W,
        budget: usize,
        live: I,
    ) -> Result<TickReport, TickError<W::Error>>
    where
        W: embedded_io_async::Write,
        I: IntoIterator<Item = Evicted<'a, D>>,
    {
        self.tick_live_async(w, budget, usize::MAX, live).await
    }

    /// [`Self::tick_live`] over an async writer.
    pub async fn tick_live_async<W, I>(
        &mut self,
        w: &mut W,
        budget: usize,
        live_budget: usize,
        live: I,
    ) -> Result<TickReport, TickError<W::Error>>
    where
        W: embedded_io_async::Write,
        I: IntoIterator,
        I::Item: LiveItem<D>,
    {
        let Some(mut t) = self.begin_tick(budget, live_budget) else {
            return Ok(TickReport::default());
        };
        let mut live = live.into_iter().peekable();
        while let Some(p) = self.plan(&mut t, &mut live) {
            let r = w.write_all(self.planned_bytes(p)).await;
            self.commit(&mut t, p, r.is_ok());
            r.map_err(|e| TickError::Write(e, t.report))?;
        }
        Ok(t.report)
    }

    /// [`Self::send_stats_within`] over an async writer (the blocking `send_control`'s steps).
    pub async fn send_stats_within_async<W: embedded_io_async::Write>(
        &mut self,
        w: &mut W,
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
            let r = w.write_all(self.planned_bytes(Planned::Pending)).await;
            self.commit(&mut t, Planned::Pending, r.is_ok());
            r?;
        }
        if !self.pend_message(Message::Stats(self.stats), PENDING_STATS) {
            return Ok(None);
        }
        if t.report.bytes + self.pending_len > budget {
            self.drop_pending();
            return Ok((t.report.bytes > 0).then_some(t.report.bytes));
        }
        if !self.can_keep(self.pending_len) {
            self.pending_kind |= PENDING_UNKEPT;
        }
        let r = w.write_all(self.planned_bytes(Planned::Pending)).await;
        self.commit(&mut t, Planned::Pending, r.is_ok());
        r?;
        Ok(Some(t.report.bytes))
    }
}
