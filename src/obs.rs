//! Per-voxel observation statistics, and the kernel gather that turns them into posteriors.
//!
//! Why store observations instead of posteriors: the NIW update is conjugate (applying batches one after
//! another equals applying their union once) and the voxel-offset kernel depends only on the offset between
//! two voxels. So after any sequence of batches a voxel's posterior is a function of the kernel-weighted
//! observation statistics of its f³ neighbourhood alone. With o over the kernel offsets, n, m, S a voxel's
//! own point count, mean and scatter Σ(y − m)²:
//!
//! ```text
//! K  = Σ_o k(o)·n(t−o)
//! ȳ  = Σ_o k(o)·n(t−o)·m(t−o) / K
//! S̄  = Σ_o k(o)·[ S(t−o) + n(t−o)·(m(t−o) − ȳ)² ]
//! λ = λ₀ + K,   μ = (λ₀μ₀ + K·ȳ)/λ,   Ψ = Ψ₀ + S̄ + (λ₀K/λ)·(ȳ − μ₀)²
//! ```
//!
//! A point then touches one voxel, not f³; the statistics of two sets of points merge exactly and in any
//! order (Chan et al.'s pairwise formula, [`ObsStats::merge_scaled`]), so evictions, revisits, several robots
//! and base stations add up exactly. The merge never forms raw sums Σy², so it stays accurate for features
//! far from zero (mean 100, spread 0.01: see the tests), where Σy² − nȳ² cancels to nothing in f32.
//!
//! The sub-voxel kernel weighs a point by its position inside its voxel, which per-voxel statistics no
//! longer know: [`gather`] refuses such tables ([`KernelLut::is_voxel_offset`]); the host's reference map
//! keeps that mode exact.

use crate::config::Prior;
use crate::kernel::KernelLut;
use crate::key::VoxelKey;
use crate::stats::{combine, update_dim_point, VoxelStats};

mod code_range;
mod code_sums;
// The core's only `unsafe` code: the DSP instructions of the int8 sums (the module says why).
#[cfg(any(latentbki_dsp, test))]
#[allow(unsafe_code)]
mod dsp;
pub use code_range::code_in_range;
pub(crate) use code_sums::scatter_numerator;
pub use code_sums::{CodeSums, CODE_MAX, CODE_SUMS_MAX_COUNT};

/// What was observed in one voxel: the (weighted) point count n, the mean m and the diagonal scatter
/// S = Σ(y − m)² of the features. Also the kernel-weighted moments of a neighbourhood (K, ȳ, S̄).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ObsStats<const D: usize> {
    /// n: the number of points (a kernel-weighted count after a gather). Exact as an integer up to 2²⁴.
    pub count: f32,
    /// m: the mean feature.
    pub mean: [f32; D],
    /// S: Σ (y − m)² per dimension.
    pub scatter: [f32; D],
}

impl<const D: usize> Default for ObsStats<D> {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl<const D: usize> ObsStats<D> {
    /// Nothing observed: the identity of every merge.
    pub const EMPTY: Self = Self {
        count: 0.0,
        mean: [0.0; D],
        scatter: [0.0; D],
    };

    /// Whether nothing has been observed (n ≤ 0).
    #[inline]
    pub fn is_empty(&self) -> bool {
        !(self.count > 0.0)
    }

    /// Add one point (Welford's update: one division per point, never a raw Σy²). The merge of a single
    /// point (n = 1, S = 0), written without the zero scatter: on a Cortex-M4 that saves two of eleven
    /// instructions per dimension on the device's per-point path.
    #[inline]
    pub fn add_point(&mut self, y: &[f32; D]) {
        self.count += 1.0;
        let gain = 1.0 / self.count; // 1/n
        let cross = (self.count - 1.0) * gain; // (n−1)/n
        for i in 0..D {
            update_dim_point(&mut self.mean[i], &mut self.scatter[i], gain, cross, y[i]);
        }
    }

