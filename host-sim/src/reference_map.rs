//! The f32 reference map: the paper's batch update, voxel for voxel, with no capacity limit or quantization.
//!
//! It is the ground truth every other map is measured against (the quantized on-device map, the base
//! station's global map). It uses the core's kernel table, locate/spread and update — no second copy of the
//! math — and computes each batch literally as the paper does: per voxel, the kernel-weighted moments
//! (k̄, ȳ, S̄) of the whole batch first, then one posterior update. Iteration is ordered (BTreeMap), so the
//! same input gives bit-identical output.

use latentbki::nalgebra::Isometry3;
use latentbki::{
    batch::locate, batch::spread, kernel::KernelLut, key::to_map_frame, key::VoxelKey,
    stats::VoxelStats, ConfigError, MapConfig, RejectionCounts,
};
use std::collections::{BTreeMap, HashMap};

/// Kernel table capacity on the host: any filter size with up to 4³ sub-cells.
pub const HOST_LUT_CAP: usize = 64 * latentbki::kernel::MAX_NEIGHBOURS;

/// An unbounded f32 LatentBKI map.
pub struct ReferenceMap<const D: usize> {
    config: MapConfig,
    lut: Box<KernelLut<HOST_LUT_CAP>>,
    prior: VoxelStats<D>,
    voxels: HashMap<VoxelKey, VoxelStats<D>>,
    rejections: RejectionCounts,
    kernel_mass: f64,
    points: u64,
}

impl<const D: usize> ReferenceMap<D> {
    /// An empty map.
    pub fn new(config: MapConfig) -> Result<Self, ConfigError> {
        Ok(Self {
            lut: Box::new(KernelLut::new(&config)?),
            prior: VoxelStats::from_prior(&config.prior()),
            config,
            voxels: HashMap::new(),
            rejections: RejectionCounts::default(),
            kernel_mass: 0.0,
            points: 0,
        })
    }

    /// Integrate one batch of sensor-frame points with their features, seen from `pose` (sensor → map).
    /// Returns how many points were integrated; the others are counted in [`Self::rejections`].
    pub fn integrate(
        &mut self,
        pose: &Isometry3<f32>,
        points: &[[f32; 3]],
        features: &[[f32; D]],
    ) -> usize {
        // 1. Group points by voxel and sub-cell (identical kernel weights within a group).
        let mut groups: BTreeMap<(VoxelKey, u16), VoxelStats<D>> = BTreeMap::new();
        let mut accepted = 0;
        for (p, y) in points.iter().zip(features) {
            match locate(&self.lut, to_map_frame(pose, *p), y) {
                Ok(at) => {
                    groups
                        .entry(at)
                        .or_insert(VoxelStats::EMPTY)
                        .absorb_point(1.0, y);
                    accepted += 1;
                }
                Err(r) => self.rejections.count(r),
            }
        }
        // 2. Per target voxel, the batch moments k̄, ȳ, S̄ over all points in reach.
        let mut batch: BTreeMap<VoxelKey, VoxelStats<D>> = BTreeMap::new();
        for (&(source, cell), group) in &groups {
            spread(&self.lut, source, cell, |target, k| {
                batch
                    .entry(target)
                    .or_insert(VoxelStats::EMPTY)
                    .absorb_scaled(k, group);
            });
        }
        // 3. One posterior update per voxel.
        for (target, moments) in &batch {
            self.kernel_mass += f64::from(moments.lambda);
            self.voxels
                .entry(*target)
                .or_insert(self.prior)
                .absorb(moments);
        }
        self.points += accepted as u64;
        accepted
    }

