//! The index: key → slot by open addressing with linear probing over 2·CAP u16 entries (slot + 1, 0 =
//! empty). O(1) lookup for 4 bytes per voxel; deletion shifts back the few entries of its probe run, so
//! there are no tombstones. (A heapless `FnvIndexMap<VoxelKey, u16, N>` costs ~20 B per voxel.)

use super::window::{unwrap, wrap};
use super::LocalMap;
use crate::forget::MapClock;
use crate::key::VoxelKey;

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

impl<const D: usize, const CAP: usize, const P: usize, const H: usize, C: MapClock>
    LocalMap<D, CAP, P, H, C>
{
    // Table positions come from `home` and `next`, always below TABLE; `get` keeps bounds-check panics
    // out of the firmware (an out-of-range position would read as empty and ignore writes).
    #[inline]
    pub(super) fn entry(&self, i: usize) -> u16 {
        self.index.as_flattened().get(i).copied().unwrap_or(0)
    }
    #[inline]
    pub(super) fn set_entry(&mut self, i: usize, v: u16) {
        if let Some(e) = self.index.as_flattened_mut().get_mut(i) {
            *e = v;
        }
    }
    #[inline]
    pub(super) fn home(k: VoxelKey) -> usize {
        let h = hash(k);
        if Self::TABLE < 1 << 16 {
            // (h·T) >> 32 from h's 16-bit halves, exactly (T < 2¹⁶: every product fits 32 bits): a 64-bit
            // product is a library call on v6-M.
            let t = Self::TABLE as u32;
            (((h >> 16) * t + (((h & 0xFFFF) * t) >> 16)) >> 16) as usize
        } else {
            ((u64::from(h) * Self::TABLE as u64) >> 32) as usize
        }
    }
    #[inline]
    pub(super) fn next(i: usize) -> usize {
        if i + 1 == Self::TABLE {
            0
        } else {
            i + 1
        }
    }

    /// (table position, slot) of a key.
    pub(super) fn find(&self, k: VoxelKey) -> Option<(usize, usize)> {
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

    /// Drop slot `s`, which holds `key`, from the index: its entry is the one holding s + 1 on `key`'s
    /// probe run (what [`Self::find`] would return, without reading the slots' keys).
    pub(super) fn unindex(&mut self, s: usize, key: VoxelKey) {
        let mut i = Self::home(key);
        for _ in 0..Self::TABLE {
            match usize::from(self.entry(i)) {
                0 => return,
                e if e == s + 1 => return self.index_remove(i),
                _ => i = Self::next(i),
            }
        }
    }

    pub(super) fn index_insert(&mut self, k: VoxelKey, slot: usize) {
        let mut i = Self::home(k);
        while self.entry(i) != 0 {
            i = Self::next(i);
        }
        self.set_entry(i, slot as u16 + 1);
    }

    /// Backward-shift deletion for linear probing.
    pub(super) fn index_remove(&mut self, mut hole: usize) {
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
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn home_from_halves_is_the_64_bit_product() {
        type Map = LocalMap<4, 30_000, 4, 2>;
        let mut seed = 0x2545_F491u32;
        for _ in 0..100_000 {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            let k = VoxelKey::new(
                seed as i32 >> 12,
                (seed << 7) as i32 >> 14,
                seed as i32 >> 20,
            );
            let want = ((u64::from(hash(k)) * Map::TABLE as u64) >> 32) as usize;
            assert_eq!(Map::home(k), want, "{k:?}");
        }
    }
}
