//! Open-vocabulary decoding: cosine similarity between a voxel's mean and text embeddings (§III-C).
//!
//! Features are PCA-compressed (x ≈ Wᵀz + m, W ∈ R^{D×F} with orthonormal rows) before they reach the map.
//! Decoding naively would back-project μ to F = 384–512 dimensions per voxel and per query, and would need
//! W (128 KiB at 64 × 512) on the device. Instead each category's text embedding F_w is folded into the
//! compressed space once:
//!
//! ```text
//! F_wᵀ(Wᵀμ + m) = μ·(W F_w) + F_w·m
//! ‖Wᵀμ + m‖²    = ‖μ‖² + 2 μ·(W m) + ‖m‖²        (W Wᵀ = I)
//! ```
//!
//! so a score costs one D-dimensional dot product and the device stores D + 2 numbers per category.

/// A PCA projection F-d → D-d: mean m ∈ R^F and components W ∈ R^{D×F} (rows orthonormal).
#[derive(Clone, Debug, PartialEq)]
pub struct Pca<const D: usize, const F: usize> {
    /// The mean m of the full-dimensional features.
    pub mean: [f32; F],
    /// The components W, one row per compressed dimension.
    pub components: [[f32; F]; D],
}

impl<const D: usize, const F: usize> Pca<D, F> {
    /// Compress a full-dimensional feature: z = W (x − m).
    pub fn project(&self, x: &[f32; F]) -> [f32; D] {
        core::array::from_fn(|d| {
            self.components[d]
                .iter()
                .zip(x)
                .zip(&self.mean)
                .map(|((w, xi), mi)| w * (xi - mi))
                .sum()
        })
    }

    /// Back to the full dimension: x = Wᵀ z + m.
    pub fn back_project(&self, z: &[f32; D]) -> [f32; F] {
        let mut x = self.mean;
        for (row, zd) in self.components.iter().zip(z) {
            for (xi, w) in x.iter_mut().zip(row) {
                *xi += w * zd;
            }
        }
        x
    }

    /// Largest |W Wᵀ − I| entry: how far the rows are from orthonormal.
    pub fn orthonormality_error(&self) -> f32 {
        let mut worst = 0.0f32;
        for a in 0..D {
            for b in 0..D {
                let dot: f32 = self.components[a]
                    .iter()
                    .zip(&self.components[b])
                    .map(|(x, y)| x * y)
                    .sum();
                let target = if a == b { 1.0 } else { 0.0 };
                worst = worst.max(libm::fabsf(dot - target));
            }
        }
        worst
    }
}

/// Why a codebook could not be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum CodebookError {
    /// More categories than the codebook's capacity.
    TooManyCategories,
    /// A text embedding has zero length or a non-finite value.
    BadEmbedding,
    /// The PCA rows are not orthonormal (|W Wᵀ − I| > 1e-3), so the compressed-space norm would be wrong.
    NotOrthonormal,
}

impl core::fmt::Display for CodebookError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::TooManyCategories => "more categories than the codebook holds",
            Self::BadEmbedding => "a text embedding is zero or not finite",
            Self::NotOrthonormal => "PCA components are not orthonormal",
        })
    }
}

impl core::error::Error for CodebookError {}

/// One category folded into the compressed space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Category<const D: usize> {
    /// W F_w.
    pub direction: [f32; D],
    /// F_w · m.
    pub offset: f32,
    /// ‖F_w‖.
    pub norm: f32,
}

/// Text embeddings of up to `K` categories, ready to score D-dimensional voxel means.
///
/// ```
/// use latentbki::decode::{Codebook, Pca};
///
/// // A PCA 3 → 2 (orthonormal rows) and the 3-d text embeddings of two words.
/// let pca = Pca { mean: [0.0; 3], components: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] };
/// let words: Codebook<2, 8> = Codebook::from_pca(&pca, &[[1.0, 0.0, 0.0], [0.0, 1.0, 0.2]]).unwrap();
///
/// // A voxel's posterior mean, in the compressed space: closest to the second word.
/// let (best, score) = words.argmax(&[0.1, 0.9]).unwrap();
/// assert_eq!(best, 1);
/// assert!(score > 0.9);
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct Codebook<const D: usize, const K: usize> {
    categories: heapless::Vec<Category<D>, K>,
    /// W m.
    mean_direction: [f32; D],
    /// ‖m‖².
    mean_norm_sq: f32,
}

fn dot<const D: usize>(a: &[f32; D], b: &[f32; D]) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

