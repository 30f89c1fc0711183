//! From sensor points to voxel updates: validation, location, grouping, spreading.
//!
//! A batch is integrated in two steps:
//! 1. [`locate`] each map-frame point (both maps): reject non-finite or out-of-range input (counted, never
//!    stored) and find its voxel and sub-cell. Points with the same voxel and sub-cell have identical
//!    kernel weights to every neighbour, so they are grouped.
//! 2. Spread each group to the neighbours in the kernel table: target voxel t receives the group scaled by
//!    k(s → t). The f32 reference map groups into Welford moments ([`crate::VoxelStats::absorb_point`]) and uses
//!    [`spread`]; the on-device map groups the same moments ([`crate::VoxelStats::add_unit_point`], one
//!    division per point) and asks [`KernelLut::weight_at`] per target. Both are exactly the paper's per-point batch sums (Chan's
//!    combination; the equivalence tests check it).
//!
//! Grouping turns "points × f³" into "occupied voxels × f³", the main saving on dense scans.

use crate::kernel::KernelLut;
use crate::key::{KeyError, VoxelKey};

/// Largest accepted |feature component|. Network features (PCA-compressed CLIP/LSeg) are O(1–100); the
/// on-device map stores μ with a per-voxel f16 scale (at most 65504 × 31 ≈ 2·10⁶ with its headroom) and Ψ
/// accumulates squares, so larger values would overflow the codes rather than carry information.
pub const FEATURE_LIMIT: f32 = 1e5;

/// Why one input point was not integrated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Rejection {
    /// Its position has a NaN or infinite coordinate.
    NonFinitePosition,
    /// Its feature has a NaN or infinite component, or one beyond ±[`FEATURE_LIMIT`].
    NonFiniteFeature,
    /// Its position is too far from the map origin for a voxel key.
    KeyOutOfRange,
    /// The map had no room for the voxels it reaches (pool full and the eviction sink refusing, or a map
    /// that was never configured).
    NoRoom,
    /// The point lies outside the local map's window around the robot.
    OutsideWindow,
    /// A batch had more points than features or more features than points: the unpaired ones.
    Unpaired,
}

/// Counts of rejected points, by reason. Every point handed to a map is either integrated or counted here.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RejectionCounts {
    /// Points with a non-finite position.
    pub non_finite_position: u32,
    /// Points with a non-finite feature.
    pub non_finite_feature: u32,
    /// Points beyond the key range.
    pub key_out_of_range: u32,
    /// Points refused for lack of room.
    pub no_room: u32,
    /// Points outside the local map's window.
    pub outside_window: u32,
    /// Points or features without a partner in their batch.
    pub unpaired: u32,
}

impl RejectionCounts {
    /// Count one rejection.
    pub fn count(&mut self, r: Rejection) {
        let c = match r {
            Rejection::NonFinitePosition => &mut self.non_finite_position,
            Rejection::NonFiniteFeature => &mut self.non_finite_feature,
            Rejection::KeyOutOfRange => &mut self.key_out_of_range,
            Rejection::NoRoom => &mut self.no_room,
            Rejection::OutsideWindow => &mut self.outside_window,
            Rejection::Unpaired => &mut self.unpaired,
        };
        *c = c.saturating_add(1);
    }

    /// All rejections.
    pub fn total(&self) -> u32 {
        self.non_finite_position
            .saturating_add(self.non_finite_feature)
            .saturating_add(self.key_out_of_range)
            .saturating_add(self.no_room)
            .saturating_add(self.outside_window)
            .saturating_add(self.unpaired)
    }
}

/// Validate a map-frame point and find its voxel and sub-cell.
pub fn locate<const D: usize, const CAP: usize>(
    lut: &KernelLut<CAP>,
    position: [f32; 3],
    feature: &[f32; D],
) -> Result<(VoxelKey, u16), Rejection> {
    let key = VoxelKey::from_position(position, lut.inv_voxel_size()).map_err(|e| match e {
        KeyError::NonFinite => Rejection::NonFinitePosition,
        KeyError::OutOfRange => Rejection::KeyOutOfRange,
    })?;
    if !feature_in_range(feature) {
        return Err(Rejection::NonFiniteFeature);
    }
    Ok((key, lut.cell_of(position, key)))
}

