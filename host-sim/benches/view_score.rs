//! The information-gain score of one candidate view (`latentbki::info_gain::view_score` through `ObsMap::view_score`),
//! on the house of `host-sim explore`: a 12 × 9-ray predicted view (the explorers now predict 24 × 18) scored against a map of the first 20
//! frames of the scripted loop (D = 64). Also the explorer's fast path: Σ gain(λ, w) over the view's
//! precomputed kernel footprint, λ gathered per voxel.
//! Run: `cargo bench -p host-sim --bench view_score`.
use criterion::{criterion_group, criterion_main, Criterion};
use host_sim::explore::world::{footprint, World};
use host_sim::sim::indoor::{self, IndoorRun, IndoorScene};
use host_sim::ObsMap;
use latentbki::nalgebra::Isometry3;
use latentbki::{info_gain::voxel_gain, kernel::KernelLut};
use std::hint::black_box;

const D: usize = 64;

fn bench(c: &mut Criterion) {
    let scene = IndoorScene::generate(1);
    let seq = indoor::sequence(&scene, &IndoorRun::default());
    let config = seq.config;
    let mut map = ObsMap::<D>::new(config).unwrap();
    for (t, f) in seq.frames.iter().take(20).enumerate() {
        let points: Vec<[f32; 3]> = f.points.iter().map(|p| p.position).collect();
        let features: Vec<[f32; D]> = f
            .points
            .iter()
            .map(|p| core::array::from_fn(|d| ((p.class as usize + d + t) % 7) as f32 * 0.1))
            .collect();
        map.integrate(&Isometry3::identity(), &points, &features);
    }
    let world = World::new(scene, &config, 3072).unwrap();
    let (view, _) = world.views[world.views.len() / 3];
    let points = world.predicted_grid(view, (12, 9));
    let lut: KernelLut = KernelLut::new(&config).unwrap();
    let fp = footprint(&lut, &points, 1.0);
    println!(
        "view_score: one view = {} predicted points, {} voxels hit, {} voxels reached",
        points.len(),
        fp.hits.len(),
        fp.weights.len()
    );
    let mut g = c.benchmark_group("view_score");
    g.bench_function("obs_map_view_score_one_view", |b| {
        b.iter(|| map.view_score(black_box(&points)))
    });
    g.bench_function("footprint_sum_one_view", |b| {
        b.iter(|| {
            black_box(&fp)
                .weights
                .iter()
                .map(|&(k, w)| map.voxel_gain(k, w))
                .sum::<f32>()
        })
    });
    g.bench_function("voxel_gain_one_voxel", |b| {
        b.iter(|| voxel_gain(black_box(3.7), black_box(0.77)))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
