//! The window that follows the robot: keys are stored as 3 × i16 wrapped around its centre (the window is
//! far smaller than 2¹⁶ voxels, so the full key is recovered exactly), and a move evicts the voxels left
//! outside in place — it reads every key but writes only the evicted slots. A sparse sensor (an 8×8 ToF)
//! moves the window every frame, so the scan is a tight loop of its own, and a move whose evictions the
//! sink refuses reads no more keys than it must (see `out_of_range`).

use super::{LocalMap, Slot, OCCUPIED};
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

    /// Whether a key is within the window's radius of its centre: [`VoxelKey::distance_squared`] ≤ r², in
    /// 32 bits (per point that misses the hot entries at hand; a 64-bit product is a library call on v6-M,
    /// three multiplies on RV32, and on the M4F its `smull`/`umull` form took ≈ 36 instructions where this
    /// takes ≈ 20). An axis farther than r is outside at once; otherwise every |d| ≤ r ≤
    /// [`super::MAX_WINDOW_VOXELS`] < 2¹⁵, so the d² sum stays below 3·2³⁰.
    #[inline]
    pub(super) fn in_window(&self, k: VoxelKey) -> bool {
        within(k, self.centre, self.radius)
    }

    /// Re-centre the window on a map-frame position and evict the voxels now outside it. Returns the number
    /// evicted. Refused evictions stay (counted); if one of them would fall out of the key wrap range the
    /// centre does not move this time.
    // Out of line on Arm (inlined into a firmware's loop, it kept its values on the stack there). Inlined
    // on riscv32imac, whose minimal build has no flash for the call's copy (+ 250 B).
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
        let mut shift = Shift::new(old_centre, new_centre, self.radius);
        // Every held key lies within r (+ drift while stranded) of the old centre on each axis (see
        // `drift`), so within that + the move's reach of the new one: below 2¹⁵ its offset is the
        // wrapped difference to the new centre, exactly.
        let drift = if self.stranded { self.drift } else { 0 };
        if cfg!(target_arch = "arm")
            && self.radius.unsigned_abs() + u32::from(drift) + shift.reach() < 1 << 15
        {
            shift.near = Some(wrap(new_centre));
        }
        let (mut evicted, mut refused, mut keep_centre) = (0, false, false);
        let mut from = 0;
        while let Some(i) = shift.next_beyond(self.slots.get(from..).unwrap_or_default()) {
            let s = from + i;
            from = s + 1;
            if self.leave(s, sink) {
                evicted += 1;
                continue;
            }
            // It stays, and so do the rest left outside: nothing drains the sink in between, so it refuses
            // them too (they are not gathered for nothing — on a link-bound 8×8 ToF run a move would
            // re-offer every voxel left outside, each decoded first).
            refused = true;
            keep_centre = self.out_of_range(&shift, s);
            break;
        }
        // Keys are stored wrapped: any centre within the wrap range unwraps them to the same full keys, so
        // moving the centre rewrites nothing.
        if !keep_centre {
            self.centre = new_centre;
        }
        self.stranded = refused;
        evicted
    }

    /// A move's eviction was refused at slot `first`: whether a held voxel from there on is out of the wrap
    /// range of the new centre (such a voxel is beyond r: left outside), so that the centre must not move.
    /// Every held key lies within r + drift of the old centre on each axis (see `drift`), so within
    /// r + drift + the move's reach (its largest axis or more) of the new one: below 2¹⁵ none can be, and
    /// no key is read — the common case, a link-bound sensor whose moves are refused one after another
    /// (reading the rest of the keys after each refusal cost ≈ 3 M instructions on the 8×8 ToF, a third
    /// of its moves'). If the centre moves, the bound grows by the move (capped: every held key is within
    /// the range). Out of line: riscv32imac's minimal build has room for this loop only once.
    #[cold]
    #[inline(never)]
    fn out_of_range(&mut self, shift: &Shift, first: usize) -> bool {
        // After a move that left nothing outside, every held voxel lies inside the window.
        let drift = if self.stranded {
            u32::from(self.drift)
        } else {
            0
        } + shift.reach();
        let out = self.radius.unsigned_abs() + drift >= 1 << 15
            && self
                .slots
                .iter()
                .skip(first)
                .any(|slot| slot.flags & OCCUPIED != 0 && shift.out_of_wrap_range(slot.key));
        if !out {
            self.drift = drift.min(1 << 15) as u16;
        }
        out
    }

    /// Slot `s` left the window: hand it to the sink. False if the sink refused it (it stays).
    #[cfg_attr(target_arch = "arm", cold, inline(never))]
    #[cfg_attr(not(target_arch = "arm"), inline(always))]
    fn leave<S: EvictionSink<D>>(&mut self, s: usize, sink: &mut S) -> bool {
        self.evict_slot(s, sink)
    }
}

