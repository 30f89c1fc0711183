//! The map scale a tile asks for, measured from its points when the user gives none: the voxel size, the
//! kernel length and the simulated sensor's range and flying height.
//!
//! Why from the data: one fixed scale cannot fit every survey. The paper's 0.1 m voxel suits a tile whose
//! points are ~0.1 m apart (the built-in one); on an airborne tile with 0.75 m spacing it left 47 % of the
//! held-out points in voxels no point reached, and 1.2 km tiles in feet overflowed the device map's window.
//!
//! The rule (documented in the README's "Your own point cloud"):
//! - **spacing** s = 1/√density, the density counted over the area the points occupy (cells of 2 s,
//!   iterated from the bounding box, so an L-shaped or diagonal strip is not diluted by its empty corners);
//! - **voxel** = s rounded to the series 1, 1.25, 1.5, 2, 2.5, 3, 4, 5, 6, 8 × 10ᵏ (nearest in ratio); the
//!   built-in tile's 0.094 m gives the paper's 0.1 m;
//! - **kernel length** ℓ = 5 voxels (the paper's outdoor 0.5 m / 0.1 m);
//! - **range**: the sensor's sphere holds four frames' budget of points, r = 2 s √(budget/π), at least
//!   10 m (the default LiDAR, which the built-in tile keeps) unless that is over 1000 voxels;
//! - **altitude** = r / 5 (2 m at 10 m).

use super::sensor::RangeLidar;
use super::tile::Tile;
use latentbki::local_map::MAX_WINDOW_VOXELS;

/// The preferred numbers a measured length is rounded to (one decade).
pub const SERIES: [f32; 10] = [1.0, 1.25, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0];

/// `x` rounded to the nearest (in ratio) number of [`SERIES`] × 10ᵏ.
pub fn preferred(x: f32) -> f32 {
    if !(x.is_finite() && x > 0.0) {
        return x;
    }
    let decade = 10f32.powf(x.log10().floor());
    SERIES
        .iter()
        .chain(std::iter::once(&10.0))
        .map(|m| m * decade)
        .min_by(|a, b| (a / x).ln().abs().total_cmp(&(b / x).ln().abs()))
        .unwrap_or(x)
}

/// The smallest number of [`SERIES`] × 10ᵏ that is at least `x`.
pub fn preferred_at_least(x: f32) -> f32 {
    if !(x.is_finite() && x > 0.0) {
        return x;
    }
    let decade = 10f32.powf(x.log10().floor());
    SERIES
        .iter()
        .chain(std::iter::once(&10.0))
        .map(|m| m * decade)
        .find(|v| *v >= x * (1.0 - 1e-6))
        .unwrap_or(10.0 * decade)
}

/// Kernel length per voxel size (the paper's outdoor configuration: ℓ = 0.5 m for 0.1 m voxels).
pub const KERNEL_VOXELS: f32 = 5.0;

/// The voxel size the rule gives for a point spacing, metres.
pub fn voxel_for_spacing(spacing: f32) -> f32 {
    preferred(spacing)
}

/// The sensor, scaled to the tile: a range whose sphere holds about four frames' budget of points at the
/// tile's measured density (never below the default 10 m, which the committed tile uses, unless 10 m is
/// over 1000 voxels of the spacing's size), and a flying height above the ground of a fifth of the range
/// (2 m at 10 m).
pub fn scaled_sensor(tile: &Tile, points_per_frame: usize) -> (f32, f32) {
    let s = tile.spacing;
    let floor = scaled_sensor_floor(s);
    let range = 2.0 * s * (points_per_frame as f32 / std::f32::consts::PI).sqrt();
    let range = if range.is_finite() {
        range.max(floor)
    } else {
        floor
    };
    (range, range / 5.0)
}

/// The shortest range [`scaled_sensor`] gives at a spacing: the default LiDAR's 10 m, unless that is over
/// 1000 voxels.
pub fn scaled_sensor_floor(spacing: f32) -> f32 {
    RangeLidar::default()
        .range_m
        .min(1000.0 * voxel_for_spacing(spacing))
}

/// The device map's window, in voxels, for a sensor range (the range plus the kernel's reach, at least
/// 1 m: the window the evaluation's scene source gives its device map).
pub fn window_voxels(range: f32, voxel: f32, filter: u8) -> f32 {
    ((range + (f32::from(filter) * voxel).max(1.0)) / voxel).ceil()
}

/// Whether a window of that many voxels fits the device map.
pub fn window_fits(voxels: f32) -> bool {
    (1.0..=MAX_WINDOW_VOXELS as f32).contains(&voxels)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn preferred_numbers() {
        for (x, want) in [
            (0.094, 0.1),
            (0.59, 0.6),
            (0.75, 0.8),
            (1.3, 1.25),
            (3.5, 4.0),
            (9.6, 10.0),
            (123.0, 125.0),
            (0.0011, 0.001),
        ] {
            assert!(
                (preferred(x) - want).abs() < want * 1e-5,
                "{x} → {}",
                preferred(x)
            );
        }
        assert_eq!(preferred_at_least(0.26), 0.3);
        assert_eq!(preferred_at_least(3.0), 3.0);
        assert_eq!(preferred_at_least(8.5), 10.0);
    }
}
