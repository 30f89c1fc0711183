//! The on-device local map: a fixed pool of quantized voxels around the robot, no heap, nothing copied.
//!
//! Shape and why:
//! - **Slots** hold quantized posteriors ([`crate::quant`]) and a key stored as 3 × i16, wrapped around the
//!   window centre (the window is far smaller than 2¹⁶ voxels, so the full key is recovered exactly).
//! - **Index**: open addressing with linear probing over 2·CAP u16 entries (slot + 1, 0 = empty): O(1)
//!   lookup for 4 bytes per voxel; deletion shifts back the few entries of its probe run, so no tombstones.
//!   (A heapless `FnvIndexMap<VoxelKey, u16, N>` costs ~20 B per voxel; see the size test.)
//! - **Ring of slots, CLOCK eviction**: when the pool is full, a hand sweeps the slots like a ring buffer and
//!   evicts the first one not updated since the hand last passed (second chance) — the classic O(1)
//!   approximation of least-recently-updated. Voxels pinned by the batch being applied are never evicted.
//! - **Window**: the map follows the robot; voxels farther than the window radius are evicted in place. A
//!   move reads every key but writes only the evicted slots: nothing is copied.
//! - **Every eviction goes to an [`EvictionSink`]**; if the sink refuses, the voxel stays and the refusal is
//!   counted. Nothing is forgotten silently.
//! - **Batches** are grouped by source voxel in a small f32 scratch (`G` groups, [`GROUPS`] by default:
//!   ~17 KiB at D = 64 on a device; a host can afford hundreds, and each flush re-encodes its targets, so a
//!   bigger scratch re-encodes shared neighbours less often); when it fills, the
//!   groups are applied target by target: the moments (count, mean, scatter about the mean — never raw
//!   sums, which cancel for offset features; see [`crate::stats`]) of every group in reach, merged through
//!   its kernel weight, form the target's batch (k̄, ȳ, S̄); the voxel is decoded once, takes the paper's
//!   batch update once, and is re-encoded once.

use crate::batch::{locate, Rejection, RejectionCounts};
use crate::config::{ConfigError, MapConfig};
use crate::kernel::KernelLut;
use crate::key::{to_map_frame, VoxelKey};
use crate::quant::{Dither, QuantVoxel};
use crate::sink::{Evicted, EvictionSink};
use crate::stats::VoxelStats;
use half::f16;
use nalgebra::Isometry3;

/// Source-voxel groups held in the f32 batch scratch before they are applied (the default `G`).
pub const GROUPS: usize = 32;

/// Largest window radius in voxels: keeps every resident key within the i16 wrap range of the centre.
pub const MAX_WINDOW_VOXELS: i32 = 16_000;

const OCCUPIED: u8 = 1;
const REFERENCED: u8 = 2;
/// Bits 2..8 of `flags`: the flush round (1..=63) that pinned the slot; 0 = not pinned.
const EPOCH_SHIFT: u8 = 2;
const EPOCH_MAX: u8 = 0x3F;

#[derive(Clone, Copy, Debug)]
struct Slot<const D: usize, const P: usize> {
    voxel: QuantVoxel<D, P>,
    key: [i16; 3],
    /// Full width, as [`Evicted::residency`] promises: the base station tells contributions of one voxel
    /// apart by it, so a 16-bit number would repeat after 65,536 allocations and a later residency of the
    /// same voxel could be taken for an earlier, closed one and dropped.
    residency: u32,
    /// Kernel mass absorbed since the voxel was last streamed (for "most changed first").
    unsent: f16,
    flags: u8,
}

impl<const D: usize, const P: usize> Slot<D, P> {
    const EMPTY: Self = Self {
        voxel: QuantVoxel::EMPTY,
        key: [0; 3],
        residency: 0,
        unsent: f16::ZERO,
        flags: 0,
    };
}

/// Why no slot could be had.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum NoSlot {
    /// Every slot is pinned by the groups being applied: apply them first, then retry.
    Pinned,
    /// The sink refused the eviction (back-pressure).
    Refused,
}

#[derive(Clone, Copy, Debug)]
struct Group<const D: usize> {
    key: VoxelKey,
    cell: u16,
    /// Moments of the group's points (λ = n, μ, Ψ = scatter), Welford-updated.
    moments: VoxelStats<D>,
}

