//! The workloads of the headline speed figures (`host-sim bench`, [`crate::cli`]) and of the criterion
//! benches.
//!
//! Each figure is the median of several timed repetitions on one core (the process is single-threaded), and
//! is printed as one stable line, e.g. `integrate surface 100k: 8.1 ms (reference map 612 ms, ratio 0.013)`.
//! The inputs are the same as the criterion benches' (`cargo bench -p host-sim --bench integrate`, for
//! development): (a) 100k surface points resampled from the real LiDAR tile with 2 cm jitter, (b) 100k
//! uniform points in a 6 m cube (almost every point alone in its voxel); f = 3, D = 64, 0.1 m voxels.
//! Uncertainty (as `cargo bench -p host-sim --bench uncertainty`): 10,000 voxels, E- and D-optimality, and
//! sampling with 30 draws against a 50-phrase vocabulary.

use crate::sim::tile::Tile;
use anyhow::Result;
use latentbki::{decode::Codebook, stats::VoxelStats};
use rand_xoshiro::rand_core::{RngCore, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::time::{Duration, Instant};

pub use crate::sim::vocab::D;
/// Points per benchmark batch.
pub const N: usize = 100_000;

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

/// A benchmark batch: points in the map frame and their features.
pub type Batch = (Vec<[f32; 3]>, Vec<[f32; D]>);

/// 100k surface points: the real tile resampled with 2 cm jitter, in random order.
pub fn surface() -> Result<Batch> {
    let tile = Tile::builtin()?;
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
    Ok((pts, f))
}

/// 100k uniform random points in a 6 m cube.
pub fn cube() -> Batch {
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

/// Phrases of the uncertainty benchmark's vocabulary.
pub const PHRASES: usize = 50;
/// Voxels of the uncertainty benchmark.
pub const UNCERTAINTY_VOXELS: usize = 10_000;

fn lcg(state: &mut u64) -> f32 {
    *state = state
        .wrapping_mul(6_364_136_223_846_793_005)
        .wrapping_add(1_442_695_040_888_963_407);
    (*state >> 40) as f32 / (1u64 << 24) as f32
}

/// 10,000 posteriors with λ from 2.5 to 62.5 and Ψ growing with λ.
pub fn uncertainty_voxels() -> Vec<VoxelStats<D>> {
    let mut s = 17u64;
    (0..UNCERTAINTY_VOXELS)
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

/// A 50-phrase vocabulary of random directions.
pub fn uncertainty_codebook() -> Codebook<D, PHRASES> {
    let mut s = 99u64;
    let e: Vec<[f32; D]> = (0..PHRASES)
        .map(|_| core::array::from_fn(|_| lcg(&mut s) - 0.5))
        .collect();
    Codebook::from_embeddings(&e).expect("valid embeddings")
}

/// Median wall time of `runs` calls of `f` (each call gets fresh state from `setup`, untimed).
pub fn median_time<S, R>(
    runs: usize,
    mut setup: impl FnMut() -> S,
    mut f: impl FnMut(&mut S) -> R,
) -> Duration {
    let mut times: Vec<Duration> = (0..runs.max(1))
        .map(|_| {
            let mut s = setup();
            let t = Instant::now();
            std::hint::black_box(f(&mut s));
            let e = t.elapsed();
            drop(s);
            e
        })
        .collect();
    times.sort();
    times[times.len() / 2]
}
