//! Reading the map: a voxel's statistics, every held voxel, the hot ones, posteriors gathered through the
//! kernel, and what it can answer.

use super::window::unwrap;
use super::{LiveVoxel, LocalMap, Slot, OCCUPIED};
use crate::key::VoxelKey;
use crate::obs::{gather, ObsLookup, ObsStats};
use crate::stats::VoxelStats;

impl<const D: usize, const CAP: usize, const P: usize, const H: usize> LocalMap<D, CAP, P, H> {
    /// The observation statistics of a voxel, if held.
    pub fn get(&self, key: VoxelKey) -> Option<ObsStats<D>> {
        if !Self::wrap_safe(key, self.centre) {
            return None; // its wrapped form could alias a resident key
        }
        let (_, s) = self.find(key)?;
        self.slots.get(s).map(|slot| self.decode_slot(slot))
    }

    pub(super) fn decode_slot(&self, slot: &Slot<D, P>) -> ObsStats<D> {
        let mut obs = slot.codes.decode();
        self.mean_weights.apply(&mut obs.mean, false);
        if let Some(hot) = usize::from(slot.hot)
            .checked_sub(1)
            .and_then(|h| self.hot.get(h))
        {
            hot.acc.merge_into(&mut obs, self.int8_scale);
        }
        obs
    }

    /// Every held voxel, decoded.
    pub fn iter(&self) -> impl Iterator<Item = LiveVoxel<D>> + '_ {
        self.slots
            .iter()
            .filter(|s| s.flags & OCCUPIED != 0)
            .map(|s| LiveVoxel {
                key: unwrap(s.key, self.centre),
                obs: self.decode_slot(s),
                residency: s.residency,
            })
    }

    /// The voxels being observed now (the hot ones), decoded: what a link with spare bytes streams as live
    /// updates — the base station replaces a live update by the next one of the same residency.
    pub fn hot_voxels(&self) -> impl Iterator<Item = LiveVoxel<D>> + '_ {
        self.hot
            .iter()
            .take(self.hot_len)
            .filter_map(|h| self.slots.get(usize::from(h.slot)))
            .map(|s| LiveVoxel {
                key: unwrap(s.key, self.centre),
                obs: self.decode_slot(s),
                residency: s.residency,
            })
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

impl<const D: usize, const CAP: usize, const P: usize, const H: usize> ObsLookup<D>
    for LocalMap<D, CAP, P, H>
{
    fn observed(&self, key: VoxelKey) -> Option<ObsStats<D>> {
        self.get(key)
    }
}
