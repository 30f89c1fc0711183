//! The window that follows the robot: keys are stored as 3 × i16 wrapped around its centre (the window is
//! far smaller than 2¹⁶ voxels, so the full key is recovered exactly), and a move evicts the voxels left
//! outside in place — it reads every key but writes only the evicted slots.

use super::{LocalMap, OCCUPIED};
use crate::forget::MapClock;
use crate::key::VoxelKey;
use crate::sink::EvictionSink;

pub(super) fn wrap(k: VoxelKey) -> [i16; 3] {
    [k.x as i16, k.y as i16, k.z as i16]
}

/// Whether `k` is within `radius` voxels of `centre` ([`VoxelKey::distance_squared`] ≤ r²) in 32 bits: an
/// axis farther than r is outside at once; otherwise every |d| ≤ r ≤ [`super::MAX_WINDOW_VOXELS`] < 2¹⁵, so
/// the d² sum stays below 3·2³⁰.
#[inline(always)]
fn within(k: VoxelKey, centre: VoxelKey, radius: i32) -> bool {
    let r = radius.unsigned_abs();
    let (dx, dy, dz) = (
        k.x.abs_diff(centre.x),
        k.y.abs_diff(centre.y),
        k.z.abs_diff(centre.z),
    );
    dx <= r && dy <= r && dz <= r && dx * dx + dy * dy + dz * dz <= r * r
}

pub(super) fn unwrap(w: [i16; 3], centre: VoxelKey) -> VoxelKey {
    let d = |w: i16, c: i32| c + i32::from(w.wrapping_sub(c as i16));
    VoxelKey::new(d(w[0], centre.x), d(w[1], centre.y), d(w[2], centre.z))
}