/// A window move from the old centre c₀ to the new one c₁, as the scan over the held keys uses it: a slot's
/// offset from c₁ straight from its wrapped key, (w − c₀) as i16 + (c₀ − c₁) per axis, never unwrapped.
/// Every held key is within 2¹⁵ of c₀, so an axis moved by 2¹⁷ or more leaves all of them more than
/// 2¹⁶ > r away, out of the wrap range too: the shift is clamped there, and i32 never overflows.
///
/// `near`: the new centre wrapped, when every held key is known to lie within 2¹⁵ of it on each axis —
/// every move of a robot within its window's reach: the offset is then `w − c₁` in i16 arithmetic, exactly,
/// and the scan needs no clamp: `PROFILE_SCENARIO=tof_f3_i8 bash boards/measure-targets.sh --profile
/// thumbv6m` next_beyond 4.28 → 2.38 M instructions (9,216 points), `bash boards/profile-scenario.sh 5`
/// (M4F ToF) 2.00 → 1.55 M. Arm only: riscv32imac's minimal build has no flash for the second loop (+288 B).
struct Shift {
    old: [i16; 3],
    by: [i32; 3],
    r2: u32,
    near: Option<[i16; 3]>,
}

impl Shift {
    #[inline(always)]
    fn new(old: VoxelKey, new: VoxelKey, radius: i32) -> Self {
        // Centres are keys of positions, within ±2³⁰ (`KEY_LIMIT`): c₀ − c₁ fits i32.
        let by = |o: i32, n: i32| o.wrapping_sub(n).clamp(-(1 << 17), (1 << 17) - 1);
        Self {
            old: wrap(old),
            by: [by(old.x, new.x), by(old.y, new.y), by(old.z, new.z)],
            r2: radius.unsigned_abs().pow(2),
            near: None,
        }
    }

    /// How far the move went: the sum of its axes in voxels (each clamped at 2¹⁷), at least its largest.
    #[inline(always)]
    fn reach(&self) -> u32 {
        self.by.iter().map(|b| b.unsigned_abs()).sum()
    }

    /// Whether a held wrapped key is out of the wrap range of the new centre: an axis offset beyond
    /// ±(2¹⁵ − 1), as [`LocalMap::wrap_safe`] (the offset is exact, or clamped beyond 2¹⁶ where the true
    /// one is), tested as one unsigned compare an axis.
    #[inline(always)]
    fn out_of_wrap_range(&self, w: [i16; 3]) -> bool {
        const SAFE: i32 = (1 << 15) - 1;
        self.offset(w)
            .iter()
            .any(|&d| (d + SAFE) as u32 > 2 * SAFE as u32)
    }

    /// The offset of a wrapped key from the new centre (each axis exact, or clamped beyond 2¹⁶).
    #[inline(always)]
    fn offset(&self, w: [i16; 3]) -> [i32; 3] {
        let d = |a: usize| i32::from(w[a].wrapping_sub(self.old[a])) + self.by[a];
        [d(0), d(1), d(2)]
    }

    /// The first held voxel of `slots` beyond the radius from the new centre. A move reads every key — an
    /// 8×8 ToF moves every 64 points — so this loop is a function of its own on Arm, over a slice, with
    /// nothing but the centre, the shift and r² live: ≈ 24 instructions a held slot on the M4F (inside
    /// the move, with the eviction's values around it, it spilled them to the stack: ≈ 45).
    #[cfg_attr(target_arch = "arm", inline(never))]
    fn next_beyond<const D: usize, const P: usize, T: Copy>(
        &self,
        slots: &[Slot<D, P, T>],
    ) -> Option<usize> {
        let r2 = self.r2;
        if let Some(c) = self.near {
            // |offset| < 2¹⁵ an axis: three squares below 3·2³⁰ fit u32.
            let sq = |w: i16, c: i16| {
                let d = i32::from(w.wrapping_sub(c));
                (d * d) as u32
            };
            return slots.iter().position(|slot| {
                slot.flags & OCCUPIED != 0
                    && sq(slot.key[0], c[0]) + sq(slot.key[1], c[1]) + sq(slot.key[2], c[2]) > r2
            });
        }
        slots
            .iter()
            .position(|slot| slot.flags & OCCUPIED != 0 && beyond(self.offset(slot.key), r2))
    }
}

