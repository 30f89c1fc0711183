//! The hot tier: the `H` voxels being observed now accumulate points in f32 (one Welford step per point,
//! no decoding). A voxel is quantized only when it cools — when another voxel needs its entry — so it is
//! re-encoded once per visit, not once per point or batch.

use super::{Hot, LocalMap, CHANGED, REFERENCED};
use crate::key::VoxelKey;
use crate::obs::ObsStats;
use crate::quant::QuantVoxel;

impl<const D: usize, const CAP: usize, const P: usize, const H: usize> LocalMap<D, CAP, P, H> {
    /// Merge hot entry `h` into its slot's codes (one decode, one exact merge, one encode) and mark the slot
    /// cold. The entry itself is left for the caller to reuse or remove.
    pub(super) fn cool(&mut self, h: usize) {
        let Some(hot) = self.hot.get(h) else { return };
        let s = usize::from(hot.slot);
        let Some(slot) = self.slots.get_mut(s) else {
            return;
        };
        if slot.codes.count > 0.0 {
            slot.codes.decode_into(&mut self.scratch);
            self.scratch.merge(&hot.obs);
            slot.codes = slot.codes.reencode(&self.scratch, &mut self.dither);
        } else {
            slot.codes = QuantVoxel::encode(&hot.obs, &mut self.dither);
        }
        slot.hot = 0;
        slot.flags |= REFERENCED;
        if hot.obs.count != hot.live_sent {
            slot.flags |= CHANGED; // points the link has not streamed live yet
        }
        self.counters.cooled = self.counters.cooled.saturating_add(1);
        self.counters.slots_written = self.counters.slots_written.saturating_add(1);
    }

    /// Drop hot entry `h` (its slot is being freed): the last entry moves into its place.
    pub(super) fn remove_hot(&mut self, h: usize) {
        let last = self.hot_len.saturating_sub(1);
        if h > last {
            return;
        }
        if h != last {
            let Some(&moved) = self.hot.get(last) else {
                return;
            };
            if let Some(e) = self.hot.get_mut(h) {
                *e = moved;
            }
            if let Some(slot) = self.slots.get_mut(usize::from(moved.slot)) {
                slot.hot = h as u8 + 1;
            }
        }
        self.hot_len = last;
        if self.last_hot >= self.hot_len {
            self.last_hot = 0;
        }
        if self.hot_hand >= self.hot_len {
            self.hot_hand = 0;
        }
    }

    /// A hot entry for slot `s` holding `key`: a free one, else the CLOCK choice among the hot, cooled.
    pub(super) fn make_hot(&mut self, s: usize, key: VoxelKey) -> usize {
        let h = if self.hot_len < H {
            self.hot_len += 1;
            self.hot_len - 1
        } else {
            let mut h = self.hot_hand;
            for _ in 0..2 * H + 1 {
                h = self.hot_hand;
                self.hot_hand = if h + 1 == H { 0 } else { h + 1 };
                match self.hot.get_mut(h) {
                    Some(e) if e.referenced => e.referenced = false,
                    _ => break,
                }
            }
            self.cool(h);
            h
        };
        if let Some(e) = self.hot.get_mut(h) {
            *e = Hot {
                obs: ObsStats::EMPTY,
                key,
                slot: s as u16,
                referenced: true,
                live_sent: 0.0,
            };
        }
        if let Some(slot) = self.slots.get_mut(s) {
            slot.hot = h as u8 + 1;
        }
        h
    }
}
