//! Sensor models: what a robot's sensors return from a pose.
//!
//! - [`RangeLidar`]: re-measures a known point cloud (the LiDAR tile): points within range, subsampled to a
//!   per-frame budget, Gaussian range noise along each ray.
//! - [`DepthCamera`]: a pinhole depth camera ray-cast into a [`RayScene`], with the VLMap protocol's depth
//!   limits (0.1–6 m) and random pixel subsampling (VLMap and the paper keep 1 % of the pixels).
//! - [`MultizoneTof`]: a multizone time-of-flight sensor (8 × 8 zones over 45°, like the ST VL53L8): one
//!   ray per zone centre, a few metres of range. This is what a small robot with a microcontroller carries.

use super::LabelledPoint;
use latentbki::nalgebra::{Isometry3, Point3, Vector3};
use rand::Rng;
use rand_distr::{Distribution, Normal};

/// A scene that rays can be cast into.
pub trait RayScene {
    /// The nearest surface hit by the ray `origin + t·dir` (dir unit length) with `t ≤ max_t`: distance
    /// along the ray, class and instance.
    fn cast(&self, origin: [f32; 3], dir: [f32; 3], max_t: f32) -> Option<(f32, u16, u32)>;
}

/// A range-limited LiDAR that re-measures a given point cloud.
#[derive(Clone, Copy, Debug)]
pub struct RangeLidar {
    /// Maximum range, metres.
    pub range_m: f32,
    /// Points kept per frame (random subset of those in range); the sparsity knob.
    pub points_per_frame: usize,
    /// Standard deviation of the range noise, metres.
    pub range_noise_m: f32,
}

impl Default for RangeLidar {
    fn default() -> Self {
        Self {
            range_m: 10.0,
            points_per_frame: 3000,
            range_noise_m: 0.02,
        }
    }
}

impl RangeLidar {
    /// One frame from `pose`: the returned points are in the map frame.
    pub fn scan<R: Rng>(
        &self,
        cloud: &[[f32; 3]],
        classes: &[u16],
        instances: &[u32],
        pose: &Isometry3<f32>,
        rng: &mut R,
    ) -> Vec<LabelledPoint> {
        let s = pose.translation.vector;
        let r2 = self.range_m * self.range_m;
        let mut visible: Vec<usize> = (0..cloud.len())
            .filter(|&i| {
                let p = cloud[i];
                let d = [p[0] - s.x, p[1] - s.y, p[2] - s.z];
                d[0] * d[0] + d[1] * d[1] + d[2] * d[2] <= r2
            })
            .collect();
        // Partial Fisher–Yates: a uniform random subset of the budget's size.
        let keep = self.points_per_frame.min(visible.len());
        for i in 0..keep {
            let j = rng.random_range(i..visible.len());
            visible.swap(i, j);
        }
        visible.truncate(keep);
        visible.sort_unstable();
        let noise = Normal::new(0.0f32, self.range_noise_m.max(0.0)).expect("finite sigma");
        visible
            .into_iter()
            .map(|i| {
                let p = cloud[i];
                let d = Vector3::new(p[0] - s.x, p[1] - s.y, p[2] - s.z);
                let r = d.norm();
                let q = if r > 0.0 {
                    let e = noise.sample(rng);
                    s + d * ((r + e) / r)
                } else {
                    s
                };
                LabelledPoint {
                    position: [q.x, q.y, q.z],
                    class: classes[i],
                    instance: instances[i],
                }
            })
            .collect()
    }
}

/// A pinhole depth camera (optical frame: x right, y down, z forward).
#[derive(Clone, Copy, Debug)]
pub struct DepthCamera {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Horizontal field of view, degrees.
    pub hfov_deg: f32,
    /// Depths below this are discarded, metres.
    pub min_depth: f32,
    /// Depths above this are discarded, metres.
    pub max_depth: f32,
    /// Pixels kept per frame (random subset); the sparsity knob.
    pub pixels_per_frame: usize,
}

impl Default for DepthCamera {
    /// 640 × 480, 70° wide, 0.1–6 m, 1 % of the pixels (the VLMap / LatentBKI protocol).
    fn default() -> Self {
        Self {
            width: 640,
            height: 480,
            hfov_deg: 70.0,
            min_depth: 0.1,
            max_depth: 6.0,
            pixels_per_frame: 3072,
        }
    }
}

impl DepthCamera {
    /// Cast the rays of a random subset of pixels; returns map-frame points within the depth limits.
    pub fn capture<S: RayScene + ?Sized, R: Rng>(
        &self,
        scene: &S,
        pose: &Isometry3<f32>,
        rng: &mut R,
    ) -> Vec<LabelledPoint> {
        let n_pix = (self.width * self.height) as usize;
        let keep = self.pixels_per_frame.min(n_pix);
        // Floyd's algorithm would avoid the allocation; a sorted set of sampled pixel indices is simpler.
        let mut chosen = std::collections::BTreeSet::new();
        while chosen.len() < keep {
            chosen.insert(rng.random_range(0..n_pix));
        }
        let fx = self.width as f32 / 2.0 / (self.hfov_deg.to_radians() / 2.0).tan();
        let (cx, cy) = (self.width as f32 / 2.0, self.height as f32 / 2.0);
        let mut out = Vec::with_capacity(keep);
        for idx in chosen {
            let u = (idx % self.width as usize) as f32 + 0.5;
            let v = (idx / self.width as usize) as f32 + 0.5;
            let ray = Vector3::new((u - cx) / fx, (v - cy) / fx, 1.0);
            if let Some(p) = cast_depth(scene, pose, ray, self.min_depth, self.max_depth) {
                out.push(p);
            }
        }
        out
    }
}

