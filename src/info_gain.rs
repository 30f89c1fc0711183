//! Information gain: how much a voxel's uncertainty would shrink if it were observed again, and the score of
//! a candidate view (where the robot should look next).
//!
//! **The measure.** A voxel's predictive is a Student-t per dimension with scale s² = (λ+1)/λ² · Ψ
//! ([`crate::inference`]). Its entropy is ½ ln s² plus a term of the degrees of freedom alone; the gain is
//! the expected drop of the ½ ln s² part (the log of the D-optimality of the authors' t_var, per dimension)
//! when the voxel receives kernel weight `w` more of observations. New observations are expected to have
//! the spread the voxel already predicts: kernel weight `w` of points adds E\[ΔΨ\] = w · Ψ/λ to the scatter
//! (the batch's own scatter plus its mean's offset from μ, §III-B's update, in expectation). Then
//!
//! ```text
//! s'²/s² = λ(λ+w+1) / ((λ+w)(λ+1))      (Ψ cancels)
//! gain(λ, w) = ½ ln[ (λ+w)(λ+1) / (λ(λ+w+1)) ]   nats per feature dimension
//! ```
//!
//! It depends on λ and w only: a voxel's spread Ψ scales its predictive, not how much a new look shrinks
//! it in ratio. It is positive for w > 0, grows with w (to ½ ln(1 + 1/λ) as w → ∞: even endless looks
//! leave the features' own spread), and falls as λ grows. A voxel with nothing in reach under a flat
//! prior (λ = 0) has an improper predictive whose entropy is infinite: λ is floored at
//! [`UNSEEN_LAMBDA`], a twentieth of a point, so such voxels gain most yet stay comparable. The
//! dimension-only entropy term (digamma of λ) is left out: it is common to all voxels of equal λ and small
//! beside the scale term once λ > 2. Multiply by D for the whole predictive's entropy.
//!
//! **The view score.** A candidate view is the set of voxels its rays are expected to hit, with a point
//! count each (e.g. ray-cast against the geometry known so far). Each hit spreads kernel weight to its
//! f³ neighbourhood exactly as integrating the points would; a target voxel t then receives
//! w_t = Σ_o k(o) · n(t+o) and the score is Σ_t gain(λ_t, w_t), with λ_t = λ₀ + the kernel-weighted count
//! the map already gathers there ([`gathered_count`]). No heap: the hits are a sorted slice, searched.

use crate::kernel::KernelLut;
use crate::key::VoxelKey;
use crate::obs::{GatherError, ObsLookup};

/// The λ an unseen voxel under a flat prior is taken to have (see the module docs).
pub const UNSEEN_LAMBDA: f32 = 0.05;

/// Expected reduction, in nats per feature dimension, of the entropy (scale part) of a voxel's Student-t
/// predictive if it received kernel weight `w` of observations, given its current confidence `lambda`
/// (floored at [`UNSEEN_LAMBDA`]). 0 for `w ≤ 0` or NaN.
#[inline]
pub fn voxel_gain(lambda: f32, w: f32) -> f32 {
    if !(w > 0.0) {
        return 0.0;
    }
    let l = if lambda > UNSEEN_LAMBDA {
        lambda
    } else {
        UNSEEN_LAMBDA
    };
    let ratio = (l + w) * (l + 1.0) / (l * (l + w + 1.0));
    0.5 * core::f32::consts::LN_2 * crate::f32math::log2(ratio)
}

/// The kernel-weighted point count K a gather gives at `target` (its posterior's λ is λ₀ + K), reading
/// counts only.
pub fn gathered_count<const D: usize, const CAP: usize, M: ObsLookup<D> + ?Sized>(
    lut: &KernelLut<CAP>,
    map: &M,
    target: VoxelKey,
) -> Result<f32, GatherError> {
    if !lut.is_voxel_offset() {
        return Err(GatherError::SubVoxelKernel);
    }
    let mut k_sum = 0.0;
    for (&o, &k) in lut.offsets().iter().zip(lut.weights(0)) {
        k_sum += k * map.observed_count(target.offset(o));
    }
    Ok(k_sum)
}

/// Why a view cannot be scored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ScoreError {
    /// The kernel table is in sub-voxel mode (see [`GatherError`]).
    SubVoxelKernel,
    /// The hits are not sorted by key without repeats.
    UnsortedHits,
}