/// Whether offset `d` from the centre (each |d| < 2¹⁸) lies farther than r (r² = `r2` < 2²⁸) in 32 bits:
/// each axis saturated to i16 first — an axis saturated is beyond r ≤ [`super::MAX_WINDOW_VOXELS`] on its
/// own, and three squares of at most 2³⁰ stay below 2³², so one test, no branch per axis.
#[inline(always)]
fn beyond(d: [i32; 3], r2: u32) -> bool {
    let sq = |d: i32| {
        let d = d.clamp(i32::from(i16::MIN), i32::from(i16::MAX));
        (d * d) as u32
    };
    sq(d[0]) + sq(d[1]) + sq(d[2]) > r2
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The scan's short form (`near`: offsets as i16 differences to the new centre) finds the same slots
    /// beyond the radius as the general one, for held keys anywhere the bound allows (within r + drift of
    /// the old centre on each axis, the move's reach keeping the sum below 2¹⁵), centres anywhere.
    #[test]
    fn the_near_scan_is_the_general_one() {
        type S = Slot<1, 1, ()>;
        let mut seed = 0x2545_F491u32;
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            seed
        };
        let mut slots = [S::empty(()); 64];
        let mut hits = 0;
        for round in 0..4_000 {
            let radius = [1, 3, 40, 1_000, super::super::MAX_WINDOW_VOXELS][round % 5];
            let spare = (1 << 15) - 1 - radius as u32; // drift + reach
            let drift = next() % (spare + 1);
            let reach_max = spare - drift;
            let span = |v: u32, m: u32| (v % (2 * m + 1)) as i32 - m as i32;
            let old = VoxelKey::new(next() as i32 >> 2, next() as i32 >> 2, next() as i32 >> 2);
            let (bx, by) = (span(next(), reach_max / 2), span(next(), reach_max / 2));
            let bz = span(next(), reach_max - bx.unsigned_abs() - by.unsigned_abs());
            let new = VoxelKey::new(old.x + bx, old.y + by, old.z + bz);
            let near_old = radius as u32 + drift;
            for slot in slots.iter_mut() {
                // Mostly close to the new centre's sphere, so that both answers occur.
                let m = if next() % 2 == 0 {
                    near_old
                } else {
                    radius as u32 + 2
                };
                let k = VoxelKey::new(
                    old.x + span(next(), m),
                    old.y + span(next(), m),
                    old.z + span(next(), m),
                );
                let k = if m == near_old {
                    k
                } else {
                    VoxelKey::new(
                        new.x + span(next(), m),
                        new.y + span(next(), m),
                        new.z + span(next(), m),
                    )
                };
                let within_old = [k.x - old.x, k.y - old.y, k.z - old.z]
                    .iter()
                    .all(|d| d.unsigned_abs() <= near_old);
                slot.key = wrap(k);
                slot.flags = if within_old && next() % 8 != 0 {
                    OCCUPIED
                } else {
                    0
                };
            }
            let general = Shift::new(old, new, radius);
            let reach = general.reach();
            assert!(radius as u32 + drift + reach < 1 << 15);
            let near = Shift {
                near: Some(wrap(new)),
                ..Shift::new(old, new, radius)
            };
            let mut from = 0;
            loop {
                let rest = &slots[from..];
                let (a, b) = (general.next_beyond(rest), near.next_beyond(rest));
                assert_eq!(a, b, "round {round}: r = {radius}, {old:?} → {new:?}");
                let Some(i) = a else { break };
                hits += 1;
                from += i + 1;
            }
        }
        assert!(hits > 10_000, "{hits}");
    }

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
                    map.in_window(k),
                    want,
                    "{k:?} {:?} r = {radius}",
                    map.centre
                );
            }
        }
    }
}