    /// The map's configuration.
    pub fn config(&self) -> &MapConfig {
        &self.config
    }
    /// The prior of an unobserved voxel.
    pub fn prior(&self) -> &VoxelStats<D> {
        &self.prior
    }
    /// The posterior of a voxel, if any point has reached it.
    pub fn get(&self, key: &VoxelKey) -> Option<&VoxelStats<D>> {
        self.voxels.get(key)
    }
    /// All observed voxels (unordered).
    pub fn voxels(&self) -> &HashMap<VoxelKey, VoxelStats<D>> {
        &self.voxels
    }
    /// Observed voxels sorted by key.
    pub fn sorted(&self) -> Vec<(VoxelKey, &VoxelStats<D>)> {
        let mut v: Vec<_> = self.voxels.iter().map(|(k, s)| (*k, s)).collect();
        v.sort_by_key(|(k, _)| *k);
        v
    }
    /// Number of observed voxels.
    pub fn len(&self) -> usize {
        self.voxels.len()
    }
    /// Whether no voxel has been observed.
    pub fn is_empty(&self) -> bool {
        self.voxels.is_empty()
    }
    /// Points refused so far, by reason.
    pub fn rejections(&self) -> RejectionCounts {
        self.rejections
    }
    /// Total kernel mass Σ k̄ applied so far (equals Σ (λ − λ₀) over voxels).
    pub fn kernel_mass(&self) -> f64 {
        self.kernel_mass
    }
    /// Points integrated so far.
    pub fn points(&self) -> u64 {
        self.points
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use latentbki::{KernelMode, Prior};

    fn cfg(mode: KernelMode) -> MapConfig {
        MapConfig::new(0.1, 0.5, 3, Prior::default(), mode).unwrap()
    }

    #[test]
    fn one_point_touches_the_filter_cube_with_kernel_weights() {
        let mut map = ReferenceMap::<2>::new(cfg(KernelMode::VoxelOffset)).unwrap();
        let n = map.integrate(&Isometry3::identity(), &[[0.05, 0.05, 0.05]], &[[1.0, 2.0]]);
        assert_eq!((n, map.len()), (1, 27));
        let own = map.get(&VoxelKey::new(0, 0, 0)).unwrap();
        assert_eq!((own.lambda, own.mean), (1.0, [1.0, 2.0]));
        let corner = map.get(&VoxelKey::new(1, -1, 1)).unwrap();
        assert!((corner.lambda - 0.4425).abs() < 1e-4);
        assert!(
            (map.kernel_mass() - map.voxels().values().map(|v| v.lambda as f64).sum::<f64>()).abs()
                < 1e-4
        );
    }

    #[test]
    fn bad_points_are_counted_and_never_stored() {
        let mut map = ReferenceMap::<2>::new(cfg(KernelMode::VoxelOffset)).unwrap();
        let pts = [
            [f32::NAN, 0.0, 0.0],
            [0.0, 0.0, 0.0],
            [1e12, 0.0, 0.0],
            [0.0, 0.0, 0.0],
        ];
        let feats = [[0.0, 0.0], [f32::INFINITY, 0.0], [0.0, 0.0], [3.0, 4.0]];
        assert_eq!(map.integrate(&Isometry3::identity(), &pts, &feats), 1);
        let r = map.rejections();
        assert_eq!(
            (
                r.non_finite_position,
                r.non_finite_feature,
                r.key_out_of_range
            ),
            (1, 1, 1)
        );
        assert!(map.voxels().values().all(|v| v.is_finite()));
        assert_eq!(map.get(&VoxelKey::new(0, 0, 0)).unwrap().mean, [3.0, 4.0]);
    }

    #[test]
    fn subvoxel_mode_weighs_by_position_inside_the_voxel() {
        let mut map = ReferenceMap::<1>::new(cfg(KernelMode::SubVoxel { cells: 4 })).unwrap();
        map.integrate(&Isometry3::identity(), &[[0.01, 0.05, 0.05]], &[[1.0]]);
        let left = map.get(&VoxelKey::new(-1, 0, 0)).unwrap().lambda;
        let right = map.get(&VoxelKey::new(1, 0, 0)).unwrap().lambda;
        assert!(
            left > right,
            "a point near the -x face weighs more on the -x neighbour"
        );
    }
}