/// What one call changed, for logs and tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Counters {
    /// Points integrated, modulo 2³² (wrapping, so differences stay right on a robot that runs for days).
    pub points: u32,
    /// Voxels handed to the sink (voxels holding only the prior are freed without it).
    pub evicted: u32,
    /// Evictions the sink refused (the voxel stayed).
    pub refused: u32,
    /// Slot writes (allocation, update, eviction): a window move that copied the map would show here.
    pub slots_written: u32,
}

/// A voxel of the map, decoded.
#[derive(Clone, Copy, Debug)]
pub struct LiveVoxel<const D: usize> {
    /// Its key.
    pub key: VoxelKey,
    /// Its posterior (decoded from the compact codes).
    pub stats: VoxelStats<D>,
    /// Its residency number (see [`Evicted::residency`]).
    pub residency: u32,
    /// Kernel mass absorbed since it was last marked sent.
    pub unsent: f32,
}

/// A fixed-capacity quantized LatentBKI map of `CAP` voxels of dimension `D`; `P` = [`crate::quant::packed_len`]`(D)`;
/// `G` source-voxel groups of batch scratch.
///
/// Large: place it in a `static` (see [`LocalMap::EMPTY`] and [`LocalMap::configure`]) or a `Box` on a host.
pub struct LocalMap<const D: usize, const CAP: usize, const P: usize, const G: usize = GROUPS> {
    config: MapConfig,
    lut: KernelLut,
    prior: VoxelStats<D>,
    prior_code: QuantVoxel<D, P>,
    slots: [Slot<D, P>; CAP],
    index: [[u16; CAP]; 2],
    len: usize,
    free_hand: usize,
    clock_hand: usize,
    groups: heapless::Vec<Group<D>, G>,
    /// The group the previous point joined.
    last_group: usize,
    scratch: VoxelStats<D>,
    /// The moments of the batch a target is absorbing.
    batch: VoxelStats<D>,
    centre: VoxelKey,
    radius: i32,
    epoch: u8,
    dither: Dither,
    next_residency: u32,
    rejections: RejectionCounts,
    counters: Counters,
    mass: f32,
    mass_carry: f32,
}

fn wrap(k: VoxelKey) -> [i16; 3] {
    [k.x as i16, k.y as i16, k.z as i16]
}

fn unwrap(w: [i16; 3], centre: VoxelKey) -> VoxelKey {
    let d = |w: i16, c: i32| c + i32::from(w.wrapping_sub(c as i16));
    VoxelKey::new(d(w[0], centre.x), d(w[1], centre.y), d(w[2], centre.z))
}

/// Spatially clustered keys need a well-mixed hash for linear probing: combine, then murmur3's finaliser.
fn hash(k: VoxelKey) -> u32 {
    let mut h = (k.x as u32)
        .wrapping_mul(0x9E37_79B1)
        .wrapping_add((k.y as u32).wrapping_mul(0x85EB_CA77))
        .wrapping_add((k.z as u32).wrapping_mul(0xC2B2_AE3D));
    h ^= h >> 16;
    h = h.wrapping_mul(0x85EB_CA6B);
    h ^= h >> 13;
    h = h.wrapping_mul(0xC2B2_AE35);
    h ^ (h >> 16)
}

impl<const D: usize, const CAP: usize, const P: usize, const G: usize> LocalMap<D, CAP, P, G> {
    const TABLE: usize = 2 * CAP;
    const CAP_OK: () = assert!(
        CAP > 0 && CAP < u16::MAX as usize && G > 0,
        "CAP must be in 1..65535 and G at least 1"
    );

    /// An unconfigured, empty map, for `static` placement; call [`Self::configure`] before use. Every byte
    /// is zero, so a `static` of it is placed in .bss and costs no flash.
    #[allow(clippy::declare_interior_mutable_const)]
    pub const EMPTY: Self = Self {
        config: MapConfig::UNCONFIGURED,
        lut: KernelLut::EMPTY,
        prior: VoxelStats::EMPTY,
        prior_code: QuantVoxel::EMPTY,
        slots: [Slot::EMPTY; CAP],
        index: [[0; CAP]; 2],
        len: 0,
        free_hand: 0,
        clock_hand: 0,
        groups: heapless::Vec::new(),
        last_group: 0,
        scratch: VoxelStats::EMPTY,
        batch: VoxelStats::EMPTY,
        centre: VoxelKey::new(0, 0, 0),
        radius: 0,
        epoch: 0,
        dither: Dither::UNSEEDED,
        next_residency: 0,
        rejections: RejectionCounts {
            non_finite_position: 0,
            non_finite_feature: 0,
            key_out_of_range: 0,
            no_room: 0,
            outside_window: 0,
            unpaired: 0,
        },
        counters: Counters {
            points: 0,
            evicted: 0,
            refused: 0,
            slots_written: 0,
        },
        mass: 0.0,
        mass_carry: 0.0,
    };

