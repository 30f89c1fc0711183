//! Fitting the PCA 384 → D that compresses features before they reach the map (§III, Feature Compression).
//!
//! The paper fits PCA on features of some scenes and applies it to others; here it is fitted on one
//! simulated sequence (its own seed) and used on another. The host can afford the exact eigen-decomposition
//! of the 384 × 384 covariance in f64; the device only ever sees the resulting projection.

use super::vocab::FULL_DIM;
use latentbki::decode::Pca;
use latentbki::nalgebra::{DMatrix, SymmetricEigen};

/// Why a PCA could not be fitted.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PcaError {
    /// Fewer samples than components.
    #[error("{found} samples cannot fit {needed} components")]
    TooFewSamples {
        /// Samples given.
        found: usize,
        /// Components asked for.
        needed: usize,
    },
}

/// Fit the top-`D` principal components of `samples` (the mean is removed; rows come out orthonormal).
pub fn fit<const D: usize>(samples: &[[f32; FULL_DIM]]) -> Result<Box<Pca<D, FULL_DIM>>, PcaError> {
    if samples.len() <= D {
        return Err(PcaError::TooFewSamples {
            found: samples.len(),
            needed: D + 1,
        });
    }
    let n = samples.len() as f64;
    let mut mean = [0.0f64; FULL_DIM];
    for s in samples {
        for (m, v) in mean.iter_mut().zip(s) {
            *m += f64::from(*v);
        }
    }
    mean.iter_mut().for_each(|m| *m /= n);
    let x = DMatrix::<f64>::from_fn(samples.len(), FULL_DIM, |r, c| {
        f64::from(samples[r][c]) - mean[c]
    });
    let cov = x.tr_mul(&x) / (n - 1.0);
    let eig = SymmetricEigen::new(cov);
    let mut order: Vec<usize> = (0..FULL_DIM).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let mut pca = Box::new(Pca {
        mean: mean.map(|m| m as f32),
        components: [[0.0f32; FULL_DIM]; D],
    });
    for (d, &col) in order.iter().take(D).enumerate() {
        let v = eig.eigenvectors.column(col);
        // A deterministic sign: the largest-magnitude entry positive.
        let big = (0..FULL_DIM)
            .max_by(|&a, &b| v[a].abs().total_cmp(&v[b].abs()))
            .unwrap_or(0);
        let sign = if v[big] < 0.0 { -1.0 } else { 1.0 };
        for i in 0..FULL_DIM {
            pca.components[d][i] = (sign * v[i]) as f32;
        }
    }
    Ok(pca)
}

/// Fraction of the samples' variance the PCA keeps.
pub fn explained_variance<const D: usize>(
    pca: &Pca<D, FULL_DIM>,
    samples: &[[f32; FULL_DIM]],
) -> f64 {
    let mut total = 0.0f64;
    let mut kept = 0.0f64;
    for s in samples {
        total += s
            .iter()
            .zip(&pca.mean)
            .map(|(x, m)| f64::from(x - m).powi(2))
            .sum::<f64>();
        kept += pca
            .project(s)
            .iter()
            .map(|z| f64::from(*z).powi(2))
            .sum::<f64>();
    }
    if total > 0.0 {
        kept / total
    } else {
        1.0
    }
}

/// The spread (standard deviation) of each component over the samples: how far a feature reaches along
/// it, which sets the step the on-device map's mean codes need there (`latentbki::quant::MeanWeights`).
pub fn spreads<const D: usize>(pca: &Pca<D, FULL_DIM>, samples: &[[f32; FULL_DIM]]) -> [f32; D] {
    let mut sq = [0.0f64; D];
    for s in samples {
        for (a, z) in sq.iter_mut().zip(pca.project(s)) {
            *a += f64::from(z) * f64::from(z);
        }
    }
    let n = samples.len().max(1) as f64;
    sq.map(|a| (a / n).sqrt() as f32)
}
