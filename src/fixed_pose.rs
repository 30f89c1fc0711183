//! Integer sensor points: a sensor frame's pose in fixed point, so that a point in millimetres finds its
//! voxel without a float operation.
//!
//! Why: range sensors report integers (a ToF or a LiDAR gives millimetres), and on a microcontroller without
//! an FPU (Cortex-M0+, RV32IMAC) the f32 pose transform and key computation of a point are ~20 software float
//! operations — more than the whole int8 feature update. The pose is converted once per sensor frame
//! ([`FixedPose::new`], float) into a rotation scaled to voxel units in Q12 and a translation in 1/256 voxel;
//! each point is then nine 32-bit multiplies, adds and shifts. The key equals the f32 path's except for
//! points within the fixed-point rounding of a voxel face (≤ 2⁻¹¹ of the point's range: 0.5 mm at 1 m).

use crate::key::VoxelKey;
use nalgebra::Isometry3;

/// Fractional bits of a map coordinate in voxel units (1/256 voxel).
const SUB: u32 = 8;
/// Fractional bits of the rotation entries (in sub-voxels per millimetre).
const Q: u32 = 10;
/// Largest |coordinate| of a sensor-frame point in millimetres: 2¹⁵ mm ≈ 32.7 m.
pub const MAX_POINT_MM: i32 = 1 << 15;
/// Smallest voxel (m) the fixed-point pose takes: |entry| ≤ 2¹⁸ / (1000 · voxel) = 13,107 at 2 cm, so the
/// three products of a row sum to at most 3 · 13,107 · 2¹⁵ < 2³¹ — 32-bit multiplies (one instruction on
/// a Cortex-M0+), no 64-bit arithmetic.
pub const MIN_VOXEL_SIZE: f32 = 0.02;

/// A sensor → map pose in fixed point, for points in millimetres.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FixedPose {
    /// Rotation × (sub-voxels per mm), Q12, row-major.
    m: [[i32; 3]; 3],
    /// Translation in sub-voxels.
    t: [i32; 3],
}

impl FixedPose {
    /// The pose for a map of `voxel_size` metres, or `None` if it cannot be represented: a non-finite pose,
    /// a voxel under [`MIN_VOXEL_SIZE`], or a translation beyond 2²² voxels (419 km at 0.1 m) from the map
    /// origin.
    pub fn new(pose: &Isometry3<f32>, voxel_size: f32) -> Option<Self> {
        if !(voxel_size >= MIN_VOXEL_SIZE) {
            return None;
        }
        let sub_per_mm = (1u32 << SUB) as f32 / (voxel_size * 1000.0);
        let r = pose.rotation.to_rotation_matrix();
        let mut m = [[0i32; 3]; 3];
        for (i, row) in m.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                let x = r[(i, j)] * sub_per_mm * (1u32 << Q) as f32;
                if !x.is_finite() {
                    return None;
                }
                *v = libm::roundf(x) as i32;
            }
        }
        let tv = pose.translation.vector;
        let mut t = [0i32; 3];
        for (ti, x) in t.iter_mut().zip([tv.x, tv.y, tv.z]) {
            let s = x / voxel_size * (1u32 << SUB) as f32;
            // Below 2³⁰ sub-voxels, so adding a point's (< 2²¹) cannot overflow.
            if !(s.abs() < (1u32 << 30) as f32) {
                return None;
            }
            *ti = libm::roundf(s) as i32;
        }
        Some(Self { m, t })
    }

    /// The voxel of a sensor-frame point given in millimetres, or `None` if a coordinate is beyond
    /// ±[`MAX_POINT_MM`].
    #[inline]
    pub fn key_of(&self, p: [i32; 3]) -> Option<VoxelKey> {
        if p.iter().any(|c| c.unsigned_abs() >= MAX_POINT_MM as u32) {
            return None;
        }
        let mut k = [0i32; 3];
        for ((row, t), out) in self.m.iter().zip(self.t).zip(&mut k) {
            // Bounded below 2³¹ (see MIN_VOXEL_SIZE and `new`): wrapping only so no overflow check links.
            let s = row[0]
                .wrapping_mul(p[0])
                .wrapping_add(row[1].wrapping_mul(p[1]))
                .wrapping_add(row[2].wrapping_mul(p[2]));
            // Arithmetic shifts are floor divisions; |key| < 2²³ < KEY_LIMIT.
            *out = ((s >> Q).wrapping_add(t)) >> SUB;
        }
        Some(VoxelKey::new(k[0], k[1], k[2]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::key::to_map_frame;
    use nalgebra::{Translation3, UnitQuaternion};

    #[test]
    fn keys_equal_the_f32_path_away_from_voxel_faces() {
        let mut x = 0x9E37_79B9u32;
        let mut next = move || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x
        };
        let (mut same, mut total) = (0, 0);
        for _ in 0..200 {
            let r = |n: u32| (n % 20_000) as f32 / 1000.0 - 10.0;
            let pose = Isometry3::from_parts(
                Translation3::new(r(next()), r(next()), r(next()) * 0.1),
                UnitQuaternion::from_euler_angles(r(next()), r(next()), r(next())),
            );
            let fixed = FixedPose::new(&pose, 0.1).unwrap();
            for _ in 0..50 {
                let p_mm = [
                    (next() % 16_000) as i32 - 8_000,
                    (next() % 16_000) as i32 - 8_000,
                    (next() % 16_000) as i32 - 8_000,
                ];
                let p = p_mm.map(|v| v as f32 / 1000.0);
                let q = to_map_frame(&pose, p);
                let want = VoxelKey::from_position(q, 10.0).unwrap();
                let got = fixed.key_of(p_mm).unwrap();
                total += 1;
                if got == want {
                    same += 1;
                } else {
                    // Only where the point is within the fixed-point rounding of a face: 2⁻¹⁰ of its
                    // range in voxels (plus the translation's 1/512 voxel).
                    let range_vox = libm::sqrtf(p.iter().map(|v| v * v).sum::<f32>()) * 10.0;
                    let tol = range_vox / 1024.0 + 1.0 / 256.0;
                    let near = q
                        .iter()
                        .any(|c| (c * 10.0 - libm::roundf(c * 10.0)).abs() < tol);
                    assert!(near, "{p_mm:?} → {q:?}: {got:?} vs {want:?}");
                    assert!(got.distance_squared(want) <= 3);
                }
            }
        }
        // Ranges up to 14 m here: about 2 % of the points lie within the rounding of a face.
        assert!(same * 100 >= total * 97, "{same} of {total}");
    }

    #[test]
    fn out_of_range_points_and_poses_are_refused() {
        let id = Isometry3::identity();
        let f = FixedPose::new(&id, 0.1).unwrap();
        assert_eq!(f.key_of([MAX_POINT_MM, 0, 0]), None);
        assert_eq!(f.key_of([0, i32::MIN, 0]), None);
        assert_eq!(f.key_of([-150, 0, 99]), Some(VoxelKey::new(-2, 0, 0)));
        let far = Isometry3::translation(1e9, 0.0, 0.0);
        assert_eq!(FixedPose::new(&far, 0.1), None);
        let nan = Isometry3::translation(f32::NAN, 0.0, 0.0);
        assert_eq!(FixedPose::new(&nan, 0.1), None);
        assert_eq!(FixedPose::new(&id, 0.01), None);
    }
}
