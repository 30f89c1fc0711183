//! `host-sim bench`: the headline speed figures, measured in one run on the user's machine.
//!
//! Each figure is the median of several timed repetitions on one core (the process is single-threaded), and
//! is printed as one stable line, e.g. `integrate surface 100k: 8.1 ms (reference map 612 ms, ratio 0.013)`.
//! The inputs are the same as the criterion benches' (`cargo bench -p host-sim --bench integrate`, for
//! development): (a) 100k surface points resampled from the real LiDAR tile with 2 cm jitter, (b) 100k
//! uniform points in a 6 m cube (almost every point alone in its voxel); f = 3, D = 64, 0.1 m voxels.
//! Uncertainty (as `cargo bench -p host-sim --bench uncertainty`): 10,000 voxels, E- and D-optimality, and
//! sampling with 30 draws against a 50-phrase vocabulary.

use crate::sim::tile::Tile;
use crate::{ObsMap, ReferenceMap};
use anyhow::Result;
use latentbki::nalgebra::Isometry3;
use latentbki::sampling::AUTHORS_DRAWS;
use latentbki::{
    decode::Codebook, inference::Spread, sampling::Sampler, sampling::SamplingMode,
    stats::VoxelStats, MapConfig,
};
use rand_xoshiro::rand_core::{RngCore, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::time::{Duration, Instant};

/// Feature dimension of the benchmarks.
pub const D: usize = 64;
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

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// Options of `host-sim bench`.
#[derive(clap::Args, Debug, Clone)]
pub struct BenchArgs {
    /// Timed repetitions per figure (the median is printed).
    #[arg(long, default_value_t = 11)]
    pub runs: usize,
    /// Repetitions of the (slow) reference map.
    #[arg(long, default_value_t = 3)]
    pub reference_runs: usize,
}

/// Run the benchmarks and print one line per figure.
pub fn run(args: &BenchArgs) -> Result<()> {
    let config = MapConfig::default();
    let id = Isometry3::identity();
    let surface = surface()?;
    let cube = cube();
    for (name, (pts, feats)) in [("surface", &surface), ("uniform", &cube)] {
        let fast = median_time(
            args.runs,
            || ObsMap::<D>::new(config).expect("default configuration"),
            |m| m.integrate(&id, pts, feats),
        );
        let reference = median_time(
            args.reference_runs,
            || ReferenceMap::<D>::new(config).expect("default configuration"),
            |m| m.integrate(&id, pts, feats),
        );
        println!(
            "integrate {name} 100k: {:.1} ms (reference map {:.0} ms, ratio {:.3})",
            ms(fast),
            ms(reference),
            fast.as_secs_f64() / reference.as_secs_f64()
        );
    }
    let mut map = ObsMap::<D>::new(config)?;
    map.integrate(&id, &surface.0, &surface.1);
    let mut voxels = 0usize;
    let gather = median_time(
        args.runs,
        || (),
        |_| {
            let mut sum = 0.0f32;
            voxels = 0;
            map.for_each_posterior(|_, post| {
                sum += post.lambda;
                voxels += 1;
            });
            sum
        },
    );
    println!(
        "posterior of every voxel in reach, surface 100k: {:.1} ms ({voxels} voxels from {} observed)",
        ms(gather),
        map.observed_len()
    );

    let vs = uncertainty_voxels();
    let cb = uncertainty_codebook();
    for (spread, name) in [
        (Spread::AuthorsTVar, "authors' t_var"),
        (Spread::StudentTCovariance, "Student-t covariance"),
    ] {
        let t = median_time(
            args.runs,
            || (),
            |_| {
                vs.iter()
                    .filter_map(|v| v.optimality(spread))
                    .map(|o| o.e + o.d)
                    .sum::<f32>()
            },
        );
        println!(
            "E- and D-optimality 10k voxels ({name}): {:.2} ms (paper, GPU: 2.3 ms)",
            ms(t)
        );
    }
    let mut sampler = Sampler::<D>::new(7);
    for (mode, name) in [
        (SamplingMode::Authors, "authors' procedure"),
        (SamplingMode::Sound, "sound"),
    ] {
        let t = median_time(
            args.reference_runs,
            || (),
            |_| {
                let mut acc = 0.0f32;
                for v in &vs {
                    if let Some((best, _)) = cb.argmax(&v.mean) {
                        acc += sampler
                            .score_variance(mode, v, &cb, best, AUTHORS_DRAWS)
                            .unwrap_or(0.0);
                    }
                }
                acc
            },
        );
        println!(
            "sampling uncertainty 10k voxels, {AUTHORS_DRAWS} draws, {PHRASES} phrases ({name}): {:.0} ms (paper, GPU: 5,661 ms)",
            ms(t)
        );
    }
    Ok(())
}
