//! The window around one hit that [`super::view_score`] lays out on the stack for f ≤ 3: every source and
//! map voxel its 27 targets can reach (±2 per axis), where each sits, and how the window moves on.
//!
//! Why a ring along z: consecutive hits are usually neighbours along z (the key's last field), so the next
//! hit's window is this one moved by a voxel or two. A slot holds (z mod 8, row): moving along z keeps
//! every map count already read where it is (a lookup costs far more than the arithmetic) and only clears
//! the planes that come in; the hits of those planes are found by one cursor per (x, y) row, which only
//! moves forward because the hits are sorted. A step to another row rebuilds the window.
//!
//! Slot of the voxel at (dx, dy) from the hit, at absolute z: `(z mod 8) · 32 + row`, row = 5·(dx+2) +
//! (dy+2) < 25. A move by (dx, dy, dz) from one voxel to another is then `+ dz · 32 + 5·dx + dy` modulo
//! 256: the row part never carries into the z part, and z wraps in the top three bits.

use crate::key::VoxelKey;
use crate::obs::ObsLookup;

/// Offsets of an f = 3 filter: the targets of one hit (≤ 32, one bit each).
pub(super) const MAX_TARGETS: usize = 27;
/// Slots of the ring: 8 z planes of 32 (25 used) rows. A power of two: a masked index is in bounds.
pub(super) const SLOTS: usize = 256;
/// Rows of a plane: (dx, dy) ∈ [−2, 2]².
const ROWS: usize = 25;
/// Reach of the window: ±2 voxels per axis.
const R: i32 = 2;
/// "Not read yet": 0, which a memclr writes. A slot holds a count's bits inverted, so 0 is the NaN with
/// all bits set (never a count the map returns as such: one it did would be read again, not misread).
const UNREAD: u32 = 0;

/// The slot step of an offset (see the module docs), as a wrapping byte.
pub(super) fn step(o: [i8; 3]) -> u8 {
    (32 * i32::from(o[2]) + 5 * i32::from(o[0]) + i32::from(o[1])) as u8
}

/// Position of the offset (dx, dy, dz), each in −2..=2, in the x-major order of the 5³ window (its
/// index in the key order of the voxels around a hit).
pub(super) fn x_major(dx: i32, dy: i32, dz: i32) -> usize {
    (((dx + R) * 5 + dy + R) * 5 + dz + R) as usize
}

/// The window around the current hit.
pub(super) struct Window {
    /// By slot: the point count of the hit there (n > 0; 0 where none), and the map count read there (its
    /// bits, inverted; [`UNREAD`] where not read yet). Side by side: one address for both, and a plane is
    /// cleared by one memclr.
    slots: [(f32, u32); SLOTS],
    /// Per plane (z mod 8): bit `row` set where a source sits.
    occupied: [u32; 8],
    /// Per row: the first hit above the window's top plane in that row (or beyond the row).
    next: [usize; ROWS],
    centre: Option<VoxelKey>,
}

impl Window {
    pub(super) fn new() -> Self {
        Self {
            slots: [(0.0, UNREAD); SLOTS],
            occupied: [0; 8],
            next: [0; ROWS],
            centre: None,
        }
    }

    /// The slot of the hit the window is centred on.
    pub(super) fn centre_slot(&self) -> u8 {
        self.centre.map_or(0, |c| ((c.z & 7) * 32 + 12) as u8)
    }

    /// The voxel at `slot`.
    #[inline(always)]
    fn key(&self, slot: usize) -> VoxelKey {
        let c = self.centre.unwrap_or_default();
        let row = (slot % 32) as i32;
        let dz = ((slot / 32) as i32 - (c.z & 7) + R) & 7;
        VoxelKey::new(
            c.x.wrapping_add(row / 5 - R),
            c.y.wrapping_add(row % 5 - R),
            c.z.wrapping_add(dz - R),
        )
    }

