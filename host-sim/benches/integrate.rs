//! `integrate`: 100k points into the quantized on-device map (f = 3, D = 64), the host's observation map
//! (and the gather of every posterior in reach), and the f32 reference map for scale. (a) surface points: the real LiDAR tile, resampled with 2 cm jitter to 100k points; (b) uniform
//! random points in a 6 m cube (the worst case: almost every point alone in its voxel).
//! Run: `cargo bench -p host-sim --bench integrate`.

use criterion::{criterion_group, criterion_main, BatchSize, Criterion, Throughput};
use host_sim::{ObsMap, ReferenceMap};
use latentbki::nalgebra::Isometry3;
use latentbki::{local_map::LocalMap, packed_len, sink::Evicted, sink::SinkFull, MapConfig};

const D: usize = host_sim::bench::D;
const P: usize = packed_len(D);
const CAP: usize = 65_000;

fn surface() -> host_sim::bench::Batch {
    host_sim::bench::surface().expect("built-in tile")
}

fn cube() -> host_sim::bench::Batch {
    host_sim::bench::cube()
}

fn discard(_: Evicted<'_, D>) -> Result<(), SinkFull> {
    Ok(())
}

fn bench(c: &mut Criterion) {
    let config = MapConfig::default();
    let mut group = c.benchmark_group("integrate");
    group.sample_size(10);
    group.throughput(Throughput::Elements(host_sim::bench::N as u64));
    for (name, (pts, feats), window) in [("surface", surface(), 20.0f32), ("cube6m", cube(), 8.0)] {
        // An empty map whose window is centred on the first point.
        let fresh = || {
            let mut m = Box::new(LocalMap::<D, CAP, P>::EMPTY);
            m.configure(config, window).unwrap();
            m.move_window(pts[0], &mut discard);
            m
        };
        // The pose only places the window; points are in the map frame (identity transform).
        group.bench_function(format!("local_map/{name}"), |b| {
            b.iter_batched_ref(
                fresh,
                |m| {
                    for (p, y) in pts.iter().zip(&feats) {
                        let _ = m.add_point(*p, y, &mut discard);
                    }
                },
                BatchSize::PerIteration,
            )
        });
        // The host's fast path: per-voxel observation statistics (posteriors gathered when asked).
        group.bench_function(format!("obs_map/{name}"), |b| {
            b.iter_batched_ref(
                || ObsMap::<D>::new(config).unwrap(),
                |m| m.integrate(&Isometry3::identity(), &pts, &feats),
                BatchSize::PerIteration,
            )
        });
        let mut gathered = ObsMap::<D>::new(config).unwrap();
        gathered.integrate(&Isometry3::identity(), &pts, &feats);
        group.bench_function(format!("obs_map_every_posterior/{name}"), |b| {
            b.iter(|| {
                let mut sum = 0.0f32;
                gathered.for_each_posterior(|_, p| sum += p.lambda);
                sum
            })
        });
        group.bench_function(format!("reference_map/{name}"), |b| {
            b.iter_batched_ref(
                || ReferenceMap::<D>::new(config).unwrap(),
                |m| m.integrate(&Isometry3::identity(), &pts, &feats),
                BatchSize::PerIteration,
            )
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