    /// (Re)configure in place: clears the map. `window_radius` is in metres around the robot.
    pub fn configure(&mut self, config: MapConfig, window_radius: f32) -> Result<(), ConfigError> {
        let () = Self::CAP_OK;
        let radius = libm::ceilf(window_radius / config.voxel_size());
        if !(radius >= 1.0 && radius <= MAX_WINDOW_VOXELS as f32) {
            return Err(ConfigError::Window);
        }
        self.lut.rebuild(&config)?;
        self.config = config;
        self.prior = VoxelStats::from_prior(&config.prior());
        self.dither = Dither::new(0x5EED_1234);
        self.prior_code = QuantVoxel::encode(&self.prior, &mut self.dither);
        self.slots.iter_mut().for_each(|s| *s = Slot::EMPTY);
        self.index = [[0; CAP]; 2];
        self.len = 0;
        self.free_hand = 0;
        self.clock_hand = 0;
        self.groups.clear();
        self.last_group = 0;
        self.radius = radius as i32;
        self.rejections = RejectionCounts::default();
        self.counters = Counters::default();
        self.mass = 0.0;
        self.mass_carry = 0.0;
        Ok(())
    }

    /// The map's configuration.
    pub fn config(&self) -> &MapConfig {
        &self.config
    }
    /// Voxels held.
    pub fn len(&self) -> usize {
        self.len
    }
    /// Whether no voxel is held.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
    /// Voxels it can hold.
    pub const fn capacity(&self) -> usize {
        CAP
    }
    /// Points refused so far, by reason.
    pub fn rejections(&self) -> RejectionCounts {
        self.rejections
    }
    /// Running totals.
    pub fn counters(&self) -> Counters {
        self.counters
    }
    /// Total kernel mass applied to voxels so far (Σ k̄; compensated f32 sum).
    pub fn kernel_mass(&self) -> f32 {
        self.mass
    }
    /// Centre of the window (voxel key).
    pub fn centre(&self) -> VoxelKey {
        self.centre
    }

    // ----- index -------------------------------------------------------------------------------------

    // Table positions come from `home` and `next`, always below TABLE; `get` keeps bounds-check panics
    // out of the firmware (an out-of-range position would read as empty and ignore writes).
    #[inline]
    fn entry(&self, i: usize) -> u16 {
        self.index.as_flattened().get(i).copied().unwrap_or(0)
    }
    #[inline]
    fn set_entry(&mut self, i: usize, v: u16) {
        if let Some(e) = self.index.as_flattened_mut().get_mut(i) {
            *e = v;
        }
    }
    #[inline]
    fn home(k: VoxelKey) -> usize {
        ((u64::from(hash(k)) * Self::TABLE as u64) >> 32) as usize
    }
    #[inline]
    fn next(i: usize) -> usize {
        if i + 1 == Self::TABLE {
            0
        } else {
            i + 1
        }
    }

    /// (table position, slot) of a key.
    fn find(&self, k: VoxelKey) -> Option<(usize, usize)> {
        let w = wrap(k);
        let mut i = Self::home(k);
        for _ in 0..Self::TABLE {
            let e = self.entry(i);
            if e == 0 {
                return None;
            }
            let s = usize::from(e - 1);
            if self.slots.get(s).is_some_and(|slot| slot.key == w) {
                return Some((i, s));
            }
            i = Self::next(i);
        }
        None
    }

    fn index_insert(&mut self, k: VoxelKey, slot: usize) {
        let mut i = Self::home(k);
        while self.entry(i) != 0 {
            i = Self::next(i);
        }
        self.set_entry(i, slot as u16 + 1);
    }

