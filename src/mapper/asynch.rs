//! The robot's loop over `embedded-io-async` (feature `async`): what an embassy firmware awaits — the
//! tick, the drain and the acknowledgements — with every decision the blocking calls make (the encoder's
//! schedule is one, `frame::encoder`'s plan-write-commit), so both write the same bytes.

use super::{DrainError, DrainReport, Mapper, NoTap, Tapped};
use crate::forget::MapClock;
use crate::frame::{TickError, TickReport};
use crate::sink::Evicted;

impl<
        const D: usize,
        const CAP: usize,
        const P: usize,
        const QB: usize,
        const N: usize,
        const H: usize,
        C: MapClock,
    > Mapper<D, CAP, P, QB, N, H, C>
{
    /// [`Self::tick`] over an async writer.
    pub async fn tick_async<W: embedded_io_async::Write>(
        &mut self,
        w: &mut W,
        budget: usize,
    ) -> Result<TickReport, TickError<W::Error>> {
        self.encoder
            .tick_async(w, budget, core::iter::empty::<Evicted<'_, D>>())
            .await
    }

    /// [`Self::tick_live`] over an async writer.
    pub async fn tick_live_async<W: embedded_io_async::Write>(
        &mut self,
        w: &mut W,
        budget: usize,
        live_budget: usize,
    ) -> Result<TickReport, TickError<W::Error>> {
        if live_budget == 0 || self.map.is_empty() {
            return self.tick_async(w, budget).await;
        }
        let hand = self.live_hand;
        #[cfg(feature = "stored-codes")]
        if crate::sink::EvictionSink::<D>::wants_stored(&self.encoder) {
            let live = self.map.changed_stored(hand);
            let report = self
                .encoder
                .tick_live_async(w, budget, live_budget, live)
                .await;
            self.mark_live_sent(hand, &report, true);
            return report;
        }
        let report = self
            .encoder
            .tick_live_async(w, budget, live_budget, self.map.changed_voxels(hand))
            .await;
        self.mark_live_sent(hand, &report, false);
        report
    }

    /// [`Self::poll_acks`] over an async reader: reads while it says bytes are ready, never waiting for
    /// more. Returns the bytes read.
    pub async fn poll_acks_async<R>(&mut self, r: &mut R) -> Result<usize, R::Error>
    where
        R: embedded_io_async::Read + embedded_io_async::ReadReady,
    {
        let mut total = 0;
        let mut chunk = [0u8; 32];
        while r.read_ready()? {
            let n = r.read(&mut chunk).await?;
            if n == 0 {
                break;
            }
            total += n;
            self.feed_acks(chunk.get(..n).unwrap_or_default());
        }
        Ok(total)
    }

    /// Wait for the back channel's next bytes (one read) and apply the acknowledgements they complete: for
    /// a task that sleeps until the base station answers (e.g. `select` with a timer). Returns the bytes
    /// read (0: the reader ended).
    pub async fn read_acks_async<R: embedded_io_async::Read>(
        &mut self,
        r: &mut R,
    ) -> Result<usize, R::Error> {
        let mut chunk = [0u8; 32];
        let n = r.read(&mut chunk).await?;
        self.feed_acks(chunk.get(..n).unwrap_or_default());
        Ok(n)
    }

    /// [`Self::drain`] over an async writer.
    pub async fn drain_async<W: embedded_io_async::Write>(
        &mut self,
        w: &mut W,
    ) -> Result<u32, DrainError<W::Error>> {
        let r = self.drain_within_async(w, usize::MAX).await?;
        if r.done {
            Ok(r.evicted)
        } else {
            Err(DrainError::Stuck)
        }
    }

    /// [`Self::drain_within`] over an async writer.
    pub async fn drain_within_async<W: embedded_io_async::Write>(
        &mut self,
        w: &mut W,
        budget: usize,
    ) -> Result<DrainReport, DrainError<W::Error>> {
        let mut report = DrainReport::default();
        loop {
            let mut sink = Tapped {
                sink: &mut self.encoder,
                tap: &mut NoTap,
            };
            let flushed = self.map.flush(&mut sink);
            let (Ok(n) | Err(n)) = flushed;
            report.evicted = report.evicted.saturating_add(n as u32);
            let left = budget.saturating_sub(report.bytes);
            if flushed.is_ok() && self.drained_but_stats() {
                if self.stats_closed() {
                    report.done = true;
                    return Ok(report);
                }
                return match self.encoder.send_stats_within_async(w, left).await {
                    Ok(Some(sent)) => {
                        report.bytes += sent;
                        report.done = true;
                        Ok(report)
                    }
                    Ok(None) if left >= N && report.bytes == 0 => Err(DrainError::Stuck),
                    Ok(None) => Ok(report),
                    Err(e) => Err(DrainError::Write(e)),
                };
            }
            let sent = self
                .encoder
                .tick_async(w, left, core::iter::empty::<Evicted<'_, D>>())
                .await?;
            report.bytes += sent.bytes;
            if sent.frames == sent.resent && n == 0 {
                return if report.bytes == 0 && budget >= N {
                    Err(DrainError::Stuck)
                } else {
                    Ok(report)
                };
            }
        }
    }
}
