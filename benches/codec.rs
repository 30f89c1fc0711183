//! Per-voxel costs on the host at D = 64: the local map's codes (encode, decode), one point into a voxel's
//! statistics (Welford) and one kernel-weighted merge (a gather's step).
//! Run: `cargo bench -p latentbki --bench codec`.
use criterion::{criterion_group, criterion_main, Criterion};
use latentbki::quant::{Dither, QuantVoxel};
use latentbki::{obs::ObsStats, packed_len};
use std::hint::black_box;

const D: usize = 64;
const P: usize = packed_len(D);

fn bench(c: &mut Criterion) {
    let mut s = ObsStats::<D> {
        count: 7.0,
        ..ObsStats::EMPTY
    };
    for i in 0..D {
        s.mean[i] = ((i as f32) * 0.37).sin() * 0.3;
        s.scatter[i] = 1.0 + (i as f32) * 0.05;
    }
    let mut d = Dither::new(3);
    let q = QuantVoxel::<D, P>::encode(&s, &mut d);
    c.bench_function("encode", |b| {
        b.iter(|| QuantVoxel::<D, P>::encode(black_box(&s), &mut d))
    });
    let mut out = ObsStats::EMPTY;
    c.bench_function("decode", |b| b.iter(|| black_box(&q).decode_into(&mut out)));
    let mut acc = s;
    let y = s.mean;
    c.bench_function("add_point", |b| b.iter(|| acc.add_point(black_box(&y))));
    let mut acc = s;
    c.bench_function("merge_scaled", |b| {
        b.iter(|| acc.merge_scaled(black_box(0.7), black_box(&s)))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