    /// Start afresh with `y` alone (n = 1, m = y, S = 0): what [`Self::add_point`] makes of an empty set
    /// (equal to it, the sign of a zero mean aside), written without reading the old values. So a reused
    /// hot entry of the local map is reset by its count alone, and its first point is a copy instead of a
    /// 516-byte clear and a Welford step (on a sparse sensor most hot entries take one point).
    #[inline]
    pub fn set_point(&mut self, y: &[f32; D]) {
        self.count = 1.0;
        // Where an FPU makes the f32 path the fast one: eight values at a time, which a Cortex-M4 moves
        // with one `ldm` and one `stm` of four registers per half (the zeros from a block the optimiser may
        // not see through, so it is not turned back into a `memset` call). The whole-array writes became
        // `__aeabi_memcpy4` and `__aeabi_memclr4` calls of a word per ≈ 3.5 and 1.8 instructions: ≈ 340 a
        // first point against ≈ 90 (`bash boards/profile-scenario.sh 6`, scanning LiDAR, M4F f32:
        // 49,161 first points). Plain elsewhere (flash; there the f32 path is soft float whatever).
        #[cfg(not(latentbki_soft_float))]
        {
            let zero = core::hint::black_box([0.0f32; 8]);
            let (m8s, m_rest) = self.mean.as_chunks_mut::<8>();
            let (s8s, s_rest) = self.scatter.as_chunks_mut::<8>();
            let (y8s, y_rest) = y.as_chunks::<8>();
            for ((m, s), y) in m8s.iter_mut().zip(s8s.iter_mut()).zip(y8s) {
                *m = *y;
                *s = zero;
            }
            m_rest.copy_from_slice(y_rest);
            s_rest.fill(0.0);
        }
        #[cfg(latentbki_soft_float)]
        {
            self.mean = *y;
            self.scatter = [0.0; D];
        }
    }

    /// Merge another set of observations whose weights (count and scatter) are multiplied by `k`: the set
    /// seen through one kernel weight. `k · other.count ≤ 0` (or NaN) changes nothing.
    #[inline]
    pub fn merge_scaled(&mut self, k: f32, other: &Self) {
        combine(
            (&mut self.count, &mut self.mean, &mut self.scatter),
            k,
            (other.count, &other.mean, &other.scatter),
        );
    }

    /// Merge another set of observations (Chan's pairwise formula: exact, order-free up to rounding).
    #[inline]
    pub fn merge(&mut self, other: &Self) {
        self.merge_scaled(1.0, other);
    }

    /// Merge observations kept as int8 code sums of scale `scale` ([`CodeSums`]): the same merge as
    /// [`Self::merge`] of `sums.to_obs(scale)`, one dimension at a time (no 516-byte temporary).
    pub fn merge_codes(&mut self, sums: &CodeSums<D>, scale: f32) {
        if sums.count == 0 {
            return;
        }
        let k_bar = sums.count as f32;
        let inv_n = 1.0 / k_bar;
        let scale2_over_n = scale * scale * inv_n;
        let total = self.count + k_bar;
        let gain = k_bar / total;
        let cross = self.count * gain;
        sums.for_each_dim(|i, sum, sq| {
            if let (Some(mean), Some(scatter)) = (self.mean.get_mut(i), self.scatter.get_mut(i)) {
                let y_bar = scale * (sum as f32 * inv_n);
                let s_bar = scatter_numerator(sums.count, sum, sq) as f32 * scale2_over_n;
                crate::stats::update_dim(mean, scatter, gain, cross, y_bar, s_bar);
            }
        });
        self.count = total;
    }

    /// The posterior of a voxel whose (gathered) observations these are, under `prior`.
    pub fn posterior(&self, prior: &Prior) -> VoxelStats<D> {
        let mut post = VoxelStats::from_prior(prior);
        post.absorb_observations(1.0, self);
        post
    }

    /// Whether every number is finite and the count and scatter are not negative (a guard for data that
    /// came from outside).
    pub fn is_valid(&self) -> bool {
        self.count.is_finite()
            && self.count >= 0.0
            && self.mean.iter().all(|v| v.is_finite())
            && self.scatter.iter().all(|v| v.is_finite() && *v >= 0.0)
    }
}

// Defined here rather than in `stats`, so that `stats` (the posterior) does not depend on `obs` (what
// feeds it): the dependency runs one way.
impl<const D: usize> VoxelStats<D> {
    /// Combine with observation statistics seen through kernel weight `k` (the paper's update with
    /// k̄ = k·n, ȳ = m, S̄ = k·S). `k · obs.count ≤ 0` leaves `self` unchanged.
    #[inline]
    pub fn absorb_observations(&mut self, k: f32, obs: &ObsStats<D>) {
        combine(
            (&mut self.lambda, &mut self.mean, &mut self.psi),
            k,
            (obs.count, &obs.mean, &obs.scatter),
        );
    }
}

/// Read access to a map of per-voxel observation statistics.
pub trait ObsLookup<const D: usize> {
    /// The observations of voxel `key`, if any point fell in it (by value: a quantized map decodes them).
    fn observed(&self, key: VoxelKey) -> Option<ObsStats<D>>;

    /// The point count n of voxel `key` (0 if nothing was observed there): all that a gather of counts
    /// reads ([`crate::info_gain`]). By default through [`Self::observed`]; a map can answer it without
    /// decoding the features.
    fn observed_count(&self, key: VoxelKey) -> f32 {
        self.observed(key).map_or(0.0, |o| o.count)
    }
}

/// Why a gather cannot be done.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum GatherError {
    /// The kernel table is in sub-voxel mode: per-voxel statistics do not know where inside its voxel
    /// each point was.
    SubVoxelKernel,
}