    /// Backward-shift deletion for linear probing.
    fn index_remove(&mut self, mut hole: usize) {
        self.set_entry(hole, 0);
        let mut j = hole;
        loop {
            j = Self::next(j);
            let e = self.entry(j);
            if e == 0 {
                return;
            }
            // (An out-of-range entry, which the map never writes, reads as staying put.)
            let home = self
                .slots
                .get(usize::from(e - 1))
                .map_or(j, |slot| Self::home(unwrap(slot.key, self.centre)));
            // The entry at j may fill the hole unless its home lies cyclically in (hole, j].
            let stays = if hole <= j {
                hole < home && home <= j
            } else {
                hole < home || home <= j
            };
            if !stays {
                self.set_entry(hole, e);
                self.set_entry(j, 0);
                hole = j;
            }
        }
    }

    // ----- slots -------------------------------------------------------------------------------------

    // Slot numbers come from the map's own index and hands, so they are always below CAP; the accessors
    // below still go through `get` so that no bounds-check panic is linked into the hot path (the
    // firmware's `panic-never` build proves it). An out-of-range number reads as an unpinned empty slot.
    // Plain indexing remains only where the bound is visible to the optimiser (loops over `0..CAP`, a
    // position checked against `len` just before), which links no panic either.

    fn pinned(&self, s: usize) -> bool {
        let e = self
            .slots
            .get(s)
            .map_or(0, |slot| slot.flags >> EPOCH_SHIFT);
        e != 0 && e == self.epoch
    }

    fn unpin(&mut self, s: usize) {
        if let Some(slot) = self.slots.get_mut(s) {
            slot.flags &= OCCUPIED | REFERENCED;
        }
    }

    /// Start a flush round: a new pin epoch. Epochs run 1..=63; when they wrap, stale pins (targets of a
    /// group that could not be placed) are cleared so an old pin never reads as current.
    fn next_epoch(&mut self) {
        if self.epoch >= EPOCH_MAX {
            for s in 0..CAP {
                self.unpin(s);
            }
            self.epoch = 1;
        } else {
            self.epoch += 1;
        }
    }

    /// Hand a slot to the sink and free it. On refusal the slot stays and this returns false.
    fn evict_slot<S: EvictionSink<D>>(&mut self, s: usize, sink: &mut S) -> bool {
        let Some(&slot) = self.slots.get(s) else {
            return false;
        };
        let key = unwrap(slot.key, self.centre);
        // A voxel holding only the prior (its batch was refused) carries no observation: free it quietly.
        if slot.voxel.lambda > self.prior.lambda {
            slot.voxel.decode_into(&mut self.scratch);
            let evicted = Evicted {
                key,
                stats: &self.scratch,
                residency: slot.residency,
            };
            if sink.evict(evicted).is_err() {
                self.counters.refused = self.counters.refused.saturating_add(1);
                return false;
            }
            self.counters.evicted = self.counters.evicted.saturating_add(1);
        }
        if let Some((pos, _)) = self.find(key) {
            self.index_remove(pos);
        }
        if let Some(freed) = self.slots.get_mut(s) {
            *freed = Slot::EMPTY;
        }
        self.len -= 1;
        self.counters.slots_written = self.counters.slots_written.saturating_add(1);
        true
    }

