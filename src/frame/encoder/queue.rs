//! The queue of evicted voxels: each is quantized into a fixed-size entry of the encoder's byte queue the
//! moment the map evicts it (so a full queue refuses and the map keeps the voxel), and leaves it, oldest
//! first, when a tick packs it into a frame.

use super::FrameEncoder;
use crate::key::VoxelKey;
use crate::local_map::LiveVoxel;
use crate::obs::ObsStats;
use crate::sink::{Evicted, EvictionSink, SinkFull};
use crate::wire::{encode_codes, wire_count};

/// Fixed part of a queue entry: key (3 × i32), residency (u32), point count (u32), all little-endian.
pub(super) const ENTRY_HEAD: usize = 20;

/// The fixed part of a queue entry.
pub(super) fn entry_head(key: VoxelKey, residency: u32, count: u32) -> [u8; ENTRY_HEAD] {
    let [x, y, z] = key.as_array();
    let words = [x as u32, y as u32, z as u32, residency, count];
    let mut head = [0u8; ENTRY_HEAD];
    for (bytes, word) in head.chunks_exact_mut(4).zip(words) {
        bytes.copy_from_slice(&word.to_le_bytes());
    }
    head
}

/// Key, residency and point count of a queue entry's fixed part.
pub(super) fn parse_entry_head(head: &[u8; ENTRY_HEAD]) -> (VoxelKey, u32, u32) {
    let word = |i: usize| u32::from_le_bytes([head[i], head[i + 1], head[i + 2], head[i + 3]]);
    (
        VoxelKey::new(word(0) as i32, word(4) as i32, word(8) as i32),
        word(12),
        word(16),
    )
}

impl<const D: usize, const QB: usize, const N: usize> FrameEncoder<D, QB, N> {
    /// Queue slot `i` places after the oldest entry (`i ≤ capacity`), wrapped around the ring.
    pub(super) fn slot(&self, i: usize) -> usize {
        let s = self.head + i;
        if s >= self.capacity {
            s - self.capacity
        } else {
            s
        }
    }

    /// Where queue slot `slot` (< `capacity`) lies in `queue`.
    pub(super) fn slot_bytes(&self, slot: usize) -> core::ops::Range<usize> {
        let at = slot * self.entry_len;
        at..at + self.entry_len
    }
}

/// The wire count of statistics the decoder accepts (valid, a whole count in 1..=2²⁴), or `None`: the
/// encoder never sends what the base station would refuse — a refused summary takes its whole frame with it.
pub(super) fn sendable<const D: usize>(obs: &ObsStats<D>) -> Option<u32> {
    if obs.is_valid() {
        wire_count(obs.count)
    } else {
        None
    }
}

impl<const D: usize, const QB: usize, const N: usize> EvictionSink<D> for FrameEncoder<D, QB, N> {
    /// Quantize the voxel into the queue now; refuse when the queue is full (or there is no session). A
    /// non-finite voxel is counted as invalid and dropped (the map must not keep retrying it).
    fn evict(&mut self, voxel: Evicted<'_, D>) -> Result<(), SinkFull> {
        let Some(count) = sendable(voxel.obs) else {
            self.stats.invalid = self.stats.invalid.saturating_add(1);
            return Ok(());
        };
        if self.len == self.capacity {
            self.stats.refused = self.stats.refused.saturating_add(1);
            return Err(SinkFull);
        }
        let bytes = self.slot_bytes(self.slot(self.len));
        let codec = self.config.codec;
        let written = self
            .queue
            .get_mut(bytes)
            .and_then(|e| e.split_first_chunk_mut::<ENTRY_HEAD>())
            .map(|(head, codes)| {
                *head = entry_head(voxel.key, voxel.residency, count);
                encode_codes(codec, voxel.obs, codes)
            });
        if !matches!(written, Some(Ok(_))) {
            // Cannot happen: the codec was validated for D and the queue sized for whole entries.
            self.stats.invalid = self.stats.invalid.saturating_add(1);
            return Ok(());
        }
        self.len += 1;
        self.stats.queue_peak = self.stats.queue_peak.max(self.len as u32);
        Ok(())
    }
}

/// A voxel the encoder can stream live: a borrowed [`Evicted`] view, or a decoded [`LiveVoxel`] from the
/// local map.
pub trait LiveItem<const D: usize> {
    /// The voxel, borrowed.
    fn voxel(&self) -> Evicted<'_, D>;
}

impl<const D: usize> LiveItem<D> for Evicted<'_, D> {
    fn voxel(&self) -> Evicted<'_, D> {
        *self
    }
}

impl<const D: usize> LiveItem<D> for LiveVoxel<D> {
    fn voxel(&self) -> Evicted<'_, D> {
        Evicted {
            time: self.time,
            ..live(self.key, &self.obs, self.residency)
        }
    }
}

/// A live voxel as the encoder takes it; convenience for callers holding `(key, obs, residency)` tuples.
pub fn live<const D: usize>(key: VoxelKey, obs: &ObsStats<D>, residency: u32) -> Evicted<'_, D> {
    Evicted {
        key,
        obs,
        residency,
        time: 0,
    }
}
