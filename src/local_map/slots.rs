//! The pool of slots, swept like a ring: allocation (a free slot, else CLOCK eviction of a cold voxel:
//! second chance ≈ least recently observed), eviction into the sink (a refusal keeps the voxel), and
//! flushing at the end of a run.

use super::window::{unwrap, wrap};
use super::{positive, LocalMap, Slot, OCCUPIED, REFERENCED};
use crate::forget::bring_forward;
use crate::forget::MapClock;
use crate::key::VoxelKey;
use crate::obs::ObsStats;
use crate::quant::QuantVoxel;
#[cfg(feature = "stored-codes")]
use crate::sink::EvictedStored;
use crate::sink::{Evicted, EvictionSink};

impl<const D: usize, const CAP: usize, const P: usize, const H: usize, C: MapClock>
    LocalMap<D, CAP, P, H, C>
{
    // Slot numbers come from the map's own index and hands, so they are always below CAP; the accessors
    // below still go through `get` so that no bounds-check panic is linked into the hot path (the
    // firmware's `panic-never` build proves it). An out-of-range number reads as an empty slot.

    /// The voxel's statistics, quantized part decoded and hot part merged, into `self.scratch`, as of the
    /// returned stamp (its last change).
    pub(super) fn gather_slot(&mut self, s: usize) -> C::Stamp {
        let Some(slot) = self.slots.get(s) else {
            self.scratch = ObsStats::EMPTY;
            return C::ZERO;
        };
        slot.codes.decode_into(&mut self.scratch);
        self.mean_weights.apply(&mut self.scratch.mean, false);
        let mut stamp = slot.stamp;
        if let Some(h) = usize::from(slot.hot).checked_sub(1) {
            if let Some(hot) = self.hot.get(h) {
                if !hot.acc.is_empty() {
                    bring_forward(&self.clock, &mut self.scratch, slot.stamp, hot.stamp);
                    stamp = hot.stamp;
                }
                hot.acc.merge_into(&mut self.scratch, self.int8_scale);
            }
        }
        stamp
    }

    /// Hand a slot to the sink and free it. On refusal the slot stays and this returns false.
    pub(super) fn evict_slot<S: EvictionSink<D>>(&mut self, s: usize, sink: &mut S) -> bool {
        #[cfg(feature = "stored-codes")]
        if sink.wants_stored() {
            return self.evict_stored(s, sink);
        }
        // The few fields the eviction needs, not the 116-byte slot.
        let Some((w, residency, hot)) = self.slots.get(s).map(|v| (v.key, v.residency, v.hot))
        else {
            return false;
        };
        let key = unwrap(w, self.centre);
        let stamp = self.gather_slot(s);
        if positive(self.scratch.count) {
            let evicted = Evicted {
                key,
                obs: &self.scratch,
                residency,
                time: C::tick(stamp),
            };
            if sink.evict(evicted).is_err() {
                self.counters.refused = self.counters.refused.saturating_add(1);
                return false;
            }
            self.counters.evicted = self.counters.evicted.saturating_add(1);
        }
        if let Some(h) = usize::from(hot).checked_sub(1) {
            self.remove_hot(h);
        }
        self.free_slot(s, key);
        true
    }

    /// Empty slot `s` (holding `key`, its hot entry removed) and drop it from the index. Only its flags
    /// and hot entry are cleared: nothing reads the rest of a slot that is not occupied, and allocation
    /// writes the whole slot (clearing all of it was a 116-byte `memclr` per eviction at D = 64).
    fn free_slot(&mut self, s: usize, key: VoxelKey) {
        self.unindex(s, key);
        if let Some(freed) = self.slots.get_mut(s) {
            freed.flags = 0;
            freed.hot = 0;
        }
        self.len -= 1;
        self.counters.slots_written = self.counters.slots_written.saturating_add(1);
    }

    /// [`Self::evict_slot`] to a sink that takes codes ([`EvictionSink::wants_stored`]): the codes go as
    /// they are (no decode). A hot voxel cools into its codes first (its points merge, as when another
    /// voxel needs its entry) and leaves the hot tier; on refusal it stays, cooled.
    #[cfg(feature = "stored-codes")]
    fn evict_stored<S: EvictionSink<D>>(&mut self, s: usize, sink: &mut S) -> bool {
        if let Some(h) = self
            .slots
            .get(s)
            .and_then(|slot| usize::from(slot.hot).checked_sub(1))
        {
            self.cool(h);
            self.remove_hot(h);
        }
        let weighed = self.mean_weights.has_shifts();
        let Some(slot) = self.slots.get(s) else {
            return false;
        };
        let key = unwrap(slot.key, self.centre);
        if positive(slot.codes.count) {
            let voxel = EvictedStored {
                key,
                codes: slot.codes.stored(),
                residency: slot.residency,
                time: C::tick(slot.stamp),
                weighed,
            };
            if sink.evict_stored(voxel).is_err() {
                self.counters.refused = self.counters.refused.saturating_add(1);
                return false;
            }
            self.counters.evicted = self.counters.evicted.saturating_add(1);
        }
        self.free_slot(s, key);
        true
    }

    /// A free slot for `k`: a never-used or freed slot if any, else CLOCK eviction of a cold voxel.
    /// `None` if the sink refused the eviction (back-pressure).
    pub(super) fn alloc<S: EvictionSink<D>>(&mut self, k: VoxelKey, sink: &mut S) -> Option<usize> {
        let s = if self.len < CAP {
            let mut s = self.free_hand;
            while self
                .slots
                .get(s)
                .is_some_and(|slot| slot.flags & OCCUPIED != 0)
            {
                s = if s + 1 == CAP { 0 } else { s + 1 };
            }
            self.free_hand = if s + 1 == CAP { 0 } else { s + 1 };
            s
        } else {
            // CAP > H: at most H slots are hot, so two sweeps find a cold one.
            let mut found = None;
            for _ in 0..2 * CAP + 1 {
                let s = self.clock_hand;
                self.clock_hand = if s + 1 == CAP { 0 } else { s + 1 };
                let Some(slot) = self.slots.get_mut(s) else {
                    continue;
                };
                if slot.hot != 0 {
                    continue;
                }
                if slot.flags & REFERENCED != 0 {
                    slot.flags &= !REFERENCED;
                    continue;
                }
                // A refusing sink will refuse the next one too.
                found = self.evict_slot(s, sink).then_some(s);
                break;
            }
            found?
        };
        let slot = self.slots.get_mut(s)?;
        *slot = Slot {
            codes: QuantVoxel::EMPTY,
            key: wrap(k),
            hot: 0,
            flags: OCCUPIED | REFERENCED,
            residency: self.next_residency,
            stamp: self.clock.now(),
        };
        self.next_residency = self.next_residency.wrapping_add(1);
        self.index_insert(k, s);
        self.len += 1;
        self.counters.slots_written = self.counters.slots_written.saturating_add(1);
        Some(s)
    }

    /// Evict every voxel (end of a run). Stops at the first refusal and returns it as an error with the
    /// number evicted so far.
    pub fn flush<S: EvictionSink<D>>(&mut self, sink: &mut S) -> Result<usize, usize> {
        let mut n = 0;
        for s in 0..CAP {
            if self.slots[s].flags & OCCUPIED != 0 {
                if !self.evict_slot(s, sink) {
                    return Err(n);
                }
                n += 1;
            }
        }
        Ok(n)
    }
}
