//! Uncertainty for 10,000 voxels at D = 64, one core: E- and D-optimality (both spreads), and sampling
//! uncertainty with 30 draws against a 50-phrase vocabulary (decode μ to its phrase, then the variance of
//! that phrase's score; and the authors' variant that scores every phrase of every draw).
//! The paper (GPU): 2.3 ms for the optimality criteria, 5,661 ms for sampling, 10,000 voxels.
//! Run: `cargo bench -p latentbki --bench uncertainty`.
use criterion::{criterion_group, criterion_main, Criterion};
use latentbki::sampling::AUTHORS_DRAWS;
use latentbki::{Codebook, Sampler, SamplingMode, Spread, VoxelStats};
use std::hint::black_box;
use std::time::Duration;

const D: usize = 64;
const K: usize = 50;
const VOXELS: usize = 10_000;

fn lcg(state: &mut u64) -> f32 {
    *state = state
        .wrapping_mul(6_364_136_223_846_793_005)
        .wrapping_add(1_442_695_040_888_963_407);
    (*state >> 40) as f32 / (1u64 << 24) as f32
}

fn voxels() -> Vec<VoxelStats<D>> {
    let mut s = 17u64;
    (0..VOXELS)
        .map(|_| {
            let lambda = 2.5 + 60.0 * lcg(&mut s) * lcg(&mut s);
            VoxelStats {
                lambda,
                mean: core::array::from_fn(|_| lcg(&mut s) - 0.5),
                psi: core::array::from_fn(|_| 1.0 + 0.2 * lambda * lcg(&mut s)),
            }
        })
        .collect()
}

fn codebook() -> Codebook<D, K> {
    let mut s = 99u64;
    let e: Vec<[f32; D]> = (0..K)
        .map(|_| core::array::from_fn(|_| lcg(&mut s) - 0.5))
        .collect();
    Codebook::from_embeddings(&e).expect("valid embeddings")
}

fn bench(c: &mut Criterion) {
    let vs = voxels();
    let cb = codebook();
    let mut g = c.benchmark_group("uncertainty_10k_voxels");
    for spread in [Spread::AuthorsTVar, Spread::StudentTCovariance] {
        let name = match spread {
            Spread::AuthorsTVar => "e_and_d_optimality_authors_tvar",
            Spread::StudentTCovariance => "e_and_d_optimality_student_t_covariance",
        };
        g.bench_function(name, |b| {
            b.iter(|| {
                let mut acc = 0.0f32;
                for v in black_box(&vs) {
                    if let Some(o) = v.optimality(spread) {
                        acc += o.e + o.d;
                    }
                }
                acc
            })
        });
    }
    g.sample_size(10).measurement_time(Duration::from_secs(8));
    let mut sampler = Sampler::<D>::new(7);
    for mode in [SamplingMode::Authors, SamplingMode::Sound] {
        let name = match mode {
            SamplingMode::Authors => "sampling_authors_30_draws_decoded_phrase_of_50",
            SamplingMode::Sound => "sampling_sound_30_draws_decoded_phrase_of_50",
        };
        g.bench_function(name, |b| {
            b.iter(|| {
                let mut acc = 0.0f32;
                for v in black_box(&vs) {
                    let Some((best, _)) = cb.argmax(&v.mean) else {
                        continue;
                    };
                    if let Some(var) = sampler.score_variance(mode, v, &cb, best, AUTHORS_DRAWS) {
                        acc += var;
                    }
                }
                acc
            })
        });
    }
    let mut out = [0.0f32; K];
    g.bench_function("sampling_authors_30_draws_all_50_phrases", |b| {
        b.iter(|| {
            let mut acc = 0.0f32;
            for v in black_box(&vs) {
                let n = sampler.authors_all_categories(v, &cb, AUTHORS_DRAWS, &mut out);
                acc += out[..n].iter().sum::<f32>();
            }
            acc
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