    /// (w, K) of the target at slot `t`: the kernel-weighted point counts of the hits and of the map
    /// around it, summed in the kernel table's order (each offset's slot step, and its weight).
    #[inline(always)]
    pub(super) fn sums<const D: usize, M: ObsLookup<D> + ?Sized>(
        &mut self,
        map: &M,
        steps: &[u8],
        weights: &[f32],
        t: u8,
    ) -> (f32, f32) {
        let (mut w, mut k_sum) = (0.0, 0.0);
        for (&step, &k) in steps.iter().zip(weights) {
            let s = usize::from(t.wrapping_add(step)) & (SLOTS - 1);
            // 0 where no hit with n > 0: adding k · 0 = +0 leaves w (≥ +0) as skipping it would.
            let (n, mut c) = self.slots[s];
            w += k * n;
            if c == UNREAD {
                c = !map.observed_count(self.key(s)).to_bits();
                self.slots[s].1 = c;
            }
            k_sum += k * f32::from_bits(!c);
        }
        (w, k_sum)
    }

    /// Centre the window on `hit` (the hits arrive in key order, `hit` among them): move it along z when
    /// the step is shorter than the window, renew all its planes otherwise; then place the hits of the
    /// planes that came in.
    pub(super) fn move_to(&mut self, hits: &[(VoxelKey, f32)], hit: VoxelKey) {
        let dz = self
            .centre
            .filter(|c| (c.x, c.y) == (hit.x, hit.y))
            .and_then(|c| u32::try_from(hit.z.wrapping_sub(c.z)).ok())
            .filter(|&dz| dz < 5);
        // A step to another row, or too far along z, brings in a whole window of planes. The 3 planes of
        // the ring outside the window are never read.
        let fresh = dz.map_or(5, |dz| dz as i32);
        self.centre = Some(hit);
        let top = hit.z.wrapping_add(R);
        // The planes that come in: clear what the planes 8 below left there.
        for p in 0..fresh {
            // Keeps this loop rolled (flash; see `view_score`).
            core::hint::black_box(());
            let z = top.wrapping_sub(p) & 7;
            let base = z as usize * 32;
            if let Some(s) = self.slots.get_mut(base..base + ROWS) {
                s.fill((0.0, UNREAD));
            }
            if let Some(o) = self.occupied.get_mut(z as usize) {
                *o = 0;
            }
        }
        let lowest = top.wrapping_sub(fresh - 1);
        for (row, next) in self.next.iter_mut().enumerate() {
            let x = hit.x.wrapping_add(row as i32 / 5 - R);
            let y = hit.y.wrapping_add(row as i32 % 5 - R);
            let to = VoxelKey::new(x, y, top);
            // Nothing at or below the window's top in this row: nothing to skip or place (the common
            // case, one comparison).
            if hits.get(*next).is_none_or(|h| h.0 > to) {
                continue;
            }
            // Rows only move forward (keys ascend): skip what lies below the new planes.
            let from = VoxelKey::new(x, y, lowest);
            while hits.get(*next).is_some_and(|h| h.0 < from) {
                *next += 1;
            }
            while let Some(&(k, n)) = hits.get(*next).filter(|h| h.0 <= to) {
                if n > 0.0 {
                    self.slots[((k.z & 7) as usize * 32 + row) & (SLOTS - 1)].0 = n;
                    self.occupied[(k.z & 7) as usize] |= 1 << row;
                }
                *next += 1;
            }
        }
    }

    /// The x-major positions (see [`x_major`]) of the sources below the centre in key order: the earlier
    /// hits within ±2. Calls `f` with each.
    pub(super) fn earlier(&self, mut f: impl FnMut(usize)) {
        let Some(c) = self.centre else {
            return;
        };
        for dz in -R..=R {
            // Keeps this loop rolled (flash; see `view_score`).
            core::hint::black_box(());
            // Rows below the centre's (x, y) in key order; the centre's own row below it in z.
            let rows = if dz < 0 { (1 << 13) - 1 } else { (1 << 12) - 1 };
            let mut bits = self.occupied[(c.z.wrapping_add(dz) & 7) as usize] & rows;
            while bits != 0 {
                let row = bits.trailing_zeros() as i32;
                bits &= bits - 1;
                // x_major(dx, dy, dz) = 5 · row + dz + 2: the row is (dx + 2) · 5 + dy + 2.
                f((5 * row + dz + R) as usize);
            }
        }
    }
}
