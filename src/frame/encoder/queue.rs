//! The queue of evicted voxels: each is quantized into a fixed-size entry of the encoder's byte queue the
//! moment the map evicts it (so a full queue refuses and the map keeps the voxel), and leaves it, oldest
//! first, when a tick packs it into a frame.

use super::FrameEncoder;
use crate::key::VoxelKey;
use crate::local_map::LiveVoxel;
use crate::obs::ObsStats;
#[cfg(feature = "stored-codes")]
use crate::sink::EvictedStored;
use crate::sink::{Evicted, EvictionSink, SinkFull};
#[cfg(feature = "stored-codes")]
use crate::wire::write_stored;
use crate::wire::WireError;
use crate::wire::{encode_codes_as, wire_count, SessionConfig};

/// Fixed part of a queue entry: key (3 × i32), residency (u32), point count (u32; a stamped entry's
/// weight n as f32 bits, its tick in the 4 bytes after), all little-endian.
pub(super) const ENTRY_HEAD: usize = 20;

/// Bytes a stamped summary adds to the largest unstamped one: the count 0 and the tick's varint (up to 5)
/// in place of the count's (at least 1), and the 4-byte weight.
#[cfg(feature = "forgetting")]
pub(super) const STAMP_EXTRA: usize = 9;

/// Whether a session forgets: its summaries are stamped (never without the `forgetting` feature).
#[inline]
pub(super) fn stamped(config: &SessionConfig) -> bool {
    #[cfg(feature = "forgetting")]
    return config.half_life > 0.0;
    #[cfg(not(feature = "forgetting"))]
    return {
        let _ = config;
        false
    };
}

/// Bytes of a queue entry between its head and its codes: a stamped entry's tick.
#[inline]
pub(super) fn stamp_len(config: &SessionConfig) -> usize {
    if stamped(config) {
        4
    } else {
        0
    }
}

/// A summary's weight as the encoder sends it: a whole point count, or (a session that forgets) the
/// weight n with the tick of the voxel's last change.
#[derive(Clone, Copy, Debug)]
pub(super) enum Weight {
    Count(u32),
    #[cfg(feature = "forgetting")]
    Stamped {
        n: f32,
        time: u32,
    },
}

impl Weight {
    /// The point count the codes are sized for.
    pub(super) fn class(self) -> u32 {
        match self {
            Self::Count(c) => c,
            #[cfg(feature = "forgetting")]
            Self::Stamped { n, .. } => crate::wire::stamped_class(n).unwrap_or(2),
        }
    }
}

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
    /// Queue one summary: its head (key, residency, weight; a stamped weight's tick after it) and the codes
    /// `write_codes` puts in the rest of the entry. Refused when the queue is full; codes that cannot be
    /// written are counted invalid and dropped (the map must not keep retrying them).
    fn queue_entry(
        &mut self,
        key: VoxelKey,
        residency: u32,
        weight: Weight,
        write_codes: impl FnOnce(&mut [u8]) -> Result<usize, WireError>,
    ) -> Result<(), SinkFull> {
        if self.len == self.capacity {
            self.stats.refused = self.stats.refused.saturating_add(1);
            return Err(SinkFull);
        }
        let bytes = self.slot_bytes(self.slot(self.len));
        let stamp_len = self.stamp_len();
        let written = self
            .queue
            .get_mut(bytes)
            .and_then(|e| e.split_first_chunk_mut::<ENTRY_HEAD>())
            .map(|(head, rest)| {
                #[allow(clippy::infallible_destructuring_match)] // one variant without forgetting
                let word = match weight {
                    Weight::Count(c) => c,
                    #[cfg(feature = "forgetting")]
                    Weight::Stamped { n, time } => {
                        if let Some(t) = rest.get_mut(..4) {
                            t.copy_from_slice(&time.to_le_bytes());
                        }
                        n.to_bits()
                    }
                };
                *head = entry_head(key, residency, word);
                write_codes(rest.get_mut(stamp_len..).unwrap_or_default())
            });
        if !matches!(written, Some(Ok(_))) {
            self.stats.invalid = self.stats.invalid.saturating_add(1);
            return Ok(());
        }
        self.len += 1;
        self.stats.queue_peak = self.stats.queue_peak.max(self.len as u32);
        Ok(())
    }

    /// Whether the session forgets: its summaries are stamped.
    #[inline]
    #[cfg_attr(not(feature = "forgetting"), allow(dead_code))]
    pub(super) fn stamped(&self) -> bool {
        stamped(&self.config)
    }

    /// Bytes of a queue entry between its head and its codes (the tick of a stamped one).
    #[inline]
    pub(super) fn stamp_len(&self) -> usize {
        stamp_len(&self.config)
    }

    /// The weight a voxel is sent with, or `None` if the decoder would refuse it (not valid; a count not
    /// whole or out of range, or a stamped weight not in (0, 2²⁴]).
    pub(super) fn weight(&self, voxel: &Evicted<'_, D>) -> Option<Weight> {
        #[cfg(feature = "stored-codes")]
        if self.config.codec.is_stored() {
            // Stored codes are the map's own: statistics handed as such have none (see `evict_stored`).
            return None;
        }
        #[cfg(feature = "forgetting")]
        if self.stamped() {
            let n = voxel.obs.count;
            return (voxel.obs.is_valid() && crate::wire::stamped_class(n).is_some()).then_some(
                Weight::Stamped {
                    n,
                    time: voxel.time,
                },
            );
        }
        sendable(voxel.obs).map(Weight::Count)
    }

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
        let Some(weight) = self.weight(&voxel) else {
            self.stats.invalid = self.stats.invalid.saturating_add(1);
            return Ok(());
        };
        let codec = self.config.codec;
        // Cannot fail: the codec was validated for D and the queue sized for whole entries.
        self.queue_entry(voxel.key, voxel.residency, weight, |codes| {
            encode_codes_as(codec, voxel.obs, weight.class(), codes)
        })
    }

    /// Whether the session carries stored codes ([`crate::wire::SummaryCodec::STORED`]): the map then
    /// hands its voxels' codes as they are ([`Self::evict_stored`]).
    #[cfg(feature = "stored-codes")]
    #[inline(always)]
    fn wants_stored(&self) -> bool {
        self.config.codec.is_stored()
    }

    /// Copy a voxel's codes into the queue now (a session of stored codes), or refuse when it is full. In
    /// a session of other codes they are decoded and quantized as [`Self::evict`] does.
    #[cfg(feature = "stored-codes")]
    fn evict_stored(&mut self, voxel: EvictedStored<'_>) -> Result<(), SinkFull> {
        if self.wants_stored() {
            return self.queue_stored(voxel);
        }
        self.evict_decoded(voxel)
    }
}

