//! The robot that revisits: how a user's tile is flown so that each surface is observed by about as many
//! frames as on the built-in tile.
//!
//! Why: fusing beats per-frame segmentation only where a place is seen several times (the network's
//! confusions are per segment and per block of frames, so one view cannot be outvoted). The built-in tile's
//! loop (60 frames of 3000 points over 25,408 points, 10 m range) returns each surface point in about 7
//! frames; the same 60 frames over a 110,000-point tile returned each about once, and the map lost to the
//! segmentation it fused. So on a user's tile the flight is *planned* from the tile:
//!
//! - **Laps of a survey**: the tile is cut into square cells of the sensor's range; a lap visits every cell
//!   that holds points once, in serpentine order (rows on even laps, columns on odd laps, so a surface is
//!   seen from other neighbours on the way back), each pose jittered inside its cell by up to a quarter of
//!   the cell, differently per lap. Every surface point is within range of its own cell's centre (at most
//!   0.71 of the range horizontally, plus the flying height of a fifth of the range).
//! - **As many laps as the built-in tile's revisits**: [`frames_per_surface`] is the expected number of
//!   frames that return a surface point (per frame: 1 if the sensor's budget covers every point in range,
//!   else budget / points in range), its median over the tile's points is the figure printed; laps are
//!   added until it reaches the built-in tile's, at least one lap ([`crate::sim::flight_plan`], which
//!   flies the laps this module lays out).
//!
//! The noise model of the simulated network is not touched: the map wins, where it does, on the evidence of
//! repeated views.

use super::Tile;
use crate::sim::sensor::RangeLidar;
use crate::sim::{mix_all, unit};
use latentbki::nalgebra::Isometry3;
use std::collections::HashMap;

/// The most laps a plan flies (a tile whose points cannot be reached by the sensor would add laps forever).
pub const MAX_LAPS: usize = 64;

/// The cells of a survey lap: squares of the sensor's range that hold points, from the tile's minimum
/// corner.
#[derive(Clone, Debug)]
pub struct Survey {
    cell: f32,
    lo: [f32; 2],
    cells: Vec<(i32, i32)>,
    /// The centroid (x, y) of each cell's points: a pose flies over the points, not over an empty corner.
    centroids: HashMap<(i32, i32), [f32; 2]>,
}

impl Survey {
    /// The survey of `tile` with a sensor of `range` metres.
    pub fn new(tile: &Tile, range: f32) -> Self {
        let cell = range.max(1e-3);
        let lo = [tile.bounds.0[0], tile.bounds.0[1]];
        let mut sums: HashMap<(i32, i32), [f64; 3]> = HashMap::new();
        for p in &tile.points {
            let k = (
                ((p[0] - lo[0]) / cell).floor() as i32,
                ((p[1] - lo[1]) / cell).floor() as i32,
            );
            let s = sums.entry(k).or_insert([0.0; 3]);
            s[0] += f64::from(p[0]);
            s[1] += f64::from(p[1]);
            s[2] += 1.0;
        }
        let mut cells: Vec<(i32, i32)> = sums.keys().copied().collect();
        cells.sort_unstable();
        let centroids = sums
            .into_iter()
            .map(|(k, s)| (k, [(s[0] / s[2]) as f32, (s[1] / s[2]) as f32]))
            .collect();
        Self {
            cell,
            lo,
            cells,
            centroids,
        }
    }

    /// Frames in one lap (one per cell that holds points).
    pub fn lap_len(&self) -> usize {
        self.cells.len().max(1)
    }

    /// The cells of lap `lap` in flying order: serpentine rows on even laps, columns on odd ones.
    fn lap_order(&self, lap: usize) -> Vec<(i32, i32)> {
        let mut c = self.cells.clone();
        if lap.is_multiple_of(2) {
            c.sort_unstable_by_key(|&(x, y)| (y, if y % 2 == 0 { x } else { -x }));
        } else {
            c.sort_unstable_by_key(|&(x, y)| (x, if x % 2 == 0 { y } else { -y }));
        }
        c
    }

