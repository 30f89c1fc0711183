//! The information-gain score of one candidate view, for the view `host-sim explore` actually scores: the
//! explorers' ray grid (`explore::world::RAYS`, 24 × 18) cast from one of the house's candidate views,
//! scored against a map of the first 20 frames of the scripted loop (D = 64). Three ways:
//! - `obs_map_view_score`: the exact no-heap score (`latentbki::info_gain::view_score` through
//!   `ObsMap::view_score`, the code `Mapper::view_score` runs on the robot);
//! - `footprint_sum`: Σ gain(λ, w) over the view's precomputed kernel footprint, λ gathered per voxel;
//! - `explorer_slots_sum`: what the explorers run per candidate, the same sum with λ read from a dense
//!   array by voxel slot.
//!
//! The earlier 12 × 9 grid is kept for the exact score only: two views of the same place that reach
//! different numbers of voxels show how the cost grows with them. Each line printed first gives a view's
//! predicted points, the voxels they hit and the voxels the kernel reaches from those.
//! Run: `cargo bench -p host-sim --bench view_score` (20 samples, 3 s each; criterion's own flags override).
use criterion::{criterion_group, criterion_main, Criterion};
use host_sim::explore::world::{footprint, World, RAYS};
use host_sim::sim::indoor::{self, IndoorRun, IndoorScene};
use host_sim::sim::sensor::DepthCamera;
use host_sim::ObsMap;
use latentbki::nalgebra::Isometry3;
use latentbki::{info_gain, kernel::KernelLut};
use std::hint::black_box;
use std::time::Duration;

use host_sim::sim::vocab::D;

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
    // The world `host-sim explore` builds: every candidate's footprint, its kernel weights per ray.
    let world = World::new(scene, &config, DepthCamera::default().pixels_per_frame).unwrap();
    let (view, fp) = &world.views[world.views.len() / 3];
    let lut: KernelLut = KernelLut::new(&config).unwrap();
    let explorer = world.predicted_grid(*view, RAYS);
    let coarse = world.predicted_grid(*view, (12, 9));
    for (rays, points, fp) in [
        (RAYS, &explorer, fp),
        ((12, 9), &coarse, &footprint(&lut, &coarse, 1.0)),
    ] {
        println!(
            "view_score: {} x {} rays (explorer: {} x {}) = {} predicted points, {} voxels hit, {} voxels reached (f = {})",
            rays.0,
            rays.1,
            RAYS.0,
            RAYS.1,
            points.len(),
            fp.hits.len(),
            fp.weights.len(),
            2 * lut.reach() + 1
        );
    }
    // The explorer's λ per slot, as it keeps it: the prior plus the kernel-weighted count gathered.
    let mut lambda = vec![0.0f32; world.slots.len()];
    for (&key, &s) in &world.slots {
        lambda[s as usize] =
            config.prior().lambda + info_gain::gathered_count(&lut, &map, key).unwrap_or(0.0);
    }
    let mut g = c.benchmark_group("view_score");
    g.sample_size(20)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3));
    g.bench_function("obs_map_view_score_24x18", |b| {
        b.iter(|| map.view_score(black_box(&explorer)))
    });
    g.bench_function("obs_map_view_score_12x9", |b| {
        b.iter(|| map.view_score(black_box(&coarse)))
    });
    g.bench_function("footprint_sum_24x18", |b| {
        b.iter(|| {
            black_box(fp)
                .weights
                .iter()
                .map(|&(k, w)| map.voxel_gain(k, w))
                .sum::<f32>()
        })
    });
    g.bench_function("explorer_slots_sum_24x18", |b| {
        b.iter(|| {
            black_box(fp)
                .slot_weights
                .iter()
                .map(|&(s, w)| info_gain::voxel_gain(lambda[s as usize], w))
                .sum::<f32>()
        })
    });
    g.bench_function("voxel_gain_one_voxel", |b| {
        b.iter(|| info_gain::voxel_gain(black_box(3.7), black_box(0.77)))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