    /// A free slot for `k` (pinned for this flush): a never-used or freed slot if any, else CLOCK eviction.
    fn alloc<S: EvictionSink<D>>(&mut self, k: VoxelKey, sink: &mut S) -> Result<usize, NoSlot> {
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
            let mut found = Err(NoSlot::Pinned);
            for _ in 0..2 * CAP + 1 {
                let s = self.clock_hand;
                self.clock_hand = if s + 1 == CAP { 0 } else { s + 1 };
                if self.pinned(s) {
                    continue;
                }
                let Some(slot) = self.slots.get_mut(s) else {
                    continue;
                };
                if slot.flags & REFERENCED != 0 {
                    slot.flags &= !REFERENCED;
                    continue;
                }
                found = if self.evict_slot(s, sink) {
                    Ok(s)
                } else {
                    Err(NoSlot::Refused)
                };
                break; // a refusing sink will refuse the next one too
            }
            found?
        };
        let Some(slot) = self.slots.get_mut(s) else {
            return Err(NoSlot::Pinned);
        };
        *slot = Slot {
            voxel: self.prior_code,
            key: wrap(k),
            residency: self.next_residency,
            unsent: f16::ZERO,
            flags: OCCUPIED | REFERENCED | (self.epoch << EPOCH_SHIFT),
        };
        self.next_residency = self.next_residency.wrapping_add(1);
        self.index_insert(k, s);
        self.len += 1;
        self.counters.slots_written = self.counters.slots_written.saturating_add(1);
        Ok(s)
    }

    /// Whether a key is close enough to a centre to be stored wrapped (every axis within ±2¹⁵).
    fn wrap_safe(k: VoxelKey, centre: VoxelKey) -> bool {
        let ok = |a: i32, c: i32| (i64::from(a) - i64::from(c)).abs() < 1 << 15;
        ok(k.x, centre.x) && ok(k.y, centre.y) && ok(k.z, centre.z)
    }

    fn in_window(&self, k: VoxelKey) -> bool {
        let r = i64::from(self.radius);
        k.distance_squared(self.centre) <= r * r
    }

    fn add_mass(&mut self, m: f32) {
        // Kahan summation: the total stays exact to f32 over millions of small terms.
        let y = m - self.mass_carry;
        let t = self.mass + y;
        self.mass_carry = (t - self.mass) - y;
        self.mass = t;
    }

    // ----- the window --------------------------------------------------------------------------------

    /// Re-centre the window on a map-frame position and evict the voxels now outside it. Returns the number
    /// evicted. Refused evictions stay (counted); if one of them would fall out of the key wrap range the
    /// centre does not move this time.
    pub fn move_window<S: EvictionSink<D>>(&mut self, position: [f32; 3], sink: &mut S) -> usize {
        let Ok(new_centre) = VoxelKey::from_position(position, self.lut.inv_voxel_size()) else {
            return 0;
        };
        let old_centre = self.centre;
        let r = i64::from(self.radius);
        let mut evicted = 0;
        let mut keep_centre = false;
        for s in 0..CAP {
            if self.slots[s].flags & OCCUPIED == 0 {
                continue;
            }
            let key = unwrap(self.slots[s].key, old_centre);
            if key.distance_squared(new_centre) > r * r {
                if self.evict_slot(s, sink) {
                    evicted += 1;
                } else if !Self::wrap_safe(key, new_centre) {
                    keep_centre = true;
                }
            }
        }
        // Keys are stored wrapped: any centre within the wrap range unwraps them to the same full keys, so
        // moving the centre rewrites nothing.
        if !keep_centre {
            self.centre = new_centre;
        }
        evicted
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

    // ----- integration -------------------------------------------------------------------------------

    /// Integrate one batch of sensor-frame points seen from `pose` (sensor → map): the window follows the
    /// sensor, points are grouped and applied. Returns the number of points integrated; the others are
    /// counted in [`Self::rejections`].
    pub fn integrate<S: EvictionSink<D>>(
        &mut self,
        pose: &Isometry3<f32>,
        points: &[[f32; 3]],
        features: &[[f32; D]],
        sink: &mut S,
    ) -> usize {
        let t = pose.translation.vector;
        self.move_window([t.x, t.y, t.z], sink);
        let before = self.counters.points;
        for (p, y) in points.iter().zip(features) {
            // A refusal is counted in `rejections`; nothing else to do here.
            let _ = self.add_point(to_map_frame(pose, *p), y, sink);
        }
        // A point without a feature (or a feature without a point) is counted, never silently dropped.
        for _ in 0..points.len().abs_diff(features.len()) {
            self.rejections.count(Rejection::Unpaired);
        }
        self.end_batch(sink);
        // Points the map took: accepted into the batch and not refused when their group was applied.
        self.counters.points.wrapping_sub(before) as usize
    }

    /// Add one map-frame point to the current batch (applied when the scratch fills or at
    /// [`Self::end_batch`]). `Ok` means accepted into the batch: if the map then has no room for its
    /// voxel group, the group's points are refused and counted as [`Rejection::NoRoom`].
    pub fn add_point<S: EvictionSink<D>>(
        &mut self,
        position: [f32; 3],
        feature: &[f32; D],
        sink: &mut S,
    ) -> Result<(), Rejection> {
        if self.lut.offsets().is_empty() {
            // Not configured (`EMPTY`): there is no kernel to spread the point with, so no room for it.
            self.rejections.count(Rejection::NoRoom);
            return Err(Rejection::NoRoom);
        }
        let located = locate(&self.lut, position, feature).and_then(|(key, cell)| {
            if self.in_window(key) {
                Ok((key, cell))
            } else {
                Err(Rejection::OutsideWindow)
            }
        });
        let (key, cell) = match located {
            Ok(at) => at,
            Err(r) => {
                self.rejections.count(r);
                return Err(r);
            }
        };
        // Sensors return points in scan order: the group of the previous point is the likeliest match, then
        // the newest groups.
        let same = |g: &Group<D>| g.key == key && g.cell == cell;
        let found = match self.groups.get(self.last_group) {
            Some(g) if same(g) => Some(self.last_group),
            _ => self.groups.iter().rposition(same),
        };
        let g = match found {
            Some(g) => g,
            None => {
                if self.groups.is_full() {
                    self.apply_groups(sink);
                }
                let group = Group {
                    key,
                    cell,
                    moments: VoxelStats::EMPTY,
                };
                // Cannot fail: the scratch was just emptied if it was full. Should it, the point is
                // refused and counted, never added to another group.
                if self.groups.push(group).is_err() {
                    self.rejections.count(Rejection::NoRoom);
                    return Err(Rejection::NoRoom);
                }
                self.groups.len() - 1
            }
        };
        self.last_group = g;
        match self.groups.get_mut(g) {
            Some(group) => group.moments.add_unit_point(feature),
            None => {
                // Unreachable: `g` was just found or pushed.
                self.rejections.count(Rejection::NoRoom);
                return Err(Rejection::NoRoom);
            }
        }
        self.counters.points = self.counters.points.wrapping_add(1);
        Ok(())
    }

    /// Apply what remains of the current batch.
    pub fn end_batch<S: EvictionSink<D>>(&mut self, sink: &mut S) {
        self.apply_groups(sink);
    }

    /// Apply the grouped scratch in rounds: (A) give every voxel a group reaches a slot, pinned against
    /// eviction — when the pool runs out of unpinned slots, the groups placed so far are applied first and
    /// the rest wait for the next round; a group is refused (its points counted as `NoRoom`) only if the
    /// sink refuses evictions or the pool cannot hold one group's reach; (B) visit each reached voxel once —
    /// owned by the first group that reaches it — decode it, absorb every placed group in reach, re-encode.
    fn apply_groups<S: EvictionSink<D>>(&mut self, sink: &mut S) {
        while !self.groups.is_empty() {
            self.next_epoch();
            let placed = self.place_groups(sink);
            self.absorb_placed(placed);
            // Drop the applied prefix, keeping the waiting groups in order.
            let n = self.groups.len();
            let placed = placed.min(n);
            self.groups.copy_within(placed.., 0);
            self.groups.truncate(n - placed);
        }
    }

    /// Pass A: pin slots for groups from the front; returns how many are placed.
    fn place_groups<S: EvictionSink<D>>(&mut self, sink: &mut S) -> usize {
        let mut placed = 0;
        while let Some(&Group { key, cell, .. }) = self.groups.get(placed) {
            let mut result = Ok(());
            for j in 0..self.lut.offsets().len() {
                if self.lut.weights(cell).get(j).copied().unwrap_or(0.0) <= 0.0 {
                    continue;
                }
                let t = key.offset(self.lut.offsets()[j]);
                match self.find(t) {
                    Some((_, s)) => {
                        if let Some(slot) = self.slots.get_mut(s) {
                            let f = &mut slot.flags;
                            *f = (*f & (OCCUPIED | REFERENCED)) | (self.epoch << EPOCH_SHIFT);
                        }
                    }
                    None => {
                        if let Err(e) = self.alloc(t, sink) {
                            result = Err(e);
                            break;
                        }
                    }
                }
            }
            match result {
                Ok(()) => placed += 1,
                Err(NoSlot::Pinned) if placed > 0 => break,
                Err(_) => {
                    // Refuse the group: count its points, close the gap (a memmove, not a ~0.5 KB
                    // group on the stack as `Vec::remove` would return).
                    let len = self.groups.len();
                    if placed < len {
                        let n = self.groups[placed].moments.lambda as u32;
                        self.rejections.no_room = self.rejections.no_room.saturating_add(n);
                        self.counters.points = self.counters.points.wrapping_sub(n);
                        self.groups.copy_within(placed + 1.., placed);
                        self.groups.truncate(len - 1);
                    }
                }
            }
        }
        placed
    }

    /// Pass B over the placed groups `..placed`: every target is visited once, by the first group that
    /// reaches it (pass A pinned all of them; a visited target is unpinned, so a later group that reaches
    /// it skips it). It is decoded, absorbs every placed group from this one on (an earlier group reaching
    /// it would have visited it), and is re-encoded once.
    fn absorb_placed(&mut self, placed: usize) {
        for g in 0..placed {
            let Some(&Group { key, cell, .. }) = self.groups.get(g) else {
                break;
            };
            for j in 0..self.lut.offsets().len() {
                if self.lut.weights(cell).get(j).copied().unwrap_or(0.0) <= 0.0 {
                    continue;
                }
                let t = key.offset(self.lut.offsets()[j]);
                let Some((_, s)) = self.find(t) else { continue };
                if !self.pinned(s) {
                    continue; // visited by an earlier group of this round
                }
                self.unpin(s);
                // The target's batch: every placed group in reach, through its kernel weight.
                let mut first = true;
                for grp in self.groups.get(g..placed).unwrap_or_default() {
                    let w = self.lut.weight_at(
                        grp.cell,
                        t.x - grp.key.x,
                        t.y - grp.key.y,
                        t.z - grp.key.z,
                    );
                    if w > 0.0 {
                        if first {
                            self.batch.set_scaled(w, &grp.moments);
                            first = false;
                        } else {
                            self.batch.absorb_scaled(w, &grp.moments);
                        }
                    }
                }
                if first {
                    continue; // unreachable: group g reaches t
                }
                let mass = self.batch.lambda;
                let Some(slot) = self.slots.get_mut(s) else {
                    continue; // unreachable: `find` returned it
                };
                slot.voxel.decode_into(&mut self.scratch);
                self.scratch.absorb(&self.batch);
                slot.voxel = slot.voxel.reencode(&self.scratch, &mut self.dither);
                slot.unsent = f16::from_f32(slot.unsent.to_f32() + mass);
                slot.flags |= REFERENCED;
                self.counters.slots_written = self.counters.slots_written.saturating_add(1);
                self.add_mass(mass);
            }
        }
    }

    // ----- reading -----------------------------------------------------------------------------------

    /// The decoded posterior of a voxel, if held.
    pub fn get(&self, key: VoxelKey) -> Option<VoxelStats<D>> {
        if !Self::wrap_safe(key, self.centre) {
            return None; // its wrapped form could alias a resident key
        }
        self.find(key)
            .and_then(|(_, s)| self.slots.get(s))
            .map(|slot| slot.voxel.decode())
    }

    /// Every held voxel, decoded.
    pub fn iter(&self) -> impl Iterator<Item = LiveVoxel<D>> + '_ {
        self.slots
            .iter()
            .filter(|s| s.flags & OCCUPIED != 0)
            .map(|s| LiveVoxel {
                key: unwrap(s.key, self.centre),
                stats: s.voxel.decode(),
                residency: s.residency,
                unsent: s.unsent.to_f32(),
            })
    }

    /// The held voxel with the most kernel mass absorbed since it was last marked sent (for streaming the
    /// most changed voxels first); `None` if nothing changed.
    pub fn most_changed(&self) -> Option<LiveVoxel<D>> {
        let slot = self
            .slots
            .iter()
            .filter(|s| s.flags & OCCUPIED != 0 && s.unsent.to_f32() > 0.0)
            .max_by(|a, b| a.unsent.to_f32().total_cmp(&b.unsent.to_f32()))?;
        Some(LiveVoxel {
            key: unwrap(slot.key, self.centre),
            stats: slot.voxel.decode(),
            residency: slot.residency,
            unsent: slot.unsent.to_f32(),
        })
    }

    /// Mark a voxel as streamed: its unsent mass returns to zero.
    pub fn mark_sent(&mut self, key: VoxelKey) {
        if !Self::wrap_safe(key, self.centre) {
            return; // its wrapped form could alias a resident key
        }
        if let Some(slot) = self.find(key).and_then(|(_, s)| self.slots.get_mut(s)) {
            slot.unsent = f16::ZERO;
        }
    }

    /// The prior of an unobserved voxel.
    pub fn prior(&self) -> &VoxelStats<D> {
        &self.prior
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

    /// Bytes one voxel costs: its slot plus its share of the index.
    pub const BYTES_PER_VOXEL: usize =
        core::mem::size_of::<Slot<D, P>>() + 2 * core::mem::size_of::<u16>();
}
