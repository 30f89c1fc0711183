//! Reading the map: a voxel's statistics, every held voxel, the hot ones, posteriors gathered through the
//! kernel, and what it can answer.

use super::window::unwrap;
use super::{LiveVoxel, LocalMap, Slot, OCCUPIED};
use crate::forget::bring_forward;
use crate::forget::MapClock;
use crate::key::VoxelKey;
use crate::obs::{gather, ObsLookup, ObsStats};
use crate::stats::VoxelStats;

impl<const D: usize, const CAP: usize, const P: usize, const H: usize, C: MapClock>
    LocalMap<D, CAP, P, H, C>
{
    /// The observation statistics of a voxel, if held.
    pub fn get(&self, key: VoxelKey) -> Option<ObsStats<D>> {
        if !Self::wrap_safe(key, self.centre) {
            return None; // its wrapped form could alias a resident key
        }
        let (_, s) = self.find(key)?;
        self.slots.get(s).map(|slot| self.decode_slot(slot))
    }

    /// A slot's statistics as read now: as of its last change, faded to the clock when forgetting.
    pub(super) fn decode_slot(&self, slot: &Slot<D, P, C::Stamp>) -> ObsStats<D> {
        let (mut obs, stamp) = self.stamped_slot(slot);
        bring_forward(&self.clock, &mut obs, stamp, self.clock.now());
        obs
    }

    /// A slot's statistics as of its last change, and that change's stamp: the codes faded to the hot
    /// stamp (never earlier) and the hot part merged.
    pub(super) fn stamped_slot(&self, slot: &Slot<D, P, C::Stamp>) -> (ObsStats<D>, C::Stamp) {
        let mut obs = slot.codes.decode();
        self.mean_weights.apply(&mut obs.mean, false);
        let mut stamp = slot.stamp;
        if let Some(hot) = usize::from(slot.hot)
            .checked_sub(1)
            .and_then(|h| self.hot.get(h))
        {
            if !hot.acc.is_empty() {
                bring_forward(&self.clock, &mut obs, slot.stamp, hot.stamp);
                stamp = hot.stamp;
            }
            hot.acc.merge_into(&mut obs, self.int8_scale);
        }
        (obs, stamp)
    }

    /// A slot as the link streams it: statistics as of its last change, with that tick.
    pub(super) fn live_voxel(&self, slot: &Slot<D, P, C::Stamp>) -> LiveVoxel<D> {
        let (obs, stamp) = self.stamped_slot(slot);
        LiveVoxel {
            key: unwrap(slot.key, self.centre),
            obs,
            residency: slot.residency,
            time: C::tick(stamp),
        }
    }

    /// Every held voxel, decoded, as of its last change ([`LiveVoxel::time`]; a map that forgets: read
    /// through [`Self::get`] to see them faded to now).
    pub fn iter(&self) -> impl Iterator<Item = LiveVoxel<D>> + '_ {
        self.slots
            .iter()
            .filter(|s| s.flags & OCCUPIED != 0)
            .map(|s| self.live_voxel(s))
    }

    /// The voxels being observed now (the hot ones), decoded: what a link with spare bytes streams as live
    /// updates — the base station replaces a live update by the next one of the same residency.
    pub fn hot_voxels(&self) -> impl Iterator<Item = LiveVoxel<D>> + '_ {
        self.hot
            .iter()
            .take(self.hot_len)
            .filter_map(|h| self.slots.get(usize::from(h.slot)))
            .map(|s| self.live_voxel(s))
    }

    /// The posterior of any voxel, gathered from the held voxels in the kernel's reach (the prior if none).
    pub fn posterior(&self, key: VoxelKey) -> VoxelStats<D> {
        // The table is voxel-offset (checked in `configure`); an unconfigured map gathers nothing.
        gather(&self.lut, self, key)
            .unwrap_or(ObsStats::EMPTY)
            .posterior(&self.config.prior())
    }

    /// How many voxels the map can answer with more than the prior: those within the kernel's reach of a
    /// held voxel. Counted without memory: a voxel in reach is counted once, by the first held voxel of its
    /// neighbourhood in the table's order (O(len · f⁶) lookups — a report, not for the hot path).
    pub fn answerable(&self) -> usize {
        let offsets = self.lut.offsets();
        let mut n = 0;
        for slot in self.slots.iter().filter(|s| s.flags & OCCUPIED != 0) {
            let own = unwrap(slot.key, self.centre);
            for o in offsets {
                let target = own.offset(*o);
                // The first held voxel around `target`, offsets in table order (the set is symmetric).
                let first = offsets
                    .iter()
                    .map(|p| target.offset(*p))
                    .find(|k| self.find(*k).is_some());
                if first == Some(own) {
                    n += 1;
                }
            }
        }
        n
    }

    /// Lookup cost: (mean, longest) probe run over the held keys, in table entries. At the index's ≤ 50 %
    /// load factor linear probing averages under 2 probes.
    pub fn probe_stats(&self) -> (f32, usize) {
        let (mut sum, mut max, mut n) = (0usize, 0usize, 0usize);
        for s in self.slots.iter().filter(|s| s.flags & OCCUPIED != 0) {
            let k = unwrap(s.key, self.centre);
            let (pos, _) = self.find(k).unwrap_or((Self::home(k), 0));
            let run = (pos + Self::TABLE - Self::home(k)) % Self::TABLE + 1;
            sum += run;
            max = max.max(run);
            n += 1;
        }
        (if n > 0 { sum as f32 / n as f32 } else { 0.0 }, max)
    }
}

impl<const D: usize, const CAP: usize, const P: usize, const H: usize, C: MapClock> ObsLookup<D>
    for LocalMap<D, CAP, P, H, C>
{
    fn observed(&self, key: VoxelKey) -> Option<ObsStats<D>> {
        self.get(key)
    }
}
