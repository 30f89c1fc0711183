//! `host-sim bench`: the headline speed figures measured on the user's machine, one line each, over the
//! workloads of [`crate::bench`] (the same as the criterion benches').

use crate::bench::*;
use crate::{ObsMap, ReferenceMap};
use anyhow::Result;
use latentbki::nalgebra::Isometry3;
use latentbki::sampling::AUTHORS_DRAWS;
use latentbki::{inference::Spread, sampling::Sampler, sampling::SamplingMode, MapConfig};
use std::time::Duration;

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

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}
