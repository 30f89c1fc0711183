//! World-anchored voxel keys.
//!
//! A voxel is named by `floor(x / voxel_size)` per axis in the map frame, so every robot, the base station
//! and every session agree on voxel identity without sharing any state but the voxel size. Keys are kept
//! within ±2³⁰ per axis so that neighbour offsets can never overflow and the f32 → i32 conversion is exact.
//! (f32 itself resolves 0.1 m only up to ~1 km from the origin: callers with geo-referenced data subtract a
//! local origin first, in f64, on the host.)

use nalgebra::{Isometry3, Point3};

/// An integer voxel offset from a voxel to a neighbour (the kernel's table lists those it reaches).
pub type Offset = [i8; 3];

/// Largest |index| per axis a key may have.
pub const KEY_LIMIT: i32 = 1 << 30;

/// Integer index of a voxel in the map frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct VoxelKey {
    /// Index along the map x axis.
    pub x: i32,
    /// Index along the map y axis.
    pub y: i32,
    /// Index along the map z axis.
    pub z: i32,
}

/// Why a point could not be given a voxel key.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum KeyError {
    /// A coordinate is NaN or infinite.
    NonFinite,
    /// A coordinate is beyond ±[`KEY_LIMIT`] voxels.
    OutOfRange,
}

impl core::fmt::Display for KeyError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::NonFinite => "a coordinate is NaN or infinite",
            Self::OutOfRange => "a coordinate is beyond the voxel key range",
        })
    }
}

impl core::error::Error for KeyError {}

impl VoxelKey {
    /// A key from its three indices (not range-checked: use for keys that came from [`Self::from_position`]).
    pub const fn new(x: i32, y: i32, z: i32) -> Self {
        Self { x, y, z }
    }

    /// The voxel containing a map-frame position.
    pub fn from_position(p: [f32; 3], inv_voxel_size: f32) -> Result<Self, KeyError> {
        let mut k = [0i32; 3];
        for axis in 0..3 {
            if !p[axis].is_finite() {
                return Err(KeyError::NonFinite);
            }
            let x = p[axis] * inv_voxel_size;
            if !(x > -(KEY_LIMIT as f32) && x < KEY_LIMIT as f32) {
                return Err(KeyError::OutOfRange);
            }
            // floor without libm's `floorf` (a function call on the device): truncate, then step down for
            // negative non-integers. |x| < 2³⁰, so the conversion is exact.
            let t = x as i32;
            k[axis] = t - i32::from(x < t as f32);
        }
        Ok(Self::new(k[0], k[1], k[2]))
    }

    /// The key as `[x, y, z]`.
    pub const fn as_array(self) -> [i32; 3] {
        [self.x, self.y, self.z]
    }

    /// Whether a key's indices are all within ±[`KEY_LIMIT`] (keys received from outside are checked so).
    pub fn in_range(self) -> bool {
        self.as_array()
            .iter()
            .all(|&i| i > -KEY_LIMIT && i < KEY_LIMIT)
    }

    /// The neighbour at an offset of at most ±3 voxels per axis.
    pub fn offset(self, o: Offset) -> Self {
        // |index| < 2³⁰ and |o| ≤ 3, so these additions cannot overflow.
        Self::new(
            self.x + i32::from(o[0]),
            self.y + i32::from(o[1]),
            self.z + i32::from(o[2]),
        )
    }

    /// Centre of the voxel in the map frame.
    pub fn centroid(self, voxel_size: f32) -> [f32; 3] {
        let a = self.as_array();
        [
            (a[0] as f32 + 0.5) * voxel_size,
            (a[1] as f32 + 0.5) * voxel_size,
            (a[2] as f32 + 0.5) * voxel_size,
        ]
    }

    /// Squared Euclidean distance between two keys, in voxels² (for robot-centric windows).
    pub fn distance_squared(self, other: Self) -> i64 {
        let d = |a: i32, b: i32| i64::from(a) - i64::from(b);
        let (dx, dy, dz) = (d(self.x, other.x), d(self.y, other.y), d(self.z, other.z));
        dx * dx + dy * dy + dz * dz
    }
}

/// Move a sensor-frame point into the map frame with the sensor's pose (sensor → map).
pub fn to_map_frame(pose: &Isometry3<f32>, p: [f32; 3]) -> [f32; 3] {
    let q = pose.transform_point(&Point3::new(p[0], p[1], p[2]));
    [q.x, q.y, q.z]
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    #[test]
    fn floor_not_truncate() {
        let k = VoxelKey::from_position([0.05, -0.05, -0.1], 10.0).unwrap();
        assert_eq!(k, VoxelKey::new(0, -1, -1));
        assert_eq!(
            VoxelKey::from_position([f32::NAN, 0.0, 0.0], 10.0),
            Err(KeyError::NonFinite)
        );
        assert_eq!(
            VoxelKey::from_position([0.0, f32::INFINITY, 0.0], 10.0),
            Err(KeyError::NonFinite)
        );
        assert_eq!(
            VoxelKey::from_position([0.0, 0.0, 2e8], 10.0),
            Err(KeyError::OutOfRange)
        );
    }

    #[test]
    fn pose_moves_points_into_the_map_frame() {
        let pose = Isometry3::from_parts(
            Translation3::new(1.0, 2.0, 3.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, core::f32::consts::FRAC_PI_2),
        );
        let q = to_map_frame(&pose, [1.0, 0.0, 0.0]);
        assert!(
            (q[0] - 1.0).abs() < 1e-6 && (q[1] - 3.0).abs() < 1e-6 && (q[2] - 3.0).abs() < 1e-6
        );
    }
}
