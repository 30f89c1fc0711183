//! From sensor points to voxel updates: validation, location, grouping, spreading.
//!
//! A batch is integrated in two steps:
//! 1. [`locate`] each map-frame point (both maps): reject non-finite or out-of-range input (counted, never
//!    stored) and find its voxel and sub-cell. Points with the same voxel and sub-cell have identical
//!    kernel weights to every neighbour, so they are grouped.
//! 2. Either spread each group to the neighbours in the kernel table — target voxel t receives the group
//!    scaled by k(s → t): the host's reference map does this with Welford moments
//!    ([`crate::stats::VoxelStats::absorb_point`]) and [`spread`], the paper's update taken literally — or keep
//!    each voxel's own observation statistics and gather them through the kernel when a posterior is asked
//!    ([`crate::obs`]: the on-device map and the host's fast map). Both are exactly the paper's per-point
//!    batch sums (Chan's combination; the equivalence tests check it).

use crate::kernel::KernelLut;
use crate::key::{KeyError, VoxelKey};

/// Largest accepted feature norm ‖y‖₂ (so every component is within ±this too). Network features
/// (PCA-compressed CLIP/LSeg) are O(1–100); the on-device map stores m with a per-voxel f16 scale (at most
/// 65504 × 63 ≈ 4·10⁶ with its headroom) and S accumulates squares, so larger values would overflow the
/// codes rather than carry information.
pub const FEATURE_LIMIT: f32 = 1e5;

/// Why one input point was not integrated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum Rejection {
    /// Its position has a NaN or infinite coordinate.
    NonFinitePosition,
    /// Its feature has a NaN or infinite component, or a norm beyond [`FEATURE_LIMIT`].
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
    /// An int8 feature with a code outside ±[`crate::obs::CODE_MAX`] (i.e. −128).
    CodeOutOfRange,
    /// An int8 feature given to a map without a valid int8 scale (none set, NaN, infinite, 0, negative,
    /// or so large that a feature could exceed [`FEATURE_LIMIT`]).
    FeatureScale,
}

impl core::fmt::Display for Rejection {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::NonFinitePosition => "point refused: a coordinate is NaN or infinite",
            Self::NonFiniteFeature => "point refused: its feature is not finite or too large",
            Self::KeyOutOfRange => "point refused: too far from the map origin",
            Self::NoRoom => {
                "point refused: no room in the map (full, and the link takes no eviction)"
            }
            Self::OutsideWindow => "point refused: outside the map's window around the robot",
            Self::Unpaired => {
                "point refused: a point without a feature or a feature without a point"
            }
            Self::CodeOutOfRange => "point refused: an int8 code of -128",
            Self::FeatureScale => {
                "point refused: int8 feature without a valid int8 scale in the setup"
            }
        })
    }
}

impl core::error::Error for Rejection {}

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
    /// int8 features with a code outside ±127.
    pub code_out_of_range: u32,
    /// int8 features refused for want of a valid scale.
    pub feature_scale: u32,
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
            Rejection::CodeOutOfRange => &mut self.code_out_of_range,
            Rejection::FeatureScale => &mut self.feature_scale,
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
            .saturating_add(self.code_out_of_range)
            .saturating_add(self.feature_scale)
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

/// Validate a map-frame position and find its voxel (for features checked elsewhere, e.g. int8 codes).
#[inline]
pub fn locate_key<const CAP: usize>(
    lut: &KernelLut<CAP>,
    position: [f32; 3],
) -> Result<VoxelKey, Rejection> {
    VoxelKey::from_position(position, lut.inv_voxel_size()).map_err(|e| match e {
        KeyError::NonFinite => Rejection::NonFinitePosition,
        KeyError::OutOfRange => Rejection::KeyOutOfRange,
    })
}

/// Whether every component is finite and the feature's norm is at most [`FEATURE_LIMIT`].
///
/// One pass of squares: a NaN or an infinity makes the sum NaN or infinite, which fails the comparison, and
/// a component beyond ±limit makes it exceed limit². Two instructions per component on a Cortex-M4 (load,
/// multiply-add; the bit-pattern test of each component this replaced took four), and eight independent
/// sums so a host vectorises it. Slightly stricter than a per-component bound: a feature whose components
/// are all within ±limit but whose norm is not is refused too, far beyond any real feature.
#[inline]
pub fn feature_in_range<const D: usize>(feature: &[f32; D]) -> bool {
    let mut sums = [0.0f32; 8];
    let chunks = feature.chunks_exact(8);
    for (s, v) in sums.iter_mut().zip(chunks.remainder()) {
        *s = v * v;
    }
    for c in chunks {
        for (s, v) in sums.iter_mut().zip(c) {
            *s += v * v;
        }
    }
    let total =
        ((sums[0] + sums[1]) + (sums[2] + sums[3])) + ((sums[4] + sums[5]) + (sums[6] + sums[7]));
    total <= FEATURE_LIMIT * FEATURE_LIMIT
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
    fn feature_range_check_refuses_non_finite_and_large_features() {
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
        // The same answer as the norm computed in f64, over many bit patterns (away from the boundary,
        // where f32 rounding of the sum decides).
        let mut x = 0x1234_5678u32;
        for _ in 0..100_000 {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            let v = f32::from_bits(x);
            let norm = (f64::from(v) * f64::from(v) + 1.0).sqrt();
            if (norm / f64::from(FEATURE_LIMIT) - 1.0).abs() > 1e-6 || !v.is_finite() {
                assert_eq!(ok(v), norm <= f64::from(FEATURE_LIMIT), "{v:e}");
            }
        }
        // A feature of 64 components each within the limit but of a larger norm is refused.
        assert!(!feature_in_range(&[FEATURE_LIMIT * 0.5; 64]));
        assert!(feature_in_range(&[FEATURE_LIMIT / 8.0; 64]));
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
