//! The 5³ window around one hit that [`super::view_score`] lays out on the stack for f ≤ 3: where its
//! sources and map counts sit, how the hits are placed in it, and how counts move to the next hit's window.

use crate::key::VoxelKey;

/// Offsets of an f = 3 filter: the targets of one hit (≤ 32, one bit each).
pub(super) const MAX_TARGETS: usize = 27;
/// Side of the window of voxels a hit's targets' sources span with f = 3: ±2.
pub(super) const WIN: i16 = 5;
pub(super) const WIN3: usize = 125;
/// The window's arrays are a power of two long, so a masked index needs no bounds check.
pub(super) const SLOTS: usize = 128;
pub(super) const CENTRE: i16 = WIN3 as i16 / 2;

/// The offset from a window's hit to window position `s` (x-major).
pub(super) fn window_offset(s: usize) -> [i8; 3] {
    let w = WIN as usize;
    let r = w / 2;
    [
        (s / (w * w)) as i8 - r as i8,
        (s / w % w) as i8 - r as i8,
        (s % w) as i8 - r as i8,
    ]
}

/// The point counts of the hits (those with n > 0) within ±2 of `hits[i]`, by window position; 0 where
/// none. They lie in the run of hits whose x is within ±2 (x is the key's first field). Differences wrap:
/// keys stay within ±2³⁰, as [`VoxelKey::offset`] requires.
pub(super) fn place_sources(sources: &mut [f32; SLOTS], hits: &[(VoxelKey, f32)], i: usize) {
    *sources = [0.0; SLOTS];
    let Some(&(c, _)) = hits.get(i) else {
        return;
    };
    let r = i32::from(WIN / 2);
    let lo = hits.partition_point(|h| h.0.x < c.x.saturating_sub(r));
    let x_end = c.x.saturating_add(r);
    for &(k, n) in hits.get(lo..).unwrap_or(&[]) {
        if k.x > x_end {
            break;
        }
        let d = |a: i32, b: i32| a.wrapping_sub(b).wrapping_add(r);
        let (dx, dy, dz) = (d(k.x, c.x), d(k.y, c.y), d(k.z, c.z));
        let w = i32::from(WIN);
        // Each in 0..WIN after the +r: one unsigned compare per axis.
        if n > 0.0 && (dx as u32) < w as u32 && (dy as u32) < w as u32 && (dz as u32) < w as u32 {
            sources[((dx * w + dy) * w + dz) as usize & (SLOTS - 1)] = n;
        }
    }
}

/// Move the map counts read for the window at `from` to where they sit in the window at `to` when the
/// step is along z only (the common step between consecutive hits: z is the key's last field); NaN (not
/// read yet) elsewhere.
pub(super) fn carry_counts(counts: &mut [f32; SLOTS], from: Option<VoxelKey>, to: VoxelKey) {
    let w = WIN as usize;
    let step = from
        .filter(|f| (f.x, f.y) == (to.x, to.y))
        .and_then(|f| usize::try_from(to.z.checked_sub(f.z)?).ok())
        .filter(|&dz| dz < w);
    let Some(dz) = step else {
        *counts = [f32::NAN; SLOTS];
        return;
    };
    // Position q takes old q + dz, except the last dz of each z row.
    for q in 0..WIN3 {
        counts[q & (SLOTS - 1)] = if q % w + dz < w {
            counts[(q + dz) & (SLOTS - 1)]
        } else {
            f32::NAN
        };
    }
}
