//! Which held voxels changed since the link last streamed them, so that a base station's map can follow
//! the robot while it works (live updates; the final copy at eviction supersedes them).
//!
//! Nothing here runs per point: a hot voxel has changed if its point count differs from the count it had
//! when it was last streamed; a cold one carries a flag set when it cooled with points not yet streamed.
//! The link walks the slots like a ring from where it stopped, so every changed voxel gets its turn.

use super::{LiveVoxel, LocalMap, CHANGED, OCCUPIED};
use crate::forget::MapClock;

impl<const D: usize, const CAP: usize, const P: usize, const H: usize, C: MapClock>
    LocalMap<D, CAP, P, H, C>
{
    /// Whether slot `s` holds a voxel with points the link has not streamed (`cold`: only a cold one, whose
    /// codes hold them all).
    fn changed(&self, s: usize, cold: bool) -> bool {
        let Some(slot) = self.slots.get(s) else {
            return false;
        };
        if slot.flags & OCCUPIED == 0 || (cold && slot.hot != 0) {
            return false;
        }
        if slot.flags & CHANGED != 0 {
            return true;
        }
        usize::from(slot.hot)
            .checked_sub(1)
            .and_then(|h| self.hot.get(h))
            .is_some_and(|h| h.acc.points_bits() != h.live_sent)
    }

    /// The next slot at or after `from` (wrapping once around the pool) holding a changed voxel (`cold`:
    /// a changed cold one, as [`Self::changed_stored`] yields them).
    pub fn next_changed(&self, from: usize, cold: bool) -> Option<usize> {
        (0..CAP)
            .map(|i| (from + i) % CAP)
            .find(|&s| self.changed(s, cold))
    }

    /// The changed voxels, decoded, in ring order from slot `from` (each once).
    pub fn changed_voxels(&self, from: usize) -> impl Iterator<Item = LiveVoxel<D>> + '_ {
        (0..CAP)
            .map(move |i| (from + i) % CAP)
            .filter(|&s| self.changed(s, false))
            .filter_map(|s| self.slots.get(s).map(|slot| self.live_voxel(slot)))
    }

    /// The changed cold voxels as their codes, in ring order from slot `from` (each once): what a link of
    /// stored codes streams live, copied as they are (no decode, no re-encode). A hot voxel's new points
    /// are not in its codes yet: it is skipped, and streamed once it cools (cooling marks it changed).
    #[cfg(feature = "stored-codes")]
    pub fn changed_stored(
        &self,
        from: usize,
    ) -> impl Iterator<Item = crate::sink::EvictedStored<'_>> + '_ {
        let weighed = self.mean_weights.has_shifts();
        (0..CAP)
            .map(move |i| (from + i) % CAP)
            .filter(|&s| self.changed(s, true))
            .filter_map(move |s| {
                self.slots.get(s).map(|slot| crate::sink::EvictedStored {
                    key: super::window::unwrap(slot.key, self.centre),
                    codes: slot.codes.stored(),
                    residency: slot.residency,
                    time: C::tick(slot.stamp),
                    weighed,
                })
            })
    }

    /// The link streamed slot `s` as it is now.
    pub fn mark_streamed(&mut self, s: usize) {
        let Some(slot) = self.slots.get_mut(s) else {
            return;
        };
        slot.flags &= !CHANGED;
        if let Some(h) = usize::from(slot.hot)
            .checked_sub(1)
            .and_then(|h| self.hot.get_mut(h))
        {
            h.live_sent = h.acc.points_bits();
        }
    }
}