impl core::fmt::Display for GatherError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::SubVoxelKernel => f.write_str(
                "the sub-voxel kernel cannot be gathered from per-voxel statistics (use the voxel-offset kernel)",
            ),
        }
    }
}

impl core::error::Error for GatherError {}

/// The kernel-weighted observation moments (K, ȳ, S̄) of `target`'s neighbourhood: everything its posterior
/// depends on ([`ObsStats::posterior`]). `K = 0` (an empty result) when no observed voxel is in reach.
///
/// The voxel-offset kernel is symmetric (k(o) = k(−o)), so the neighbour at `target + o` contributes with
/// weight k(o). The target's own voxel goes first: the pairwise merge is exact in any order, and starting
/// from the heaviest set keeps the rounding of the running mean smallest.
pub fn gather<const D: usize, const CAP: usize, M: ObsLookup<D> + ?Sized>(
    lut: &KernelLut<CAP>,
    map: &M,
    target: VoxelKey,
) -> Result<ObsStats<D>, GatherError> {
    if !lut.is_voxel_offset() {
        return Err(GatherError::SubVoxelKernel);
    }
    let mut acc = map.observed(target).unwrap_or(ObsStats::EMPTY);
    for (&o, &k) in lut.offsets().iter().zip(lut.weights(0)) {
        if o == [0, 0, 0] {
            continue;
        }
        if let Some(obs) = map.observed(target.offset(o)) {
            acc.merge_scaled(k, &obs);
        }
    }
    Ok(acc)
}

