//! The window around one hit that [`super::view_score`] lays out on the stack for f ≤ 3: every source and
//! map voxel its 27 targets can reach (±2 per axis), where each sits, and how the window moves on.
//!
//! Why a ring along z: consecutive hits are usually neighbours along z (the key's last field), so the next
//! hit's window is this one moved by a voxel or two. A slot holds (z mod 16, row): moving along z keeps
//! every map count already read where it is (a lookup costs far more than the arithmetic) and only clears
//! the planes that come in; the hits of those planes are found by one cursor per (x, y) row, which only
//! moves forward because the hits are sorted. Why 16 planes, and rows shifted: a view's next run of hits
//! is usually the next y (a wall, a depth image's column), whose window overlaps the previous run's by 4
//! of its 5 lines in y over the same z. The ring keeps the planes of the whole run (up to 16), and a step
//! to the next y moves every plane's rows by one line — by moving where slot 0 lies in the array (`base`),
//! not the 4 KiB (copying them cost a view 0.03 M instructions): each map count is then read once per
//! view, not once per run that reaches it. Any other step to another row rebuilds the window.
//!
//! Slot of the voxel at (dx, dy) from the hit, at absolute z: `(z mod 16) · 32 + row`, row = 5·(dx+2) +
//! (dy+2) < 25. A move by (dx, dy, dz) from one voxel to another is then `+ dz · 32 + 5·dx + dy` modulo
//! 512: the row part never carries into the z part, and z wraps in the top four bits.

use crate::key::VoxelKey;
use crate::obs::ObsLookup;

/// Offsets of an f = 3 filter: the targets of one hit (≤ 32, one bit each).
pub(super) const MAX_TARGETS: usize = 27;
/// Slots of the ring: 16 z planes of 32 (25 used) rows. A power of two: a masked index is in bounds.
pub(super) const SLOTS: usize = 512;
/// Planes of the ring.
const PLANES: i32 = 16;
/// Rows of a plane: (dx, dy) ∈ [−2, 2]².
const ROWS: usize = 25;
/// Reach of the window: ±2 voxels per axis.
const R: i32 = 2;
/// "Not read yet": 0, which a memclr writes. A slot holds a count negated, so 0 is a count of −0 (one the
/// map returned would be read again, not misread), and the sum subtracts it: k_sum − k·(−c) is k_sum +
/// k·c to the bit (negation is exact), one instruction less per term than undoing an inversion.
const UNREAD: u32 = 0;

/// Rows of the line dy = +2 (row % 5 = 4), which a step to the next y brings in.
const LAST_LINE: u32 = 1 << 4 | 1 << 9 | 1 << 14 | 1 << 19 | 1 << 24;

/// The slot step of an offset (see the module docs), wrapping modulo [`SLOTS`].
pub(super) fn step(o: [i8; 3]) -> u16 {
    (32 * i32::from(o[2]) + 5 * i32::from(o[0]) + i32::from(o[1])) as u16
}

/// Position of the offset (dx, dy, dz), each in −2..=2, in the x-major order of the 5³ window (its
/// index in the key order of the voxels around a hit).
pub(super) fn x_major(dx: i32, dy: i32, dz: i32) -> usize {
    (((dx + R) * 5 + dy + R) * 5 + dz + R) as usize
}

/// The window around the current hit.
pub(super) struct Window {
    /// By slot: the point count of the hit there (n > 0; 0 where none), and the map count read there (its
    /// bits, negated; [`UNREAD`] where not read yet). Side by side: one address for both, and a plane is
    /// cleared by one memclr.
    slots: [(f32, u32); SLOTS],
    /// Per plane (z mod 16): bit `row` set where a source sits.
    occupied: [u32; PLANES as usize],
    /// Per row: the first hit above the highest plane held in that row (or beyond the row).
    next: [usize; ROWS],
    /// The hit the window is centred on.
    centre: VoxelKey,
    /// The absolute z of the highest plane the ring holds for the centre's rows: it holds the 16 up to it.
    /// (Before the first hit every slot is empty, which holds for any planes: all zero, one memclr.)
    held: i32,
    /// Where slot 0 lies in `slots`: a step to the next y moves every slot back by one by adding 1 here
    /// (a ring: the 4 KiB are not copied).
    base: u16,
}

impl Window {
    pub(super) fn new() -> Self {
        Self {
            slots: [(0.0, UNREAD); SLOTS],
            occupied: [0; PLANES as usize],
            next: [0; ROWS],
            centre: VoxelKey::new(0, 0, 0),
            held: 0,
            base: 0,
        }
    }

    /// The slot of the hit the window is centred on.
    pub(super) fn centre_slot(&self) -> u16 {
        (((self.centre.z & (PLANES - 1)) * 32 + 12) as u16).wrapping_add(self.base)
    }

    /// Where slot `slot` (plane · 32 + row) lies in `slots`.
    #[inline(always)]
    fn at(&self, slot: usize) -> usize {
        (slot + usize::from(self.base)) & (SLOTS - 1)
    }

    /// The voxel at position `at` of `slots`.
    #[inline(always)]
    fn key(&self, at: usize) -> VoxelKey {
        let slot = at.wrapping_sub(usize::from(self.base)) & (SLOTS - 1);
        let c = self.centre;
        let row = (slot % 32) as i32;
        let dz = ((slot / 32) as i32 - (c.z & (PLANES - 1)) + R) & (PLANES - 1);
        VoxelKey::new(
            c.x.wrapping_add(row / 5 - R),
            c.y.wrapping_add(row % 5 - R),
            c.z.wrapping_add(dz - R),
        )
    }

