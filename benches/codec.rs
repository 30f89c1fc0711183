//! Per-voxel costs on the host: requantization (encode, decode) and one kernel-weighted absorb at D = 64.
//! Run: `cargo bench -p latentbki --bench codec`.
use criterion::{criterion_group, criterion_main, Criterion};
use latentbki::quant::{Dither, QuantVoxel};
use latentbki::{packed_len, VoxelStats};
use std::hint::black_box;

const D: usize = 64;
const P: usize = packed_len(D);

fn bench(c: &mut Criterion) {
    let mut s = VoxelStats::<D> {
        lambda: 7.0,
        ..VoxelStats::EMPTY
    };
    for i in 0..D {
        s.mean[i] = ((i as f32) * 0.37).sin() * 0.3;
        s.psi[i] = 1.0 + (i as f32) * 0.05;
    }
    let mut d = Dither::new(3);
    let q = QuantVoxel::<D, P>::encode(&s, &mut d);
    c.bench_function("encode", |b| {
        b.iter(|| QuantVoxel::<D, P>::encode(black_box(&s), &mut d))
    });
    let mut out = VoxelStats::EMPTY;
    c.bench_function("decode", |b| b.iter(|| black_box(&q).decode_into(&mut out)));
    let mut acc = s;
    c.bench_function("absorb_scaled", |b| {
        b.iter(|| acc.absorb_scaled(black_box(0.7), black_box(&s)))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