impl<const D: usize, const K: usize> Codebook<D, K> {
    /// Fold full-dimensional text embeddings through a PCA.
    pub fn from_pca<const F: usize>(
        pca: &Pca<D, F>,
        embeddings: &[[f32; F]],
    ) -> Result<Self, CodebookError> {
        if pca.orthonormality_error() > 1e-3 {
            return Err(CodebookError::NotOrthonormal);
        }
        let mut categories = heapless::Vec::new();
        for e in embeddings {
            let norm = libm::sqrtf(e.iter().map(|v| v * v).sum());
            if !(norm.is_finite() && norm > 0.0) {
                return Err(CodebookError::BadEmbedding);
            }
            let direction =
                core::array::from_fn(|d| pca.components[d].iter().zip(e).map(|(w, x)| w * x).sum());
            let offset = e.iter().zip(&pca.mean).map(|(x, m)| x * m).sum();
            categories
                .push(Category {
                    direction,
                    offset,
                    norm,
                })
                .map_err(|_| CodebookError::TooManyCategories)?;
        }
        let mean_direction = core::array::from_fn(|d| {
            pca.components[d]
                .iter()
                .zip(&pca.mean)
                .map(|(w, m)| w * m)
                .sum()
        });
        let mean_norm_sq = pca.mean.iter().map(|m| m * m).sum();
        Ok(Self {
            categories,
            mean_direction,
            mean_norm_sq,
        })
    }

    /// Embeddings that already live in the map's D-dimensional space (no PCA).
    pub fn from_embeddings(embeddings: &[[f32; D]]) -> Result<Self, CodebookError> {
        let mut categories = heapless::Vec::new();
        for e in embeddings {
            let norm = libm::sqrtf(dot(e, e));
            if !(norm.is_finite() && norm > 0.0) {
                return Err(CodebookError::BadEmbedding);
            }
            categories
                .push(Category {
                    direction: *e,
                    offset: 0.0,
                    norm,
                })
                .map_err(|_| CodebookError::TooManyCategories)?;
        }
        Ok(Self {
            categories,
            mean_direction: [0.0; D],
            mean_norm_sq: 0.0,
        })
    }

    /// Rebuild from stored parts (e.g. a compiled-in table on the device).
    pub fn from_parts(
        categories: &[Category<D>],
        mean_direction: [f32; D],
        mean_norm_sq: f32,
    ) -> Result<Self, CodebookError> {
        let categories =
            heapless::Vec::from_slice(categories).map_err(|_| CodebookError::TooManyCategories)?;
        Ok(Self {
            categories,
            mean_direction,
            mean_norm_sq,
        })
    }

    /// The folded categories.
    pub fn categories(&self) -> &[Category<D>] {
        &self.categories
    }

    /// Number of categories.
    pub fn len(&self) -> usize {
        self.categories.len()
    }

    /// Whether there are no categories.
    pub fn is_empty(&self) -> bool {
        self.categories.is_empty()
    }

    /// ‖Wᵀμ + m‖, the norm of the back-projected mean (0 for the zero vector).
    fn full_norm(&self, mu: &[f32; D]) -> f32 {
        let sq = dot(mu, mu) + 2.0 * dot(mu, &self.mean_direction) + self.mean_norm_sq;
        libm::sqrtf(sq.max(0.0))
    }

    fn cosine(&self, c: &Category<D>, mu: &[f32; D], full_norm: f32) -> f32 {
        let denom = full_norm * c.norm;
        if denom > 0.0 {
            (dot(mu, &c.direction) + c.offset) / denom
        } else {
            0.0
        }
    }

    /// Cosine score of every category (as many as fit in `out`); returns how many were written.
    pub fn scores(&self, mu: &[f32; D], out: &mut [f32]) -> usize {
        let n = self.full_norm(mu);
        let mut written = 0;
        for (c, o) in self.categories.iter().zip(out.iter_mut()) {
            *o = self.cosine(c, mu, n);
            written += 1;
        }
        written
    }

    /// Cosine score of one category (0 for an unknown index).
    pub fn score(&self, mu: &[f32; D], category: usize) -> f32 {
        self.categories
            .get(category)
            .map_or(0.0, |c| self.cosine(c, mu, self.full_norm(mu)))
    }

    /// The best category and its cosine score; `None` for an empty codebook.
    pub fn argmax(&self, mu: &[f32; D]) -> Option<(usize, f32)> {
        let n = self.full_norm(mu);
        let mut best: Option<(usize, f32)> = None;
        for (i, c) in self.categories.iter().enumerate() {
            let s = self.cosine(c, mu, n);
            if best.is_none_or(|(_, b)| s > b) {
                best = Some((i, s));
            }
        }
        best
    }
}