impl<const D: usize, const CAP: usize, const P: usize, const H: usize, C: MapClock>
    LocalMap<D, CAP, P, H, C>
{
    /// Whether a key is close enough to a centre to be stored wrapped (every axis within ±2¹⁵).
    pub(super) fn wrap_safe(k: VoxelKey, centre: VoxelKey) -> bool {
        let ok = |a: i32, c: i32| (i64::from(a) - i64::from(c)).abs() < 1 << 15;
        ok(k.x, centre.x) && ok(k.y, centre.y) && ok(k.z, centre.z)
    }

    /// Whether a key is within the window's radius of its centre: [`VoxelKey::distance_squared`] ≤ r².
    #[inline]
    pub(super) fn in_window(&self, k: VoxelKey) -> bool {
        #[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
        return {
            // The M4F's `smull`/`smlal`: the 64-bit form is the shortest there.
            let r = i64::from(self.radius);
            k.distance_squared(self.centre) <= r * r
        };
        #[cfg(not(all(target_arch = "arm", target_abi = "eabihf")))]
        return self.in_window_32(k);
    }

    /// [`Self::in_window`] in 32 bits (per point; a 64-bit product is a library call on v6-M, three
    /// multiplies on RV32). An axis farther than r is outside at once; otherwise every |d| ≤ r ≤
    /// [`super::MAX_WINDOW_VOXELS`] < 2¹⁵, so the d² sum stays below 3·2³⁰.
    #[inline]
    #[cfg_attr(all(target_arch = "arm", target_abi = "eabihf"), allow(dead_code))]
    pub(super) fn in_window_32(&self, k: VoxelKey) -> bool {
        within(k, self.centre, self.radius)
    }

    /// Re-centre the window on a map-frame position and evict the voxels now outside it. Returns the number
    /// evicted. Refused evictions stay (counted); if one of them would fall out of the key wrap range the
    /// centre does not move this time.
    // Out of line on Arm: inlined into a firmware's loop, its scan kept its values on the stack there
    // (≈ 55 instructions a slot on the M4F). Inlined on riscv32imac, whose minimal build has no flash for
    // the call's copy (+ 580 B).
    #[cfg_attr(target_arch = "arm", inline(never))]
    pub fn move_window<S: EvictionSink<D>>(&mut self, position: [f32; 3], sink: &mut S) -> usize {
        let Ok(new_centre) = VoxelKey::from_position(position, self.lut.inv_voxel_size()) else {
            return 0;
        };
        let old_centre = self.centre;
        if new_centre == old_centre && !self.stranded {
            // Every voxel was taken inside this same window and none was left outside by a refused
            // eviction: nothing can be outside. (A 64-point ToF frame would otherwise read every key.)
            return 0;
        }
        // A slot's offset from the new centre straight from its wrapped key: (w − c₀) as i16 + (c₀ − c₁) per
        // axis; the full key is unwrapped only for a voxel that leaves (`leave`, out of line, so the scan
        // keeps its few values in registers). A move reads every key — an 8×8 ToF moves every 64 points —
        // and unwrapping each key with the 64-bit distance cost ≈ 55 instructions a slot on the M4F. Every
        // held key is within 2¹⁵ of the old centre, so an axis moved by 2¹⁶ or more leaves all of them
        // more than 2¹⁵ > r away: the offset is clamped there, and i32 never overflows.
        let offset = |o: i32, n: i32| {
            let off = (i64::from(o) - i64::from(n)).clamp(-(1 << 16), 1 << 16) as i32;
            (o as i16, off)
        };
        let [(cx, ox), (cy, oy), (cz, oz)] = [
            offset(old_centre.x, new_centre.x),
            offset(old_centre.y, new_centre.y),
            offset(old_centre.z, new_centre.z),
        ];
        let r = self.radius.unsigned_abs();
        let (mut evicted, mut stranded, mut keep_centre) = (0, false, false);
        for s in 0..CAP {
            let Some(slot) = self.slots.get(s) else {
                break;
            };
            if slot.flags & OCCUPIED == 0 {
                continue;
            }
            let w = slot.key;
            let d = |w: i16, c: i16, off: i32| (i32::from(w.wrapping_sub(c)) + off).unsigned_abs();
            let (dx, dy, dz) = (d(w[0], cx, ox), d(w[1], cy, oy), d(w[2], cz, oz));
            if dx <= r && dy <= r && dz <= r && dx * dx + dy * dy + dz * dz <= r * r {
                continue;
            }
            match self.leave(s, old_centre, new_centre, stranded, sink) {
                Ok(()) => evicted += 1,
                Err(wrap_unsafe) => {
                    stranded = true;
                    keep_centre |= wrap_unsafe;
                }
            }
        }
        // Keys are stored wrapped: any centre within the wrap range unwraps them to the same full keys, so
        // moving the centre rewrites nothing.
        if !keep_centre {
            self.centre = new_centre;
        }
        self.stranded = stranded;
        evicted
    }

    /// Slot `s` left the window moving from `old_centre` to `new_centre`: evict it, unless the sink has
    /// already refused one in this move (`refused`: it refuses the rest too, nothing drains it in between,
    /// so the voxel stays without being gathered for nothing — on a link-bound 8×8 ToF run a move
    /// re-offered every voxel left outside, each decoded first: 5,148 refusals). `Err` when it stays, with
    /// whether its key would fall out of the wrap range of the new centre.
    #[cfg_attr(target_arch = "arm", cold, inline(never))]
    #[cfg_attr(not(target_arch = "arm"), inline(always))]
    fn leave<S: EvictionSink<D>>(
        &mut self,
        s: usize,
        old_centre: VoxelKey,
        new_centre: VoxelKey,
        refused: bool,
        sink: &mut S,
    ) -> Result<(), bool> {
        if !refused && self.evict_slot(s, sink) {
            return Ok(());
        }
        let key = self
            .slots
            .get(s)
            .map_or(new_centre, |slot| unwrap(slot.key, old_centre));
        Err(!Self::wrap_safe(key, new_centre))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_32_bit_window_test_is_the_64_bit_one() {
        let mut map = LocalMap::<4, 4, 4, 2>::EMPTY;
        let mut seed = 0x9E37_79B9u32;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            seed
        };
        for radius in [1, 2, 7, 100, super::super::MAX_WINDOW_VOXELS] {
            map.radius = radius;
            for _ in 0..20_000 {
                let c = |v: u32| (v % (4 * radius as u32 + 3)) as i32 - 2 * radius - 1;
                let far = |v: u32| v as i32 >> (v % 32);
                map.centre = VoxelKey::new(far(next()), c(next()), 0);
                let k = VoxelKey::new(
                    map.centre.x.wrapping_add(c(next())),
                    map.centre.y.wrapping_add(c(next())),
                    far(next()) % 3 * c(next()),
                );
                let r = i64::from(radius);
                let want = k.distance_squared(map.centre) <= r * r;
                assert_eq!(
                    map.in_window_32(k),
                    want,
                    "{k:?} {:?} r = {radius}",
                    map.centre
                );
                assert_eq!(map.in_window(k), want);
            }
        }
    }
}
