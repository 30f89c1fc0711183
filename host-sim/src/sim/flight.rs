//! The robot's flight over a tile: a closed loop over the middle 60 % of the tile, following the terrain,
//! with the sensor's range and altitude scaled to the tile's point density ([`super::scale`]).
//!
//! The tile is already the set of surface points a real LiDAR returned, so a frame is modelled as a
//! re-measurement of it — every tile point within the sensor's range of the pose, randomly subsampled to
//! the sensor's per-frame budget, each displaced by Gaussian range noise along its ray (see
//! [`super::sensor::RangeLidar`]). Occlusion is not simulated (the survey sensor saw each point).

use super::sensor::RangeLidar;
use super::tile::Tile;
use super::trajectory::{ellipse, level_pose};
use super::{mix_all, LabelledPoint, ScanFrame, Sequence};
use latentbki::nalgebra::Isometry3;
use latentbki::MapConfig;
use rand_xoshiro::rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use std::collections::{HashMap, HashSet};

/// Terrain following: the robot flies `altitude` above the lowest terrain point and leaves that height
/// only where the local ground (the median height of the terrain points within `altitude` of it,
/// horizontally; within the 3 × 3 cells of that size around it if there are none that close) would bring
/// it closer than `altitude / 2` or farther than `3 · altitude / 2`: it then holds the nearest edge of that
/// band. A deadband, as terrain-following autopilots use, so it does
/// not chase every bump: on a flat tile (the committed one: its ground spans 0.43 m) it flies level, and on
/// relief it stays between half and one and a half times its altitude above the ground beneath it.
pub struct TerrainFollowing {
    cell: f32,
    lo: [f32; 2],
    cells: HashMap<(i32, i32), Vec<[f32; 3]>>,
    floor: f32,
    altitude: f32,
}

impl TerrainFollowing {
    /// The terrain of `tile` for a flight `altitude` above it.
    pub fn new(tile: &Tile, altitude: f32) -> Self {
        let cell = altitude.max(0.05);
        let lo = [tile.bounds.0[0], tile.bounds.0[1]];
        let mut cells: HashMap<(i32, i32), Vec<[f32; 3]>> = HashMap::new();
        let terrain = tile.terrain_points();
        for p in &terrain {
            let k = (
                ((p[0] - lo[0]) / cell).floor() as i32,
                ((p[1] - lo[1]) / cell).floor() as i32,
            );
            cells.entry(k).or_default().push(*p);
        }
        let floor = terrain.iter().map(|p| p[2]).fold(f32::INFINITY, f32::min);
        Self {
            cell,
            lo,
            cells,
            floor,
            altitude,
        }
    }

    /// The local ground height around (x, y), if there is terrain nearby.
    pub fn ground(&self, x: f32, y: f32) -> Option<f32> {
        let (cx, cy) = (
            ((x - self.lo[0]) / self.cell).floor() as i32,
            ((y - self.lo[1]) / self.cell).floor() as i32,
        );
        let mut near: Vec<[f32; 3]> = (-1..=1)
            .flat_map(|dx| (-1..=1).map(move |dy| (cx + dx, cy + dy)))
            .filter_map(|k| self.cells.get(&k))
            .flatten()
            .copied()
            .collect();
        // No terrain that close (a patchy ground class): the nearest ring of cells that holds some, up to
        // 64 cells away, so the robot flies over the ground beneath its points, not the tile's lowest.
        let mut ring = 2;
        while near.is_empty() && ring <= 64 && !self.cells.is_empty() {
            near = (-ring..=ring)
                .flat_map(|dx| (-ring..=ring).map(move |dy| (dx, dy)))
                .filter(|&(dx, dy): &(i32, i32)| dx.abs() == ring || dy.abs() == ring)
                .filter_map(|(dx, dy)| self.cells.get(&(cx + dx, cy + dy)))
                .flatten()
                .copied()
                .collect();
            ring += 1;
        }
        let r2 = self.cell * self.cell;
        let mut z: Vec<f32> = near
            .iter()
            .filter(|p| (p[0] - x).powi(2) + (p[1] - y).powi(2) <= r2)
            .map(|p| p[2])
            .collect();
        if z.is_empty() {
            z = near.iter().map(|p| p[2]).collect();
        }
        if z.is_empty() {
            return None;
        }
        let k = z.len() / 2;
        z.select_nth_unstable_by(k, f32::total_cmp);
        Some(z[k])
    }

    /// The flying height over (x, y).
    pub fn height(&self, x: f32, y: f32) -> f32 {
        let level = self.floor + self.altitude;
        match self.ground(x, y) {
            Some(g) if self.floor.is_finite() => {
                level.clamp(g + 0.5 * self.altitude, g + 1.5 * self.altitude)
            }
            _ => level,
        }
    }
}

/// How the robot observes the tile.
#[derive(Clone, Copy, Debug)]
pub struct TileRun {
    /// Number of frames (poses on the loop).
    pub frames: usize,
    /// The sensor.
    pub lidar: RangeLidar,
    /// Flying height above the ground, metres (see [`TerrainFollowing`]).
    pub altitude: f32,
    /// Seed of the per-frame subsampling and range noise.
    pub seed: u64,
    /// Start of the loop, as a fraction of a turn (a different phase gives a different sequence).
    pub phase: f32,
    /// The map configuration the sequence asks for.
    pub config: MapConfig,
    /// Fly laps of a survey over the cells that hold points ([`super::tile::survey`]: the robot that
    /// revisits, planned for a user's tile) instead of the loop over the middle.
    pub survey: bool,
}