impl core::fmt::Display for ScoreError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::SubVoxelKernel => GatherError::SubVoxelKernel.fmt(f),
            Self::UnsortedHits => {
                f.write_str("view hits must be sorted by voxel key, without repeats")
            }
        }
    }
}

impl core::error::Error for ScoreError {}

fn count_at(hits: &[(VoxelKey, f32)], key: VoxelKey) -> f32 {
    hits.binary_search_by_key(&key, |h| h.0)
        .map_or(0.0, |i| hits[i].1)
}

/// The information-gain score of a candidate view: Σ over every voxel the view's points would reach of
/// [`voxel_gain`]`(λ, w)` (module docs). `hits` are the voxels the view's points are expected to fall
/// in, with the number of points in each, sorted by key without repeats; `prior_lambda` is the map's λ₀.
///
/// Each target is counted once, from the first hit (in key order) in its neighbourhood. Cost: per hit
/// and offset, a neighbourhood of binary searches and one gather of counts — O(H · f⁶ · log H).
pub fn view_score<const D: usize, const CAP: usize, M: ObsLookup<D> + ?Sized>(
    lut: &KernelLut<CAP>,
    map: &M,
    prior_lambda: f32,
    hits: &[(VoxelKey, f32)],
) -> Result<f32, ScoreError> {
    if !lut.is_voxel_offset() {
        return Err(ScoreError::SubVoxelKernel);
    }
    if hits.windows(2).any(|p| p[0].0 >= p[1].0) {
        return Err(ScoreError::UnsortedHits);
    }
    let offsets = lut.offsets();
    let weights = lut.weights(0);
    let mut score = 0.0;
    for (i, &(hit, _)) in hits.iter().enumerate() {
        for &o in offsets {
            let target = hit.offset(o);
            // The hits reaching `target` are target + o′ (the kernel is symmetric); count the target from
            // the first of them only.
            let mut w = 0.0;
            let mut first = true;
            for (&p, &k) in offsets.iter().zip(weights) {
                let source = target.offset(p);
                let n = count_at(hits, source);
                if n > 0.0 {
                    first &= source >= hits[i].0;
                    w += k * n;
                }
            }
            if first {
                let lambda = prior_lambda
                    + gathered_count(lut, map, target).map_err(|_| ScoreError::SubVoxelKernel)?;
                score += voxel_gain(lambda, w);
            }
        }
    }
    Ok(score)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::MapConfig;
    use crate::obs::ObsStats;

    struct List<'a>(&'a [(VoxelKey, ObsStats<1>)]);
    impl ObsLookup<1> for List<'_> {
        fn observed(&self, key: VoxelKey) -> Option<ObsStats<1>> {
            self.0.iter().find(|(k, _)| *k == key).map(|(_, s)| *s)
        }
    }

    fn seen(n: f32) -> ObsStats<1> {
        ObsStats {
            count: n,
            mean: [0.5],
            scatter: [0.1 * n],
        }
    }

    #[test]
    fn hand_worked_gains() {
        // λ = 1, w = 1: ½ ln(2·2 / (1·3)) = ½ ln(4/3).
        assert!((voxel_gain(1.0, 1.0) - 0.5 * libm::logf(4.0 / 3.0)).abs() < 1e-6);
        // λ = 4, w = 2: ½ ln(6·5 / (4·7)).
        assert!((voxel_gain(4.0, 2.0) - 0.5 * libm::logf(30.0 / 28.0)).abs() < 1e-6);
        // Never seen (flat prior): the floor, λ = 0.05, w = 1: ½ ln(1.05·1.05 / (0.05·2.05)).
        let unseen = 0.5 * libm::logf(1.05 * 1.05 / (0.05 * 2.05));
        assert!((voxel_gain(0.0, 1.0) - unseen).abs() < 1e-5);
        // No weight, no gain; NaN weight, none either.
        assert_eq!(voxel_gain(3.0, 0.0), 0.0);
        assert_eq!(voxel_gain(3.0, f32::NAN), 0.0);
    }

    #[test]
    fn a_voxel_never_seen_gains_most_and_gain_falls_as_lambda_grows() {
        for w in [0.1f32, 0.5, 1.0, 4.0, 30.0] {
            let mut prev = voxel_gain(0.0, w);
            assert!(prev > 0.0);
            for lambda in [0.1f32, 0.5, 1.0, 2.0, 5.0, 20.0, 100.0, 1000.0] {
                let g = voxel_gain(lambda, w);
                assert!(g < prev, "w {w}: gain at λ {lambda} = {g} not below {prev}");
                assert!(g > 0.0);
                prev = g;
            }
        }
    }

    #[test]
    fn gain_is_monotone_in_w_and_bounded() {
        for lambda in [0.0f32, 0.3, 1.0, 7.0, 60.0] {
            let mut prev = 0.0;
            for w in [0.01f32, 0.1, 0.4425, 1.0, 3.0, 10.0, 100.0] {
                let g = voxel_gain(lambda, w);
                assert!(g > prev, "λ {lambda}: gain at w {w} = {g} not above {prev}");
                prev = g;
            }
            let l = lambda.max(UNSEEN_LAMBDA);
            assert!(prev < 0.5 * libm::logf(1.0 + 1.0 / l) + 1e-6);
        }
    }

    #[test]
    fn view_score_sums_each_reached_voxel_once() {
        let config = MapConfig::default(); // 0.1 m voxels, ℓ = 0.5, f = 3: 27 offsets
        let lut: KernelLut = KernelLut::new(&config).unwrap();
        let empty = List(&[]);
        // One hit of 2 points on an empty map: 27 targets, each gaining gain(0, 2·k(o)).
        let a = VoxelKey::new(0, 0, 0);
        let one = view_score(&lut, &empty, 0.0, &[(a, 2.0)]).unwrap();
        let by_hand: f32 = lut
            .weights(0)
            .iter()
            .map(|&k| voxel_gain(0.0, 2.0 * k))
            .sum();
        assert!((one - by_hand).abs() < 1e-4 * by_hand);
        // Two adjacent hits: targets in both neighbourhoods receive both weights, counted once.
        let b = VoxelKey::new(1, 0, 0);
        let two = view_score(&lut, &empty, 0.0, &[(a, 2.0), (b, 1.0)]).unwrap();
        let mut by_hand = 0.0;
        for x in -1..=2 {
            for y in -1..=1 {
                for z in -1..=1 {
                    let w = 2.0 * lut.weight_at(0, x, y, z) + lut.weight_at(0, x - 1, y, z);
                    by_hand += voxel_gain(0.0, w);
                }
            }
        }
        assert!((two - by_hand).abs() < 1e-4 * by_hand, "{two} vs {by_hand}");
        // A view of voxels the map has seen scores less, and less again the more it has seen.
        let seen_once = [(a, seen(1.0)), (b, seen(1.0))];
        let seen_often = [(a, seen(50.0)), (b, seen(50.0))];
        let s1 = view_score(&lut, &List(&seen_once), 0.0, &[(a, 2.0), (b, 1.0)]).unwrap();
        let s2 = view_score(&lut, &List(&seen_often), 0.0, &[(a, 2.0), (b, 1.0)]).unwrap();
        assert!(two > s1 && s1 > s2 && s2 > 0.0, "{two} > {s1} > {s2} > 0");
        // Unsorted or repeated hits are refused.
        assert_eq!(
            view_score(&lut, &empty, 0.0, &[(b, 1.0), (a, 1.0)]),
            Err(ScoreError::UnsortedHits)
        );
        assert_eq!(
            view_score(&lut, &empty, 0.0, &[(a, 1.0), (a, 1.0)]),
            Err(ScoreError::UnsortedHits)
        );
        assert_eq!(view_score(&lut, &empty, 0.0, &[]), Ok(0.0));
    }

    #[test]
    fn gathered_count_is_the_posterior_lambda_above_the_prior() {
        let lut: KernelLut = KernelLut::new(&MapConfig::default()).unwrap();
        let a = VoxelKey::new(0, 0, 0);
        let map = [(a, seen(3.0)), (VoxelKey::new(1, 1, 0), seen(2.0))];
        let k = gathered_count(&lut, &List(&map), a).unwrap();
        let post = crate::obs::gather(&lut, &List(&map), a).unwrap();
        assert!((k - post.count).abs() < 1e-5);
        assert!((k - (3.0 + 2.0 * lut.weight_at(0, 1, 1, 0))).abs() < 1e-5);
    }
}
