//! Robot trajectories: smooth, closed paths through a scene, sampled at one pose per frame.
//!
//! Poses are sensor → map. A forward-looking sensor (camera, ToF) uses the optical convention: x right,
//! y down, z forward; the pose's rotation maps those axes into the map (z up).

use latentbki::nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// A camera pose at `position` looking along `yaw` (radians from +x, counter-clockwise) and pitched down by
/// `pitch` radians (optical axes: x right, y down, z forward).
pub fn camera_pose(position: [f32; 3], yaw: f32, pitch: f32) -> Isometry3<f32> {
    let (sy, cy) = yaw.sin_cos();
    let (sp, cp) = pitch.sin_cos();
    let forward = Vector3::new(cy * cp, sy * cp, -sp);
    let right = Vector3::new(sy, -cy, 0.0);
    let down = forward.cross(&right);
    let m = Matrix3::from_columns(&[right, down, forward]);
    let rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m));
    Isometry3::from_parts(
        Translation3::new(position[0], position[1], position[2]),
        rot,
    )
}

/// A level, z-up sensor pose (for a spinning LiDAR) at `position` heading along `yaw`.
pub fn level_pose(position: [f32; 3], yaw: f32) -> Isometry3<f32> {
    Isometry3::from_parts(
        Translation3::new(position[0], position[1], position[2]),
        UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
    )
}

/// Points every `step` metres along a closed polyline through `waypoints` (xy), with the heading of travel.
pub fn along_polyline(waypoints: &[[f32; 2]], step: f32) -> Vec<([f32; 2], f32)> {
    let mut out = Vec::new();
    if waypoints.len() < 2 || step.is_nan() || step <= 0.0 {
        return out;
    }
    let mut carry = 0.0f32;
    for i in 0..waypoints.len() {
        let a = waypoints[i];
        let b = waypoints[(i + 1) % waypoints.len()];
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        let len = (dx * dx + dy * dy).sqrt();
        if len == 0.0 {
            continue;
        }
        let yaw = dy.atan2(dx);
        let mut s = carry;
        while s < len {
            let t = s / len;
            out.push(([a[0] + t * dx, a[1] + t * dy], yaw));
            s += step;
        }
        carry = s - len;
    }
    out
}

/// `n` poses evenly spaced on an ellipse (centre, radii) at height `z`, heading along the ellipse.
pub fn ellipse(centre: [f32; 2], radii: [f32; 2], z: f32, n: usize) -> Vec<Isometry3<f32>> {
    (0..n)
        .map(|i| {
            let a = i as f32 / n as f32 * std::f32::consts::TAU;
            let p = [
                centre[0] + radii[0] * a.cos(),
                centre[1] + radii[1] * a.sin(),
                z,
            ];
            let yaw = (radii[1] * a.cos()).atan2(-radii[0] * a.sin());
            level_pose(p, yaw)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use latentbki::nalgebra::Point3;

    #[test]
    fn camera_looks_where_it_is_told() {
        let pose = camera_pose([1.0, 2.0, 1.5], std::f32::consts::FRAC_PI_2, 0.0);
        // Optical +z (forward) must point along map +y, optical +y (down) along map −z.
        let f = pose.transform_point(&Point3::new(0.0, 0.0, 1.0));
        assert!((f - Point3::new(1.0, 3.0, 1.5)).norm() < 1e-5);
        let d = pose.transform_point(&Point3::new(0.0, 1.0, 0.0));
        assert!((d - Point3::new(1.0, 2.0, 0.5)).norm() < 1e-5);
        let r = pose.transform_point(&Point3::new(1.0, 0.0, 0.0));
        assert!((r - Point3::new(2.0, 2.0, 1.5)).norm() < 1e-5);
    }

    #[test]
    fn polyline_is_sampled_evenly() {
        let path = along_polyline(&[[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]], 0.5);
        assert_eq!(path.len(), 16);
        for w in path.windows(2) {
            let d = ((w[1].0[0] - w[0].0[0]).powi(2) + (w[1].0[1] - w[0].0[1]).powi(2)).sqrt();
            assert!(d <= 0.5 + 1e-5);
        }
    }
}
