//! Inference and uncertainty from a voxel's posterior (§III-C, §III-D).
//!
//! The posterior predictive of a voxel is a Student-t with λ degrees of freedom, location μ and scale
//! (λ+1)/λ² · Ψ. Its covariance, λ/(λ−2) · scale, exists only for λ > 2; E-optimality (largest variance)
//! and D-optimality (geometric mean of the variances — the diagonal is the eigenvalues) summarise it in one
//! number for free. Sampling uncertainty decodes S draws of the predictive and reports the variance of the
//! decoded category scores: the paper's more expensive reference.

use crate::decode::Codebook;
use crate::stats::VoxelStats;
use rand_core::RngCore;
use rand_distr::{ChiSquared, Distribution, StandardNormal};

impl<const D: usize> VoxelStats<D> {
    /// The expectation of the feature, μ (meaningful for λ > 1).
    pub fn expectation(&self) -> &[f32; D] {
        &self.mean
    }

    /// Multiplier (λ+1)/λ² turning Ψ into the Student-t scale; `None` for λ ≤ 0.
    pub fn scale_factor(&self) -> Option<f32> {
        (self.lambda > 0.0).then(|| (self.lambda + 1.0) / (self.lambda * self.lambda))
    }

    /// Multiplier λ/(λ−2) · (λ+1)/λ² turning Ψ into the predictive covariance; `None` for λ ≤ 2.
    pub fn covariance_factor(&self) -> Option<f32> {
        (self.lambda > 2.0).then(|| (self.lambda + 1.0) / (self.lambda * (self.lambda - 2.0)))
    }

    /// The Student-t scale diagonal (λ+1)/λ² · Ψ.
    pub fn predictive_scale(&self) -> Option<[f32; D]> {
        let f = self.scale_factor()?;
        Some(self.psi.map(|p| f * p))
    }

    /// The predictive covariance diagonal λ/(λ−2) · scale, defined for λ > 2.
    pub fn predictive_variance(&self) -> Option<[f32; D]> {
        let f = self.covariance_factor()?;
        Some(self.psi.map(|p| f * p))
    }

    /// E-optimality: the largest eigenvalue (= diagonal entry) of the predictive covariance.
    pub fn e_optimality(&self) -> Option<f32> {
        let f = self.covariance_factor()?;
        Some(f * self.psi.iter().fold(0.0f32, |a, &b| a.max(b)))
    }

    /// D-optimality: exp(mean(log eigenvalues)) of the predictive covariance (its volume, per dimension).
    pub fn d_optimality(&self) -> Option<f32> {
        let f = self.covariance_factor()?;
        if D == 0 {
            return Some(0.0);
        }
        let mean_log = self.psi.iter().map(|&p| libm::logf(p)).sum::<f32>() / D as f32;
        Some(f * libm::expf(mean_log))
    }

    /// Draw one feature from the posterior predictive Student-t into `out`. Returns `false` (and leaves
    /// `out` alone) when λ ≤ 0, where the predictive is undefined.
    ///
    /// Not on the device path: `rand_distr` draws its f32 normal and χ² variates through f64. Sampling
    /// uncertainty is an evaluation tool (host-sim); the firmware never links it.
    pub fn sample_predictive<R: RngCore + ?Sized>(&self, rng: &mut R, out: &mut [f32; D]) -> bool {
        let (Some(f), Ok(chi)) = (self.scale_factor(), ChiSquared::new(self.lambda)) else {
            return false;
        };
        // Multivariate t: one χ²_ν shared by all dimensions, ν = λ.
        let g: f32 = chi.sample(rng);
        let w = libm::sqrtf(self.lambda / g.max(f32::MIN_POSITIVE));
        for i in 0..D {
            let z: f32 = StandardNormal.sample(rng);
            out[i] = self.mean[i] + libm::sqrtf(f * self.psi[i]) * z * w;
        }
        true
    }

