//! Live updates: what a tick with bytes to spare streams of the voxels the robot still holds, so a base
//! station's map follows the robot while it works — each changed voxel once, in ring order over the map's
//! slots from where the last round stopped. A link of stored codes streams the changed cold voxels' codes as
//! the map holds them (nothing is coded again); other links, every changed voxel decoded and quantized.

use super::Mapper;
use crate::forget::MapClock;
use crate::frame::{TickError, TickReport};

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
    /// [`Self::tick`], then live updates: up to `live_budget` of the `budget` bytes stream the held voxels
    /// that changed since they were last streamed, in ring order over the map's slots (each gets its
    /// turn), so a base station's map follows the robot while it works. The base station replaces a live
    /// copy by the next one and by the final one. A link of stored codes streams the changed cold voxels'
    /// codes as they are (a hot voxel's new points once they have cooled into its codes). A firmware that
    /// wants only final voxels calls [`Self::tick`], and links none of this.
    pub fn tick_live<W: embedded_io::Write>(
        &mut self,
        w: &mut W,
        budget: usize,
        live_budget: usize,
    ) -> Result<TickReport, TickError<W::Error>> {
        if live_budget == 0 || self.map.is_empty() {
            return self.tick(w, budget);
        }
        let hand = self.live_hand;
        #[cfg(feature = "stored-codes")]
        if crate::sink::EvictionSink::<D>::wants_stored(&self.encoder) {
            let report =
                self.encoder
                    .tick_live(w, budget, live_budget, self.map.changed_stored(hand));
            self.mark_live_sent(hand, &report, true);
            return report;
        }
        let report = self
            .encoder
            .tick_live(w, budget, live_budget, self.map.changed_voxels(hand));
        self.mark_live_sent(hand, &report, false);
        report
    }

    /// After a live tick from `hand`: the leading `live_sent` changed voxels from the hand (`cold`: the
    /// changed cold ones) were consumed, mark them streamed and move the hand past them.
    pub(super) fn mark_live_sent<E>(
        &mut self,
        hand: usize,
        report: &Result<TickReport, TickError<E>>,
        cold: bool,
    ) {
        let consumed = match report {
            Ok(r) => r.live_sent,
            Err(TickError::Write(_, r)) => r.live_sent,
        };
        let mut at = hand;
        for _ in 0..consumed {
            let Some(s) = self.map.next_changed(at, cold) else {
                break;
            };
            self.map.mark_streamed(s);
            at = if s + 1 >= CAP { 0 } else { s + 1 };
        }
        self.live_hand = at;
    }
}
