//! `host-sim view-bench`: the cost of the live view's full scene for a large map (goal ≤ 50 ms at 100k
//! voxels). The map is a synthetic ground plane of observed voxels (one robot, random features); the
//! figure is the median over repeats of one layer's full `SceneUpdate` as a late joiner gets it — the
//! blocks' cached encodings joined, what a subscription costs the view thread — and, apart, of building
//! and encoding every block again (a layer's first send, or after its colour range changed). Decoding every voxel's
//! posterior (done once when a map is loaded, then only for the voxels a frame changes) is printed apart.

use super::station::median_p95;
use crate::base_station::view::{scene::encode, DecodedMap, Layer};
use crate::base_station::{ContributionId, GlobalMap, GlobalVoxel, VOCAB_CAP};
use crate::link::SplitMix;
use anyhow::Result;
use clap::Args;
use latentbki::wire::{SessionConfig, SummaryCodec, NO_FEATURE_SPACE};
use latentbki::{decode::Codebook, key::VoxelKey, obs::ObsStats, MapConfig};
use std::time::{Duration, Instant};

use crate::sim::vocab::D;

/// Options of `host-sim view-bench`.
#[derive(Args, Debug)]
pub struct ViewBenchArgs {
    /// Observed voxels in the synthetic map.
    #[arg(long, default_value_t = 100_000)]
    voxels: usize,
    /// Repeats of the full scene (the median is printed).
    #[arg(long, default_value_t = 7)]
    repeats: usize,
}

/// Run `host-sim view-bench`.
pub fn run(args: &ViewBenchArgs) -> Result<()> {
    let config = SessionConfig::new(
        &MapConfig::default(),
        D,
        SummaryCodec::DEFAULT,
        NO_FEATURE_SPACE,
    );
    let mut map = GlobalMap::<D>::new(config).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let side = (args.voxels as f64).sqrt().ceil() as i32;
    let mut rng = SplitMix::new(1);
    let mut class_means = [[0.0f32; D]; 12];
    for m in class_means.iter_mut().flatten() {
        *m = rng.unit() as f32 - 0.5;
    }
    for i in 0..args.voxels as i32 {
        let mut obs = ObsStats::<D>::EMPTY;
        obs.count = 4.0;
        let class = &class_means[(i as usize / 97) % 12];
        for ((m, s), c) in obs.mean.iter_mut().zip(&mut obs.scatter).zip(class) {
            *m = c + 0.05 * (rng.unit() as f32 - 0.5);
            *s = 0.01 + 0.01 * rng.unit() as f32;
        }
        let id = ContributionId {
            robot: 1,
            session: 1,
            residency: 0,
        };
        map.insert_raw(
            VoxelKey::new(i % side, i / side, (i % 7 == 0) as i32),
            GlobalVoxel {
                settled: obs,
                closed: vec![id],
                ..GlobalVoxel::EMPTY
            },
        );
    }
    let vocab = Codebook::<D, VOCAB_CAP>::from_embeddings(&class_means)
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let mut scene = DecodedMap::<D, VOCAB_CAP>::new(map.map_config().voxel_size());
    let t = Instant::now();
    scene.update(&map, &map.sorted_keys(), Some(&vocab), None);
    scene.fix_ranges();
    let decode = t.elapsed();
    let now = crate::base_station::view::foxglove::messages::Timestamp::now;
    // Rebuilt: every block built and encoded (the first full scene of a layer, or after its colour range
    // changed).
    let mut rebuilt = Vec::<Duration>::new();
    for _ in 0..args.repeats.max(1) {
        let t = Instant::now();
        let msg = scene.full_message(Layer::Classes, now());
        std::hint::black_box(encode(&msg));
        rebuilt.push(t.elapsed());
    }
    // A late joiner: the live view has sent the layer once (building every block's bytes), then each
    // subscription joins the cached bytes.
    scene.full_bytes(Layer::Classes, now());
    let mut times = Vec::<Duration>::new();
    let mut bytes = 0;
    for _ in 0..args.repeats.max(1) {
        let t = Instant::now();
        bytes = std::hint::black_box(scene.full_bytes(Layer::Classes, now())).len();
        times.push(t.elapsed());
    }
    let (median, p95) = median_p95(&times);
    println!(
        "view full scene, {} voxels: {:.1} ms median, {:.1} ms p95 over {} repeats (one layer, late joiner: cached block bytes joined, {:.1} MB; goal <= 50 ms)",
        scene.len(),
        median.as_secs_f64() * 1e3,
        p95.as_secs_f64() * 1e3,
        times.len(),
        bytes as f64 / 1e6
    );
    let (median, p95) = median_p95(&rebuilt);
    println!(
        "view full scene rebuilt (every block built + encoded: first send, or a colour range changed), {} voxels: {:.1} ms median, {:.1} ms p95 over {} repeats",
        scene.len(),
        median.as_secs_f64() * 1e3,
        p95.as_secs_f64() * 1e3,
        rebuilt.len()
    );
    println!(
        "view decode of every voxel (posterior, class, E-optimality), {} voxels: {:.0} ms (once per loaded map)",
        scene.len(),
        decode.as_secs_f64() * 1e3
    );
    Ok(())
}