    /// Frame `i`'s pose (horizontal position and heading; `z` is set by the caller), for a flight whose
    /// jitter is salted by `salt` (another salt: another flight over the same cells).
    pub fn poses(&self, frames: usize, salt: u64) -> Vec<([f32; 2], f32)> {
        let m = self.lap_len();
        let mut out = Vec::with_capacity(frames);
        let mut lap = 0;
        while out.len() < frames {
            let order = self.lap_order(lap);
            let at = |k: usize| -> [f32; 2] {
                let (cx, cy) = order[k % order.len()];
                let h = mix_all(&[salt, lap as u64, cx as u64, cy as u64]);
                let jx = (unit(mix_all(&[h, 1])) - 0.5) * 0.5;
                let jy = (unit(mix_all(&[h, 2])) - 0.5) * 0.5;
                let c = self.centroids.get(&(cx, cy)).copied().unwrap_or([
                    self.lo[0] + (cx as f32 + 0.5) * self.cell,
                    self.lo[1] + (cy as f32 + 0.5) * self.cell,
                ]);
                [c[0] + jx * self.cell, c[1] + jy * self.cell]
            };
            for k in 0..m.min(frames - out.len()) {
                let p = at(k);
                let next = at(k + 1);
                let yaw = (next[1] - p[1]).atan2(next[0] - p[0]);
                out.push((p, yaw));
            }
            lap += 1;
        }
        out
    }
}

/// Calls `each` with the indices of the tile's points within `range` of each pose (3D distance), pose by
/// pose.
pub(crate) fn for_points_in_range(
    tile: &Tile,
    poses: &[Isometry3<f32>],
    range: f32,
    mut each: impl FnMut(&[u32]),
) {
    let r = range.max(1e-3);
    let lo = tile.bounds.0;
    let key = |x: f32, y: f32| {
        (
            ((x - lo[0]) / r).floor() as i32,
            ((y - lo[1]) / r).floor() as i32,
        )
    };
    let mut grid: HashMap<(i32, i32), Vec<u32>> = HashMap::new();
    for (i, p) in tile.points.iter().enumerate() {
        grid.entry(key(p[0], p[1])).or_default().push(i as u32);
    }
    let mut seen: Vec<u32> = Vec::new();
    for pose in poses {
        let s = pose.translation.vector;
        let (cx, cy) = key(s.x, s.y);
        seen.clear();
        for dx in -1..=1 {
            for dy in -1..=1 {
                if let Some(ids) = grid.get(&(cx + dx, cy + dy)) {
                    seen.extend(ids.iter().copied().filter(|&i| {
                        let p = tile.points[i as usize];
                        let d = [p[0] - s.x, p[1] - s.y, p[2] - s.z];
                        d[0] * d[0] + d[1] * d[1] + d[2] * d[2] <= r * r
                    }));
                }
            }
        }
        each(&seen);
    }
}

/// Expected number of frames that return each tile point: per frame, every point within the sensor's
/// range counts `min(1, budget / points in range)` (the sensor keeps a uniform subset of its budget).
pub fn frames_per_surface(tile: &Tile, poses: &[Isometry3<f32>], lidar: &RangeLidar) -> Vec<f32> {
    let mut counts = vec![0.0f32; tile.points.len()];
    for_points_in_range(tile, poses, lidar.range_m, |seen| {
        if seen.is_empty() {
            return;
        }
        let p = (lidar.points_per_frame as f32 / seen.len() as f32).min(1.0);
        for &i in seen {
            counts[i as usize] += p;
        }
    });
    counts
}

/// The median of a list (0 for an empty one).
pub fn median(v: &[f32]) -> f32 {
    if v.is_empty() {
        return 0.0;
    }
    let mut s = v.to_vec();
    let k = s.len() / 2;
    s.select_nth_unstable_by(k, f32::total_cmp);
    s[k]
}

/// The `q`-quantile of a list (0 for an empty one).
pub fn quantile(v: &[f32], q: f32) -> f32 {
    if v.is_empty() {
        return 0.0;
    }
    let mut s = v.to_vec();
    let k = ((s.len() - 1) as f32 * q.clamp(0.0, 1.0)).round() as usize;
    s.select_nth_unstable_by(k, f32::total_cmp);
    s[k]
}