impl Default for TileRun {
    fn default() -> Self {
        Self {
            frames: 60,
            lidar: RangeLidar::default(),
            altitude: 2.0,
            seed: 1,
            phase: 0.0,
            config: MapConfig::default(),
            survey: false,
        }
    }
}

/// Cells of `size` metres that hold a point, keyed by (column, row) from the tile's minimum corner.
fn occupied_cells(tile: &Tile, size: f32) -> HashSet<(i32, i32)> {
    let lo = tile.bounds.0;
    tile.points
        .iter()
        .map(|p| {
            (
                ((p[0] - lo[0]) / size).floor() as i32,
                ((p[1] - lo[1]) / size).floor() as i32,
            )
        })
        .collect()
}

/// `n` poses over the cells that hold points, in serpentine order (rows of cells, alternate rows
/// reversed), evenly spread over the list of cells: a survey pattern for tiles whose points do not fill
/// their bounding box (an L-shaped edge strip, separate patches), which the loop over the middle misses.
fn over_the_points(tile: &Tile, cell: f32, z: f32, n: usize) -> Vec<Isometry3<f32>> {
    let mut cells: Vec<(i32, i32)> = occupied_cells(tile, cell).into_iter().collect();
    cells.sort_unstable_by_key(|&(x, y)| (y, if y % 2 == 0 { x } else { -x }));
    let lo = tile.bounds.0;
    (0..n)
        .map(|i| {
            let (cx, cy) = cells[i * cells.len() / n];
            let (nx, ny) = cells[((i + 1) * cells.len() / n) % cells.len()];
            let yaw = ((ny - cy) as f32).atan2((nx - cx) as f32);
            level_pose(
                [
                    lo[0] + (cx as f32 + 0.5) * cell,
                    lo[1] + (cy as f32 + 0.5) * cell,
                    z,
                ],
                yaw,
            )
        })
        .collect()
}

/// The robot's run through the tile: a closed loop over the middle 60 % of the tile, terrain-following;
/// where fewer than half of that loop's poses have points within the sensor's range of them, a survey
/// pattern over the cells that hold points instead (`over_the_points`). The default map configuration
/// is the paper's outdoor one (0.1 m, ℓ = 0.5 m, f = 3).
pub fn sequence(tile: &Tile, run: &TileRun) -> Sequence {
    let poses = sequence_poses(tile, run);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(run.seed);
    let instances: Vec<u32> = tile.classes.iter().map(|&c| u32::from(c)).collect();
    let frames = poses
        .into_iter()
        .map(|pose| {
            let points: Vec<LabelledPoint> =
                run.lidar
                    .scan(&tile.points, &tile.classes, &instances, &pose, &mut rng);
            ScanFrame { pose, points }
        })
        .collect();
    Sequence {
        name: "tile".into(),
        classes: tile.class_names(),
        config: run.config,
        frames,
        cutaway_height: None,
    }
}

/// The poses of [`sequence`], terrain-following: the loop over the middle (or its serpentine fallback),
/// or with [`TileRun::survey`] the laps of the revisiting survey ([`super::tile::survey::Survey`]).
pub fn sequence_poses(tile: &Tile, run: &TileRun) -> Vec<Isometry3<f32>> {
    let terrain = TerrainFollowing::new(tile, run.altitude);
    let n = run.frames.max(1);
    let lift = |mut pose: Isometry3<f32>| {
        let t = &mut pose.translation.vector;
        t.z = terrain.height(t.x, t.y);
        pose
    };
    let z = tile.ground_height() + run.altitude;
    if run.survey {
        let salt = mix_all(&[u64::from(run.phase.to_bits()), 0x5C7]);
        return super::tile::survey::Survey::new(tile, run.lidar.range_m)
            .poses(n, salt)
            .into_iter()
            .map(|(p, yaw)| lift(level_pose([p[0], p[1], z], yaw)))
            .collect();
    }
    let (lo, hi) = tile.bounds;
    let centre = [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0];
    let radii = [(hi[0] - lo[0]) * 0.3, (hi[1] - lo[1]) * 0.3];
    let mut loop_poses = ellipse(centre, radii, z, n * 8);
    // A pose sees points if its cell (of half the range: every point in it is within range) or a
    // neighbour holds some.
    let cell = (run.lidar.range_m / 2.0).max(1e-3);
    let occupied = occupied_cells(tile, cell);
    let over_points = loop_poses
        .iter()
        .filter(|p| {
            let t = p.translation.vector;
            let (cx, cy) = (
                ((t.x - lo[0]) / cell).floor() as i32,
                ((t.y - lo[1]) / cell).floor() as i32,
            );
            (-1..=1).any(|dx| (-1..=1).any(|dy| occupied.contains(&(cx + dx, cy + dy))))
        })
        .count();
    if 2 * over_points < loop_poses.len() {
        loop_poses = over_the_points(tile, cell, z, n * 8);
    }
    let offset = (run.phase.rem_euclid(1.0) * (n * 8) as f32) as usize;
    (0..n)
        .map(|i| lift(loop_poses[(offset + i * 8) % loop_poses.len()]))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_flies_level_and_keeps_its_range() {
        // The committed tile is flat (its ground spans 0.43 m): the terrain following leaves the old
        // level flight (2 m above the lowest ground point) unchanged, so its figures do not move.
        let t = Tile::builtin().unwrap();
        assert_eq!(super::super::scale::scaled_sensor(&t, 3000), (10.0, 2.0));
        let seq = sequence(&t, &TileRun::default());
        let level = t.ground_height() + 2.0;
        assert!(seq
            .frames
            .iter()
            .all(|f| f.pose.translation.vector.z == level));
    }
}