/// The posterior of `target` gathered from `map` under `prior` (the prior alone when nothing is in reach).
pub fn gather_posterior<const D: usize, const CAP: usize, M: ObsLookup<D> + ?Sized>(
    lut: &KernelLut<CAP>,
    map: &M,
    prior: &Prior,
    target: VoxelKey,
) -> Result<VoxelStats<D>, GatherError> {
    Ok(gather(lut, map, target)?.posterior(prior))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{KernelMode, MapConfig};

    /// A tiny map for tests: a fixed list of (key, stats).
    struct List<const D: usize>(&'static [(VoxelKey, ObsStats<D>)]);
    impl<const D: usize> ObsLookup<D> for List<D> {
        fn observed(&self, key: VoxelKey) -> Option<ObsStats<D>> {
            self.0.iter().find(|(k, _)| *k == key).map(|(_, s)| *s)
        }
    }

    fn f64_moments(ys: &[(f64, [f64; 2])]) -> (f64, [f64; 2], [f64; 2]) {
        let w: f64 = ys.iter().map(|(k, _)| k).sum();
        let m: [f64; 2] =
            core::array::from_fn(|d| ys.iter().map(|(k, y)| k * y[d]).sum::<f64>() / w);
        let s: [f64; 2] = core::array::from_fn(|d| {
            ys.iter()
                .map(|(k, y)| k * (y[d] - m[d]) * (y[d] - m[d]))
                .sum::<f64>()
        });
        (w, m, s)
    }

    /// A first point written over a used set is Welford's step on an empty one, whole eights and a tail.
    #[test]
    fn set_point_writes_over_every_value() {
        fn check<const D: usize>() {
            let y: [f32; D] = core::array::from_fn(|i| i as f32 * 0.75 - 3.0);
            let mut one = ObsStats::<D>::EMPTY;
            one.add_point(&y);
            let mut set = ObsStats::<D> {
                count: 7.0,
                mean: [9.0; D],
                scatter: [5.0; D],
            };
            set.set_point(&y);
            assert_eq!(set, one, "D = {D}");
        }
        check::<64>();
        check::<13>();
        check::<3>();
    }

    #[test]
    fn welford_and_merge_equal_the_two_pass_moments() {
        let ys = [
            [1.0f32, -2.0],
            [3.0, 0.5],
            [-1.0, 4.0],
            [0.25, 0.0],
            [2.0, 2.0],
        ];
        let mut all = ObsStats::<2>::EMPTY;
        let (mut a, mut b) = (ObsStats::<2>::EMPTY, ObsStats::<2>::EMPTY);
        for (i, y) in ys.iter().enumerate() {
            all.add_point(y);
            if i < 2 {
                a.add_point(y)
            } else {
                b.add_point(y)
            }
        }
        a.merge(&b);
        let exact = f64_moments(&ys.map(|y| (1.0, [y[0] as f64, y[1] as f64])));
        for s in [all, a] {
            assert_eq!(s.count, 5.0);
            for d in 0..2 {
                assert!((s.mean[d] as f64 - exact.1[d]).abs() < 1e-6);
                assert!((s.scatter[d] as f64 - exact.2[d]).abs() < 1e-5);
            }
        }
    }

    #[test]
    fn non_centred_features_keep_their_scatter() {
        // Mean 100, spread 0.01: Σy² − nȳ² would cancel every significant digit in f32.
        let mut lcg = 12345u32;
        let mut next = || {
            lcg = lcg.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (lcg >> 8) as f64 / (1u64 << 24) as f64 - 0.5
        };
        let ys: [[f64; 2]; 400] =
            core::array::from_fn(|_| [100.0 + 0.02 * next(), -100.0 + 0.02 * next()]);
        let mut parts = [ObsStats::<2>::EMPTY; 4];
        for (i, y) in ys.iter().enumerate() {
            parts[i % 4].add_point(&[y[0] as f32, y[1] as f32]);
        }
        let mut merged = parts[0];
        for p in &parts[1..] {
            merged.merge_scaled(0.5, p); // weights 1, ½, ½, ½
        }
        let weighted: [(f64, [f64; 2]); 400] =
            core::array::from_fn(|i| (if i % 4 == 0 { 1.0 } else { 0.5 }, ys[i]));
        let (w, m, s) = f64_moments(&weighted);
        assert!((merged.count as f64 - w).abs() < 1e-9);
        for d in 0..2 {
            // f32 resolves 100 to 7.6e-6.
            assert!((merged.mean[d] as f64 - m[d]).abs() < 2e-5);
            let rel = (merged.scatter[d] as f64 - s[d]).abs() / s[d];
            assert!(rel < 1e-3, "dimension {d}: relative scatter error {rel}");
        }
    }

    #[test]
    fn gather_equals_the_paper_update_of_the_union() {
        // Three observed voxels around the origin; the target's posterior from the gather must equal the
        // paper's batch update applied to every point through its kernel weight (prior λ₀ = 2 so the cross
        // term is exercised).
        static MAP: [(VoxelKey, ObsStats<2>); 3] = [
            (
                VoxelKey::new(0, 0, 0),
                ObsStats {
                    count: 2.0,
                    mean: [1.0, 0.0],
                    scatter: [0.5, 0.0],
                },
            ),
            (
                VoxelKey::new(1, 0, 0),
                ObsStats {
                    count: 1.0,
                    mean: [0.0, 1.0],
                    scatter: [0.0, 0.0],
                },
            ),
            (
                VoxelKey::new(1, 1, 0),
                ObsStats {
                    count: 3.0,
                    mean: [1.0, 1.0],
                    scatter: [0.2, 0.3],
                },
            ),
        ];
        let prior = Prior {
            lambda: 2.0,
            mean: 0.25,
            psi: 0.5,
        };
        let config = MapConfig::new(0.1, 0.5, 3, prior, KernelMode::VoxelOffset).unwrap();
        let lut: KernelLut = KernelLut::new(&config).unwrap();
        let post = gather_posterior(&lut, &List(&MAP), &prior, VoxelKey::new(0, 0, 0)).unwrap();
        // The same through the paper's update: per source voxel, its moments seen through k.
        let mut reference = VoxelStats::<2>::from_prior(&prior);
        let mut batch = VoxelStats::<2>::EMPTY;
        for (key, obs) in &MAP {
            let k = lut.weight_at(0, key.x, key.y, key.z);
            let moments = VoxelStats {
                lambda: obs.count,
                mean: obs.mean,
                psi: obs.scatter,
            };
            batch.absorb_scaled(k, &moments);
        }
        reference.absorb(&batch);
        assert!((post.lambda - reference.lambda).abs() < 1e-6);
        for d in 0..2 {
            assert!((post.mean[d] - reference.mean[d]).abs() < 1e-6);
            assert!((post.psi[d] - reference.psi[d]).abs() < 1e-5);
        }
        // Nothing in reach: the prior.
        let far = gather_posterior(&lut, &List(&MAP), &prior, VoxelKey::new(5, 5, 5)).unwrap();
        assert_eq!(far, VoxelStats::from_prior(&prior));
    }

    #[test]
    fn sub_voxel_tables_are_refused() {
        let config = MapConfig::new(
            0.1,
            0.5,
            3,
            Prior::default(),
            KernelMode::SubVoxel { cells: 2 },
        )
        .unwrap();
        let lut: KernelLut<{ 8 * 27 }> = KernelLut::new(&config).unwrap();
        static EMPTY: [(VoxelKey, ObsStats<1>); 0] = [];
        assert_eq!(
            gather(&lut, &List(&EMPTY), VoxelKey::new(0, 0, 0)),
            Err(GatherError::SubVoxelKernel)
        );
    }
}