#[cfg(feature = "stored-codes")]
impl<const D: usize, const QB: usize, const N: usize> FrameEncoder<D, QB, N> {
    /// Codes handed to an encoder of another codec: decoded, then taken as statistics. Out of line: its
    /// 516-byte statistics would otherwise sit in the frame of every eviction (the map's eviction inlines
    /// the sink), raising the stack's high-water mark where this never runs.
    #[inline(never)]
    fn evict_decoded(&mut self, voxel: EvictedStored<'_>) -> Result<(), SinkFull> {
        let mut obs = ObsStats::EMPTY;
        if voxel.decode_into(&mut obs).is_none() {
            self.stats.invalid = self.stats.invalid.saturating_add(1);
            return Ok(());
        }
        self.evict(Evicted {
            key: voxel.key,
            obs: &obs,
            residency: voxel.residency,
            time: voxel.time,
        })
    }
}

#[cfg(feature = "stored-codes")]
impl<const D: usize, const QB: usize, const N: usize> FrameEncoder<D, QB, N> {
    /// The weight a voxel's stored codes are sent with: as [`Self::weight`], from the codes' exact n.
    pub(super) fn stored_weight(&self, voxel: &EvictedStored<'_>) -> Option<Weight> {
        let n = voxel.codes.count;
        #[cfg(feature = "forgetting")]
        if self.stamped() {
            return crate::wire::stamped_class(n).map(|_| Weight::Stamped {
                n,
                time: voxel.time,
            });
        }
        wire_count(n).map(Weight::Count)
    }

    /// [`EvictionSink::evict_stored`] in a session that carries stored codes: the codes are copied into
    /// the queue as they are. Codes of a weighed mean (only their map can weigh them back) or of a count
    /// the decoder would refuse are counted invalid and dropped.
    fn queue_stored(&mut self, voxel: EvictedStored<'_>) -> Result<(), SinkFull> {
        let Some(weight) = self.stored_weight(&voxel).filter(|_| !voxel.weighed) else {
            self.stats.invalid = self.stats.invalid.saturating_add(1);
            return Ok(());
        };
        // Fails only for codes of another dimension (never from this encoder's map).
        self.queue_entry(voxel.key, voxel.residency, weight, |codes| {
            write_stored::<D>(&voxel.codes, weight.class(), codes)
        })
    }
}

/// A voxel the encoder can stream live: a borrowed [`Evicted`] view, a decoded [`LiveVoxel`] from the
/// local map, or (feature `stored-codes`) a held voxel's codes as the map holds them.
pub trait LiveItem<const D: usize> {
    /// The voxel as statistics (`None` if it is only codes): what a session of packed or Rice codes
    /// quantizes.
    fn voxel(&self) -> Option<Evicted<'_, D>>;
    /// The voxel as its map's codes: what a session of stored codes sends (`None` if it is only
    /// statistics: such a session skips it).
    #[cfg(feature = "stored-codes")]
    fn stored(&self) -> Option<EvictedStored<'_>> {
        None
    }
}

impl<const D: usize> LiveItem<D> for Evicted<'_, D> {
    fn voxel(&self) -> Option<Evicted<'_, D>> {
        Some(*self)
    }
}

impl<const D: usize> LiveItem<D> for LiveVoxel<D> {
    fn voxel(&self) -> Option<Evicted<'_, D>> {
        Some(Evicted {
            time: self.time,
            ..live(self.key, &self.obs, self.residency)
        })
    }
}

#[cfg(feature = "stored-codes")]
impl<const D: usize> LiveItem<D> for EvictedStored<'_> {
    fn voxel(&self) -> Option<Evicted<'_, D>> {
        None
    }
    fn stored(&self) -> Option<EvictedStored<'_>> {
        Some(*self)
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