    /// (w, K) of the target at slot `t`: the kernel-weighted point counts of the hits and of the map
    /// around it, summed in the kernel table's order (each offset's slot step beside its weight: one
    /// pointer walks both in the hot loop).
    #[inline(always)]
    pub(super) fn sums<const D: usize, M: ObsLookup<D> + ?Sized>(
        &mut self,
        map: &M,
        kernel: &[(u32, f32)],
        t: u16,
    ) -> (f32, f32) {
        let (mut w, mut k_sum) = (0.0, 0.0);
        for &(step, k) in kernel {
            let s = usize::from(t.wrapping_add(step as u16)) & (SLOTS - 1);
            // 0 where no hit with n > 0: adding k · 0 = +0 leaves w (≥ +0) as skipping it would.
            let (n, mut c) = self.slots[s];
            w += k * n;
            if c == UNREAD {
                c = (-map.observed_count(self.key(s))).to_bits();
                self.slots[s].1 = c;
            }
            k_sum -= k * f32::from_bits(c);
        }
        (w, k_sum)
    }

    /// Centre the window on `hit` (the hits arrive in key order, `hit` among them): move it along z, or
    /// to the next y (rows shifted by a line), keeping the planes held; renew them otherwise. Then place
    /// the hits of the planes and lines that came in.
    pub(super) fn move_to(&mut self, hits: &[(VoxelKey, f32)], hit: VoxelKey) {
        let top = hit.z.wrapping_add(R);
        let (c, held) = (self.centre, self.held);
        // Along z in this row, or to the next y, with the window's bottom among the planes held: those
        // planes stay (the planes above them come in); else all 16 planes are renewed.
        let dy = hit.y.wrapping_sub(c.y) as u32;
        let keep =
            c.x == hit.x && dy <= 1 && top.wrapping_sub(2 * R) >= held.wrapping_sub(PLANES - 1);
        if keep && dy == 1 {
            self.next_line();
        }
        let held = if keep { held } else { i32::MIN };
        let mut z = held.max(top.wrapping_sub(PLANES));
        // The planes that come in: clear what the planes 16 below left there.
        while z < top {
            // Keeps this loop rolled (flash; see `view_score`).
            core::hint::black_box(());
            z = z.wrapping_add(1);
            let p = (z & (PLANES - 1)) as usize;
            // The plane's rows, which may wrap around the array's end.
            let from = self.at(p * 32);
            let (lo, hi) = self.slots.split_at_mut(from);
            let rest = ROWS.saturating_sub(hi.len());
            if let Some(s) = hi.get_mut(..ROWS - rest) {
                s.fill((0.0, UNREAD));
            }
            if let Some(s) = lo.get_mut(..rest) {
                s.fill((0.0, UNREAD));
            }
            if let Some(o) = self.occupied.get_mut(p) {
                *o = 0;
            }
        }
        self.held = held.max(top);
        let lowest = self.held.wrapping_sub(PLANES - 1);
        self.centre = hit;
        for (row, next) in self.next.iter_mut().enumerate() {
            let x = hit.x.wrapping_add(row as i32 / 5 - R);
            let y = hit.y.wrapping_add(row as i32 % 5 - R);
            let to = VoxelKey::new(x, y, top);
            // Nothing at or below the window's top in this row: nothing to skip or place (the common
            // case, one comparison).
            if hits.get(*next).is_none_or(|h| h.0 > to) {
                continue;
            }
            // Rows only move forward (keys ascend): skip what lies below the planes held.
            let from = VoxelKey::new(x, y, lowest);
            while hits.get(*next).is_some_and(|h| h.0 < from) {
                *next += 1;
            }
            while let Some(&(k, n)) = hits.get(*next).filter(|h| h.0 <= to) {
                if n > 0.0 {
                    let p = (k.z & (PLANES - 1)) as usize;
                    let s = (p * 32 + row + usize::from(self.base)) & (SLOTS - 1);
                    self.slots[s].0 = n;
                    self.occupied[p] |= 1 << row;
                }
                *next += 1;
            }
        }
    }

    /// A step to the next y: every plane's rows move by one line (dy − 1; the rows past the 25th are
    /// never read), the line dy = +2 comes in empty, and its cursors continue from the line before it
    /// (whose hits precede its).
    #[inline(never)]
    fn next_line(&mut self) {
        self.base = self.base.wrapping_add(1);
        self.next.copy_within(1.., 0);
        let mut row = 4;
        while row < ROWS {
            self.next[row] = self.next[row - 1];
            row += 5;
        }
        for (p, o) in self.occupied.iter_mut().enumerate() {
            // Keeps this loop rolled (flash; see `view_score`).
            core::hint::black_box(());
            *o = *o >> 1 & !LAST_LINE;
            let mut row = 4;
            while row < ROWS {
                let s = (p * 32 + row + usize::from(self.base)) & (SLOTS - 1);
                self.slots[s] = (0.0, UNREAD);
                row += 5;
            }
        }
    }

    /// The x-major positions (see [`x_major`]) of the sources below the centre in key order: the earlier
    /// hits within ±2. Calls `f` with each.
    pub(super) fn earlier(&self, mut f: impl FnMut(usize)) {
        let c = self.centre;
        for dz in -R..=R {
            // Keeps this loop rolled (flash; see `view_score`).
            core::hint::black_box(());
            // Rows below the centre's (x, y) in key order; the centre's own row below it in z.
            let rows = if dz < 0 { (1 << 13) - 1 } else { (1 << 12) - 1 };
            let mut bits = self.occupied[(c.z.wrapping_add(dz) & (PLANES - 1)) as usize] & rows;
            while bits != 0 {
                let row = bits.trailing_zeros() as i32;
                bits &= bits - 1;
                // x_major(dx, dy, dz) = 5 · row + dz + 2: the row is (dx + 2) · 5 + dy + 2.
                f((5 * row + dz + R) as usize);
            }
        }
    }
}
