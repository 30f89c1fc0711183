//! Adding f32 points: each point through the pose into its voxel's hot entry — the previous point's, the
//! recent-hot hint's, else the voxel's own or a new one (a slot allocated, evicting if the pool is full) —
//! and one Welford step there. Every refusal is counted.

use super::{hot_tile, LocalMap};
use crate::batch::{locate, Rejection};
use crate::forget::MapClock;
use crate::key::{to_map_frame, VoxelKey};
use crate::sink::EvictionSink;
use nalgebra::Isometry3;

impl<const D: usize, const CAP: usize, const P: usize, const H: usize, C: MapClock>
    LocalMap<D, CAP, P, H, C>
{
    /// Integrate one batch of sensor-frame points seen from `pose` (sensor → map): the window follows the
    /// sensor, then every point. Returns the number of points integrated; the others are counted in
    /// [`Self::rejections`]. (A firmware does this through [`crate::Mapper`], which owns the sink too.)
    pub fn integrate<S: EvictionSink<D>>(
        &mut self,
        pose: &Isometry3<f32>,
        points: &[[f32; 3]],
        features: &[[f32; D]],
        sink: &mut S,
    ) -> usize {
        let t = pose.translation.vector;
        self.move_window([t.x, t.y, t.z], sink);
        self.add_points(pose, points, features, sink)
    }

    /// Add sensor-frame points seen from `pose` without moving the window (one chunk of a frame). Returns
    /// the number integrated; the others are counted in [`Self::rejections`].
    pub fn add_points<S: EvictionSink<D>>(
        &mut self,
        pose: &Isometry3<f32>,
        points: &[[f32; 3]],
        features: &[[f32; D]],
        sink: &mut S,
    ) -> usize {
        self.add_paired(pose, points, features, |m, p, y| m.add_point(p, y, sink))
    }

    /// Each point through `pose` into `add` with its feature; returns how many were taken. A refusal is
    /// counted in `rejections` by `add`; a point without a feature (or a feature without a point) is
    /// counted here, never silently dropped.
    pub(super) fn add_paired<F>(
        &mut self,
        pose: &Isometry3<f32>,
        points: &[[f32; 3]],
        features: &[F],
        mut add: impl FnMut(&mut Self, [f32; 3], &F) -> Result<(), Rejection>,
    ) -> usize {
        let mut taken = 0;
        for (p, y) in points.iter().zip(features) {
            if add(self, to_map_frame(pose, *p), y).is_ok() {
                taken += 1;
            }
        }
        for _ in 0..points.len().abs_diff(features.len()) {
            self.rejections.count(Rejection::Unpaired);
        }
        taken
    }

    /// Add one map-frame point: `Ok` means its voxel took it. Refusals are counted in [`Self::rejections`]
    /// ([`Rejection::NoRoom`] when the pool is full and the sink refuses the eviction that would make room).
    pub fn add_point<S: EvictionSink<D>>(
        &mut self,
        position: [f32; 3],
        feature: &[f32; D],
        sink: &mut S,
    ) -> Result<(), Rejection> {
        self.counted(|m| m.take_point(position, feature, sink))
    }

    /// Run one point's intake: count it as taken or refused.
    #[inline]
    pub(super) fn counted(
        &mut self,
        take: impl FnOnce(&mut Self) -> Result<(), Rejection>,
    ) -> Result<(), Rejection> {
        match take(self) {
            Ok(()) => {
                self.counters.points = self.counters.points.wrapping_add(1);
                Ok(())
            }
            Err(r) => {
                self.rejections.count(r);
                Err(r)
            }
        }
    }

    fn take_point<S: EvictionSink<D>>(
        &mut self,
        position: [f32; 3],
        feature: &[f32; D],
        sink: &mut S,
    ) -> Result<(), Rejection> {
        let (key, _) = locate(&self.lut, position, feature)?;
        let h = self.hot_entry(key, sink, false)?;
        self.hot_to_now(h);
        let scale = self.int8_scale;
        let e = self.hot.get_mut(h).ok_or(Rejection::NoRoom)?;
        e.acc.add_f32(feature, scale);
        e.referenced = true;
        Ok(())
    }

    /// The hot entry of `key`'s voxel: the previous point's, else the voxel's own, else a new one (a slot
    /// allocated, evicting if the pool is full).
    ///
    /// On Arm the common case — the previous point's entry or the recent-hot hint's holds `key`, and no
    /// held voxel was left outside the window — is inlined into the per-point path (no call, no `Result`
    /// in memory: int8 871 → 848 instructions a point on the M4F, +470 B of flash). Flash decides where:
    /// riscv32imac's firmware and the M4F's forgetting build (a clock with stamps) have none to spare for
    /// it, so there it stays one call — but for int8 points (`int8`), whose relative cost of forgetting
    /// (issue 21) would otherwise rise.
    #[inline(always)]
    pub(super) fn hot_entry<S: EvictionSink<D>>(
        &mut self,
        key: VoxelKey,
        sink: &mut S,
        int8: bool,
    ) -> Result<usize, Rejection> {
        #[cfg(target_arch = "arm")]
        if int8 || core::mem::size_of::<C::Stamp>() == 0 {
            if let Some(h) = self.hot_at_hand(key) {
                return Ok(h);
            }
            // Not stranded, it looked at both entries at hand: `find_hot` need not again.
            let missed = !self.stranded;
            return self.find_hot(key, sink, missed);
        }
        #[cfg(target_arch = "arm")]
        return self.find_hot(key, sink, false);
        #[cfg(not(target_arch = "arm"))]
        {
            let _ = int8;
            self.find_hot(key, sink)
        }
    }

    /// [`Self::hot_entry`]'s common case alone: the hot entry of `key`'s voxel if it is the previous
    /// point's or the recent-hot hint's (and no held voxel was left outside the window); `None` otherwise.
    #[cfg(target_arch = "arm")]
    #[inline(always)]
    pub(super) fn hot_at_hand(&mut self, key: VoxelKey) -> Option<usize> {
        if self.stranded {
            return None;
        }
        let held = |h: usize| h < self.hot_len && self.hot.get(h).is_some_and(|e| e.key == key);
        if held(self.last_hot) {
            return Some(self.last_hot);
        }
        let h = usize::from(*self.recent_hot.get(hot_tile(key))?);
        if held(h) {
            self.last_hot = h;
            return Some(h);
        }
        None
    }

    /// [`Self::hot_entry`] in full.
    #[cfg_attr(target_arch = "arm", inline(never))]
    #[cfg_attr(not(target_arch = "arm"), inline)]
    fn find_hot<S: EvictionSink<D>>(
        &mut self,
        key: VoxelKey,
        sink: &mut S,
        #[cfg(target_arch = "arm")] missed: bool,
    ) -> Result<usize, Rejection> {
        // Off Arm, `missed` is no parameter (it cost riscv32imac's minimal build 22 B): always false.
        #[cfg(not(target_arch = "arm"))]
        let missed = false;
        // The previous point's entry, else the recent-hot hint (unless [`Self::hot_at_hand`] found neither
        // holds `key`: `missed`, ≈ 40 instructions a point on thumbv6m not spent twice). A voxel holds at
        // most one hot entry, so an entry in use that holds `key` is the one the index would lead to (its
        // slot's `hot`): the same answer without the lookup.
        let tile = hot_tile(key);
        let held = |h: usize| h < self.hot_len && self.hot.get(h).is_some_and(|e| e.key == key);
        let hot = if missed {
            None
        } else if held(self.last_hot) {
            Some(self.last_hot)
        } else {
            self.recent_hot
                .get(tile)
                .map(|&h| usize::from(h))
                .filter(|&h| held(h))
        };
        // A hot voxel is held by the map (so it is configured), and every held voxel lies inside the window
        // unless the last move left one outside (`stranded`): then no window test is needed.
        if hot.is_none() || self.stranded {
            if self.lut.offsets().is_empty() {
                // Not configured (`EMPTY`): no room for anything.
                return Err(Rejection::NoRoom);
            }
            if !self.in_window(key) {
                return Err(Rejection::OutsideWindow);
            }
        }
        if let Some(h) = hot {
            self.last_hot = h;
            return Ok(h);
        }
        let h = match self.find(key) {
            Some((_, s)) => match self.slots.get(s).map_or(0, |slot| slot.hot) {
                0 => self.make_hot(s, key),
                h => usize::from(h - 1),
            },
            None => {
                let s = self.alloc(key, sink).ok_or(Rejection::NoRoom)?;
                self.make_hot(s, key)
            }
        };
        self.last_hot = h;
        if let Some(r) = self.recent_hot.get_mut(tile) {
            *r = h as u8;
        }
        Ok(h)
    }
}
