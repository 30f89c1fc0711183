//! Uncertainty for 10,000 voxels at D = 64, one core: E- and D-optimality (both spreads), and sampling
//! uncertainty with 30 draws against a 50-phrase vocabulary (decode μ to its phrase, then the variance of
//! that phrase's score; and the authors' variant that scores every phrase of every draw).
//! The paper (GPU): 2.3 ms for the optimality criteria, 5,661 ms for sampling, 10,000 voxels.
//! Run: `cargo bench -p host-sim --bench uncertainty` (`host-sim bench` prints the same figures, one run).
use criterion::{criterion_group, criterion_main, Criterion};
use latentbki::sampling::AUTHORS_DRAWS;
use latentbki::{inference::Spread, sampling::Sampler, sampling::SamplingMode};
use std::hint::black_box;
use std::time::Duration;

const D: usize = host_sim::bench::D;
const K: usize = host_sim::bench::PHRASES;

fn bench(c: &mut Criterion) {
    let vs = host_sim::bench::uncertainty_voxels();
    let cb = host_sim::bench::uncertainty_codebook();
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
