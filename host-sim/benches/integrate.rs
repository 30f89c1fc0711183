//! `integrate`: 100k points into the quantized on-device map (f = 3, D = 64), and the f32 reference map for
//! scale. (a) surface points: the real LiDAR tile, resampled with 2 cm jitter to 100k points; (b) uniform
//! random points in a 6 m cube (the worst case: almost every point alone in its voxel).
//! Run: `cargo bench -p host-sim --bench integrate`.

use criterion::{criterion_group, criterion_main, BatchSize, Criterion, Throughput};
use host_sim::order::morton_order;
use host_sim::sim::tile::Tile;
use host_sim::ReferenceMap;
use latentbki::nalgebra::Isometry3;
use latentbki::rand_xoshiro::rand_core::{RngCore, SeedableRng};
use latentbki::rand_xoshiro::Xoshiro256PlusPlus;
use latentbki::{packed_len, Evicted, LocalMap, MapConfig, SinkFull};

const D: usize = 64;
const P: usize = packed_len(D);
const CAP: usize = 65_000;
const N: usize = 100_000;

fn unit(rng: &mut Xoshiro256PlusPlus) -> f32 {
    (rng.next_u32() >> 8) as f32 / (1u32 << 24) as f32
}

fn features(classes: &[u16], rng: &mut Xoshiro256PlusPlus) -> Vec<[f32; D]> {
    let proto: Vec<[f32; D]> = (0..8)
        .map(|_| core::array::from_fn(|_| unit(rng) - 0.5))
        .collect();
    classes
        .iter()
        .map(|&c| core::array::from_fn(|i| proto[c as usize % 8][i] + 0.05 * (unit(rng) - 0.5)))
        .collect()
}

fn surface() -> (Vec<[f32; 3]>, Vec<[f32; D]>) {
    let tile = Tile::builtin().expect("built-in tile");
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
    let mut pts = Vec::with_capacity(N);
    let mut cls = Vec::with_capacity(N);
    for _ in 0..N {
        let i = rng.next_u32() as usize % tile.points.len();
        let p = tile.points[i];
        pts.push([
            p[0] + 0.02 * (unit(&mut rng) - 0.5),
            p[1] + 0.02 * (unit(&mut rng) - 0.5),
            p[2] + 0.02 * (unit(&mut rng) - 0.5),
        ]);
        cls.push(tile.classes[i]);
    }
    let f = features(&cls, &mut rng);
    (pts, f)
}

fn cube() -> (Vec<[f32; 3]>, Vec<[f32; D]>) {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(2);
    let pts: Vec<[f32; 3]> = (0..N)
        .map(|_| {
            [
                6.0 * unit(&mut rng),
                6.0 * unit(&mut rng),
                6.0 * unit(&mut rng),
            ]
        })
        .collect();
    let cls: Vec<u16> = pts.iter().map(|p| (p[0] / 1.5) as u16).collect();
    let f = features(&cls, &mut rng);
    (pts, f)
}

fn discard(_: Evicted<'_, D>) -> Result<(), SinkFull> {
    Ok(())
}

fn bench(c: &mut Criterion) {
    let config = MapConfig::default();
    let mut group = c.benchmark_group("integrate");
    group.sample_size(10);
    group.throughput(Throughput::Elements(N as u64));
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
                    m.end_batch(&mut discard);
                },
                BatchSize::PerIteration,
            )
        });
        // The same batch put in Morton order first (the sort is inside the timed region).
        group.bench_function(format!("local_map_morton/{name}"), |b| {
            b.iter_batched_ref(
                fresh,
                |m| {
                    for i in morton_order(&pts, config.voxel_size()) {
                        let i = i as usize;
                        let _ = m.add_point(pts[i], &feats[i], &mut discard);
                    }
                    m.end_batch(&mut discard);
                },
                BatchSize::PerIteration,
            )
        });
        // A host-sized batch scratch (256 source-voxel groups, 136 KiB instead of the device's 32, 17 KiB):
        // shared neighbours are re-encoded once per flush, so fewer flushes mean fewer re-encodes.
        let fresh_g256 = || {
            let mut m = Box::new(LocalMap::<D, CAP, P, 256>::EMPTY);
            m.configure(config, window).unwrap();
            m.move_window(pts[0], &mut discard);
            m
        };
        group.bench_function(format!("local_map_morton_g256/{name}"), |b| {
            b.iter_batched_ref(
                fresh_g256,
                |m| {
                    for i in morton_order(&pts, config.voxel_size()) {
                        let i = i as usize;
                        let _ = m.add_point(pts[i], &feats[i], &mut discard);
                    }
                    m.end_batch(&mut discard);
                },
                BatchSize::PerIteration,
            )
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
