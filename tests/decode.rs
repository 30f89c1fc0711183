//! Decoding in the compressed 64-d space equals the naive decode (back-project to full dimension, cosine).

use latentbki::decode::CodebookError;
use latentbki::{decode::Codebook, decode::Pca};
use proptest::prelude::*;
use proptest::test_runner::TestRng;

const D: usize = 64;
const F: usize = 384;
const K: usize = 24;

/// A random PCA with orthonormal rows (Gram–Schmidt in f64) and a random mean.
fn random_pca(rng: &mut TestRng) -> Box<Pca<D, F>> {
    let mut rows: Vec<[f64; F]> = Vec::new();
    while rows.len() < D {
        let mut v: [f64; F] = core::array::from_fn(|_| rng.random_range(-1.0..1.0));
        for r in &rows {
            let p: f64 = v.iter().zip(r).map(|(a, b)| a * b).sum();
            v.iter_mut().zip(r).for_each(|(a, b)| *a -= p * b);
        }
        let n = v.iter().map(|a| a * a).sum::<f64>().sqrt();
        if n > 1e-3 {
            rows.push(v.map(|a| a / n));
        }
    }
    let mut pca = Box::new(Pca {
        mean: [0.0; F],
        components: [[0.0; F]; D],
    });
    for (dst, src) in pca.components.iter_mut().zip(&rows) {
        *dst = src.map(|a| a as f32);
    }
    pca.mean = core::array::from_fn(|_| rng.random_range(-0.5..0.5));
    pca
}

/// The naive decode, in f64: x = Wᵀμ + m, cosine with each embedding.
fn naive_scores(pca: &Pca<D, F>, mu: &[f32; D], embeddings: &[[f32; F]]) -> Vec<f64> {
    let x = pca.back_project(mu);
    let nx = x.iter().map(|&a| (a as f64).powi(2)).sum::<f64>().sqrt();
    embeddings
        .iter()
        .map(|e| {
            let ne = e.iter().map(|&a| (a as f64).powi(2)).sum::<f64>().sqrt();
            x.iter()
                .zip(e)
                .map(|(&a, &b)| a as f64 * b as f64)
                .sum::<f64>()
                / (nx * ne)
        })
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]
    #[test]
    fn compressed_decode_equals_naive(seed in any::<u64>(), mu_scale in prop_oneof![Just(0.05f32), Just(1.0f32), Just(20.0f32)]) {
        let mut rng = TestRng::from_seed(proptest::test_runner::RngAlgorithm::ChaCha, &seed.to_le_bytes().repeat(4));
        let pca = random_pca(&mut rng);
        let embeddings: Vec<[f32; F]> = (0..K).map(|_| core::array::from_fn(|_| rng.random_range(-1.0f32..1.0))).collect();
        let codebook = Codebook::<D, K>::from_pca(&pca, &embeddings).unwrap();
        for _ in 0..8 {
            // Means near a category (the realistic case) and arbitrary ones.
            let target = &embeddings[rng.random_range(0..K)];
            let near = pca.project(target);
            let mu: [f32; D] = core::array::from_fn(|d| near[d] + mu_scale * rng.random_range(-1.0f32..1.0));
            let naive = naive_scores(&pca, &mu, &embeddings);
            let mut fast = [0.0f32; K];
            prop_assert_eq!(codebook.scores(&mu, &mut fast), K);
            for c in 0..K {
                prop_assert!((fast[c] as f64 - naive[c]).abs() < 1e-5, "category {}: {} vs {}", c, fast[c], naive[c]);
            }
            let (best, score) = codebook.argmax(&mu).unwrap();
            let (nbest, nscore) = naive.iter().enumerate().fold((0, f64::MIN), |a, (i, &s)| if s > a.1 { (i, s) } else { a });
            // Same argmax unless two categories tie within the score tolerance.
            prop_assert!(best == nbest || (nscore - naive[best]).abs() < 1e-5);
            prop_assert!((score as f64 - nscore).abs() < 1e-5);
        }
    }
}

#[test]
fn codebook_errors_are_clear() {
    let mut rng = TestRng::deterministic_rng(proptest::test_runner::RngAlgorithm::ChaCha);
    let mut pca = random_pca(&mut rng);
    let e = [[1.0f32; F]];
    assert_eq!(
        Codebook::<D, 1>::from_pca(&pca, &[[0.0; F]]).unwrap_err(),
        CodebookError::BadEmbedding
    );
    assert_eq!(
        Codebook::<D, 0>::from_pca(&pca, &e).unwrap_err(),
        CodebookError::TooManyCategories
    );
    pca.components[3][0] += 0.1;
    assert_eq!(
        Codebook::<D, 1>::from_pca(&pca, &e).unwrap_err(),
        CodebookError::NotOrthonormal
    );
}