/// Whether every component is finite and within ±[`FEATURE_LIMIT`].
///
/// On the bit patterns, branch-free: |v| ≤ limit ⟺ (bits & 0x7FFF_FFFF) ≤ bits(limit) for finite v, and
/// infinities and NaNs have larger magnitude bits. `limit − magnitude` goes negative (top bit set) exactly
/// for the bad components, so one OR over all of them answers: 4 integer instructions per component on a
/// Cortex-M4 and vectorised on a host, where a per-component float compare-and-branch costs 6.
#[inline]
pub fn feature_in_range<const D: usize>(feature: &[f32; D]) -> bool {
    const LIMIT_BITS: u32 = FEATURE_LIMIT.to_bits();
    let over = feature.iter().fold(0u32, |acc, v| {
        acc | LIMIT_BITS.wrapping_sub(v.to_bits() & 0x7FFF_FFFF)
    });
    over >> 31 == 0
}

/// Call `apply(target, k)` for every neighbour `target` of a group of points in `source`/`cell` that the
/// kernel reaches with weight `k > 0`. The caller absorbs the group: `target.absorb_scaled(k, group)`.
#[inline]
pub fn spread<const CAP: usize>(
    lut: &KernelLut<CAP>,
    source: VoxelKey,
    cell: u16,
    mut apply: impl FnMut(VoxelKey, f32),
) {
    for (&o, &k) in lut.offsets().iter().zip(lut.weights(cell)) {
        if k > 0.0 {
            apply(source.offset(o), k);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::MapConfig;

    #[test]
    fn locate_rejects_bad_points() {
        let lut: KernelLut = KernelLut::new(&MapConfig::default()).unwrap();
        let f = [0.0f32; 4];
        assert_eq!(
            locate(&lut, [f32::NAN, 0.0, 0.0], &f),
            Err(Rejection::NonFinitePosition)
        );
        assert_eq!(
            locate(&lut, [1e9, 0.0, 0.0], &f),
            Err(Rejection::KeyOutOfRange)
        );
        assert_eq!(
            locate(&lut, [0.0; 3], &[0.0, f32::INFINITY, 0.0, 0.0]),
            Err(Rejection::NonFiniteFeature)
        );
        assert_eq!(
            locate(&lut, [0.15, -0.05, 0.0], &f),
            Ok((VoxelKey::new(1, -1, 0), 0))
        );
        let mut c = RejectionCounts::default();
        c.count(Rejection::NonFiniteFeature);
        c.count(Rejection::NoRoom);
        assert_eq!((c.non_finite_feature, c.no_room, c.total()), (1, 1, 2));
    }

    #[test]
    fn feature_range_check_on_bit_patterns() {
        let ok = |v: f32| feature_in_range(&[0.0, v, -1.0]);
        for v in [
            0.0,
            -0.0,
            1.0,
            -3.5,
            FEATURE_LIMIT,
            -FEATURE_LIMIT,
            f32::MIN_POSITIVE,
            1e-45,
        ] {
            assert!(ok(v), "{v}");
        }
        let above = f32::from_bits(FEATURE_LIMIT.to_bits() + 1);
        for v in [
            above,
            -above,
            1e6,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            -f32::NAN,
            f32::MAX,
        ] {
            assert!(!ok(v), "{v}");
        }
        // The same answer as the plain float comparison, over many bit patterns.
        let mut x = 0x1234_5678u32;
        for _ in 0..100_000 {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            let v = f32::from_bits(x);
            assert_eq!(ok(v), libm::fabsf(v) <= FEATURE_LIMIT, "{v:e}");
        }
    }

    #[test]
    fn spread_reaches_the_filter_cube() {
        let lut: KernelLut = KernelLut::new(&MapConfig::default()).unwrap();
        let mut seen = heapless::Vec::<(VoxelKey, f32), 27>::new();
        spread(&lut, VoxelKey::new(5, 5, 5), 0, |t, k| {
            seen.push((t, k)).unwrap()
        });
        assert_eq!(seen.len(), 27);
        assert!(seen
            .iter()
            .all(|(t, _)| t.distance_squared(VoxelKey::new(5, 5, 5)) <= 3));
        assert!(seen.contains(&(VoxelKey::new(5, 5, 5), 1.0)));
    }
}