    /// Sampling uncertainty: decode `samples` draws of the predictive with `codebook`, write the variance of
    /// each category's cosine score into `variances` (as many as fit) and return the variance of the score
    /// of the category that μ decodes to. `None` if λ ≤ 0, `samples < 2` or the codebook is empty.
    pub fn sampling_uncertainty<const K: usize, R: RngCore + ?Sized>(
        &self,
        codebook: &Codebook<D, K>,
        rng: &mut R,
        samples: u32,
        variances: &mut [f32],
    ) -> Option<f32> {
        let (best, _) = codebook.argmax(&self.mean)?;
        if samples < 2 || self.scale_factor().is_none() {
            return None;
        }
        let n = codebook.len().min(variances.len()).min(K);
        let mut mean = [0.0f32; K];
        let mut m2 = [0.0f32; K];
        let mut scores = [0.0f32; K];
        let mut draw = [0.0f32; D];
        let mut best_stats = (0.0f32, 0.0f32); // Welford of the best category, even if it does not fit `n`
        for s in 1..=samples {
            if !self.sample_predictive(rng, &mut draw) {
                return None; // unreachable: λ > 0 was checked above
            }
            codebook.scores(&draw, &mut scores);
            let inv = 1.0 / s as f32;
            for c in 0..n {
                let d = scores[c] - mean[c];
                mean[c] += d * inv;
                m2[c] += d * (scores[c] - mean[c]);
            }
            let d = scores[best] - best_stats.0;
            best_stats.0 += d * inv;
            best_stats.1 += d * (scores[best] - best_stats.0);
        }
        let denom = (samples - 1) as f32;
        for c in 0..n {
            variances[c] = m2[c] / denom;
        }
        Some(best_stats.1 / denom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand_core::SeedableRng;
    use rand_xoshiro::Xoshiro128PlusPlus;

    fn voxel(lambda: f32) -> VoxelStats<3> {
        VoxelStats {
            lambda,
            mean: [1.0, 0.0, 0.0],
            psi: [4.0, 1.0, 0.25],
        }
    }

    #[test]
    fn predictive_moments_follow_the_paper() {
        let v = voxel(4.0);
        let scale = v.predictive_scale().unwrap();
        assert!((scale[0] - 5.0 / 16.0 * 4.0).abs() < 1e-6);
        let var = v.predictive_variance().unwrap();
        assert!((var[0] - 2.0 * 5.0 / 16.0 * 4.0).abs() < 1e-6);
        assert!((v.e_optimality().unwrap() - var[0]).abs() < 1e-6);
        let geo = libm::cbrtf(var[0] * var[1] * var[2]);
        assert!((v.d_optimality().unwrap() - geo).abs() < 1e-5);
        assert!(voxel(2.0).predictive_variance().is_none());
        assert!(voxel(2.0).e_optimality().is_none());
        assert!(voxel(0.0).predictive_scale().is_none());
    }

    #[test]
    fn samples_have_the_student_t_moments() {
        let v = voxel(10.0);
        let mut rng = Xoshiro128PlusPlus::seed_from_u64(7);
        let n = 40_000;
        let (mut s, mut s2) = ([0.0f64; 3], [0.0f64; 3]);
        let mut y = [0.0f32; 3];
        for _ in 0..n {
            assert!(v.sample_predictive(&mut rng, &mut y));
            for i in 0..3 {
                s[i] += y[i] as f64;
                s2[i] += (y[i] as f64).powi(2);
            }
        }
        let var = v.predictive_variance().unwrap();
        for i in 0..3 {
            let m = s[i] / n as f64;
            let vr = s2[i] / n as f64 - m * m;
            assert!((m - v.mean[i] as f64).abs() < 0.02, "mean {i}: {m}");
            assert!(
                (vr / var[i] as f64 - 1.0).abs() < 0.05,
                "variance {i}: {vr} vs {}",
                var[i]
            );
        }
        assert!(!voxel(0.0).sample_predictive(&mut rng, &mut y));
    }

    #[test]
    fn sampling_uncertainty_grows_with_scatter() {
        let cb =
            Codebook::<3, 3>::from_embeddings(&[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
                .unwrap();
        let mut rng = Xoshiro128PlusPlus::seed_from_u64(1);
        let mut var = [0.0f32; 3];
        let tight = VoxelStats::<3> {
            lambda: 50.0,
            mean: [1.0, 0.2, 0.0],
            psi: [0.5; 3],
        };
        let loose = VoxelStats::<3> {
            lambda: 50.0,
            mean: [1.0, 0.2, 0.0],
            psi: [20.0; 3],
        };
        let a = tight
            .sampling_uncertainty(&cb, &mut rng, 200, &mut var)
            .unwrap();
        let b = loose
            .sampling_uncertainty(&cb, &mut rng, 200, &mut var)
            .unwrap();
        assert!(b > 5.0 * a, "tight {a} loose {b}");
        assert!(var.iter().all(|&v| v > 0.0));
        assert!(tight
            .sampling_uncertainty(&cb, &mut rng, 1, &mut var)
            .is_none());
    }
}