/// Cast an optical-frame ray (z component 1: its length scales depth to range) and keep hits whose depth
/// (optical z) is within limits.
fn cast_depth<S: RayScene + ?Sized>(
    scene: &S,
    pose: &Isometry3<f32>,
    ray: Vector3<f32>,
    min_depth: f32,
    max_depth: f32,
) -> Option<LabelledPoint> {
    let len = ray.norm();
    let dir = pose.rotation * (ray / len);
    let o = pose.translation.vector;
    let (t, class, instance) =
        scene.cast([o.x, o.y, o.z], [dir.x, dir.y, dir.z], max_depth * len)?;
    let depth = t / len;
    if depth < min_depth || depth > max_depth {
        return None;
    }
    let p = Point3::from(o + dir * t);
    Some(LabelledPoint {
        position: [p.x, p.y, p.z],
        class,
        instance,
    })
}

/// A multizone time-of-flight sensor: one distance per zone of a square grid.
#[derive(Clone, Copy, Debug)]
pub struct MultizoneTof {
    /// Zones per side (8 gives 64 zones).
    pub zones: u32,
    /// Diagonal-free field of view per side, degrees.
    pub fov_deg: f32,
    /// Maximum range, metres.
    pub max_range: f32,
}

impl Default for MultizoneTof {
    /// 8 × 8 zones over 45°, up to 4 m.
    fn default() -> Self {
        Self {
            zones: 8,
            fov_deg: 45.0,
            max_range: 4.0,
        }
    }
}

impl MultizoneTof {
    /// One frame: the hit of each zone's centre ray (zones with no return within range give nothing).
    pub fn capture<S: RayScene + ?Sized>(
        &self,
        scene: &S,
        pose: &Isometry3<f32>,
    ) -> Vec<LabelledPoint> {
        let half = (self.fov_deg.to_radians() / 2.0).tan();
        let n = self.zones.max(1);
        let mut out = Vec::new();
        for j in 0..n {
            for i in 0..n {
                let x = ((i as f32 + 0.5) / n as f32 * 2.0 - 1.0) * half;
                let y = ((j as f32 + 0.5) / n as f32 * 2.0 - 1.0) * half;
                if let Some(p) =
                    cast_depth(scene, pose, Vector3::new(x, y, 1.0), 0.02, self.max_range)
                {
                    out.push(p);
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::trajectory::camera_pose;
    use rand_xoshiro::rand_core::SeedableRng;
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// A wall at x = 3 (class 1) and nothing else.
    struct Wall;
    impl RayScene for Wall {
        fn cast(&self, o: [f32; 3], d: [f32; 3], max_t: f32) -> Option<(f32, u16, u32)> {
            (d[0] > 0.0)
                .then(|| (3.0 - o[0]) / d[0])
                .filter(|&t| t > 0.0 && t <= max_t)
                .map(|t| (t, 1, 7))
        }
    }

    #[test]
    fn depth_camera_sees_the_wall_within_limits() {
        let cam = DepthCamera {
            pixels_per_frame: 500,
            ..DepthCamera::default()
        };
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(3);
        let pose = camera_pose([0.0, 0.0, 1.0], 0.0, 0.0);
        let pts = cam.capture(&Wall, &pose, &mut rng);
        assert_eq!(pts.len(), 500, "every pixel sees the wall at 3 m");
        assert!(pts
            .iter()
            .all(|p| (p.position[0] - 3.0).abs() < 1e-4 && p.class == 1));
        // Beyond the 6 m depth limit nothing is returned.
        let far = camera_pose([-4.0, 0.0, 1.0], 0.0, 0.0);
        assert!(cam.capture(&Wall, &far, &mut rng).is_empty());
        // Facing away, nothing either.
        let away = camera_pose([0.0, 0.0, 1.0], std::f32::consts::PI, 0.0);
        assert!(cam.capture(&Wall, &away, &mut rng).is_empty());
    }

    #[test]
    fn tof_returns_one_point_per_zone() {
        let tof = MultizoneTof::default();
        let pose = camera_pose([1.0, 0.0, 1.0], 0.0, 0.0);
        let pts = tof.capture(&Wall, &pose);
        assert_eq!(pts.len(), 64);
        let far = camera_pose([-2.0, 0.0, 1.0], 0.0, 0.0);
        assert!(
            tof.capture(&Wall, &far).is_empty(),
            "5 m is beyond 4 m range"
        );
    }

    #[test]
    fn lidar_keeps_the_budget_within_range() {
        let cloud: Vec<[f32; 3]> = (0..1000).map(|i| [i as f32 * 0.02, 0.0, 0.0]).collect();
        let classes = vec![0u16; 1000];
        let inst = vec![0u32; 1000];
        let lidar = RangeLidar {
            range_m: 5.0,
            points_per_frame: 100,
            range_noise_m: 0.0,
        };
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
        let pose = crate::sim::trajectory::level_pose([0.0, 0.0, 0.0], 0.0);
        let pts = lidar.scan(&cloud, &classes, &inst, &pose, &mut rng);
        assert_eq!(pts.len(), 100);
        assert!(pts.iter().all(|p| p.position[0] <= 5.0));
        let mut xs: Vec<i64> = pts
            .iter()
            .map(|p| (p.position[0] * 50.0).round() as i64)
            .collect();
        xs.dedup();
        assert_eq!(xs.len(), 100, "a subset, without repeats");
    }
}
