//! `base_station`: how many voxel summaries per second the base station takes from a file into its SQLite
//! map database with commits on (every 250 ms, the default), the whole path the CLI runs: a reader thread,
//! frame checks, the exact merge, dirty-voxel tracking and the transactions. The stream: 6 robots, 60 scans
//! each along a street (the streaming tests' scene), live updates and evictions, written to a file once.
//! Then the map's lookups on the merged result: one voxel's posterior (a 27-neighbour gather) for every
//! voxel held, and every posterior in reach at once (what the exports and `map-info` take).
//! Run: `cargo bench -p host-sim --bench base_station`; it prints one line per figure.

#[path = "../tests/stream_common/mod.rs"]
mod stream_common;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use host_sim::base_station::store::SqliteStore;
use host_sim::base_station::BaseStation;
use host_sim::cli::station::{pump, spawn_reader, PumpOptions};
use host_sim::link::SplitMix;
use latentbki::wire::SummaryCodec;
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use stream_common::*;

/// Six robots' streams, one after another in one file.
fn recorded() -> Vec<u8> {
    let world = World::new(SummaryCodec::DEFAULT);
    let mut bytes = Vec::new();
    for robot in 1..=6u16 {
        let mut rig = RobotRig::new(&world, robot, 2.5);
        let mut rng = SplitMix::new(u64::from(robot));
        for i in 0..60 {
            let x = 1.0 + 0.3 * i as f32;
            let (pose, pts, feats) = scan(&world, &mut rng, x, 0.3 * f32::from(robot), 400, 1.6);
            rig.step(&pose, &pts, &feats, 16_384);
        }
        rig.finish();
        bytes.extend_from_slice(&rig.uart.0);
    }
    bytes
}

/// One run from the file into a fresh database: (summaries taken, time).
fn run(file: &std::path::Path, dir: &std::path::Path, n: usize) -> (u64, Duration) {
    let db = dir.join(format!("bench-{n}.db"));
    let start = Instant::now();
    let mut store = SqliteStore::open(&db).unwrap();
    let mut base = BaseStation::<D>::open(&mut store).unwrap();
    let chunks = spawn_reader(Box::new(std::fs::File::open(file).unwrap()));
    let options = PumpOptions {
        commit_every: Duration::from_millis(250),
        duration: None,
        stop: Arc::new(AtomicBool::new(false)),
    };
    pump(&mut base, Some(&mut store), &chunks, &options).unwrap();
    let took = start.elapsed();
    let s = base.stats();
    assert_eq!(s.lost, 0);
    (u64::from(s.merged + s.updated + s.ignored), took)
}

fn bench(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("robots.bin");
    std::fs::write(&file, recorded()).unwrap();
    let (summaries, _) = run(&file, dir.path(), 0);
    let rates = Arc::new(Mutex::new(Vec::new()));
    let mut g = c.benchmark_group("base_station");
    g.sample_size(10);
    g.throughput(Throughput::Elements(summaries));
    let mut n = 0;
    g.bench_function("file_to_sqlite_commit_250ms", |b| {
        b.iter_custom(|iters| {
            let mut total = Duration::ZERO;
            for _ in 0..iters {
                n += 1;
                let (s, t) = run(&file, dir.path(), n);
                rates.lock().unwrap().push(s as f64 / t.as_secs_f64());
                total += t;
            }
            total
        })
    });
    g.finish();
    let mut r = rates.lock().unwrap().clone();
    r.sort_by(f64::total_cmp);
    if r.is_empty() {
        return; // filtered out
    }
    println!(
        "base station, file -> SQLite with commits every 250 ms: median {:.0} summaries/s (min {:.0}, max {:.0}; {summaries} summaries, {} runs)",
        r[r.len() / 2],
        r[0],
        r[r.len() - 1],
        r.len()
    );
}

/// Median of `f`'s time over `runs` runs.
fn median_time(runs: usize, mut f: impl FnMut()) -> Duration {
    let mut t: Vec<Duration> = (0..runs)
        .map(|_| {
            let start = Instant::now();
            f();
            start.elapsed()
        })
        .collect();
    t.sort();
    t[runs / 2]
}

fn lookups(c: &mut Criterion) {
    let mut base = BaseStation::<D>::adopting();
    base.receive(&recorded());
    let map = base
        .into_map()
        .expect("the stream carries a session header");
    let keys = map.sorted_keys();
    let mut g = c.benchmark_group("global_map");
    g.sample_size(10);
    g.throughput(Throughput::Elements(keys.len() as u64));
    let gather_all = || {
        keys.iter()
            .filter_map(|k| map.posterior(k))
            .map(|p| p.lambda)
            .sum::<f32>()
    };
    g.bench_function("posterior_every_voxel", |b| b.iter(gather_all));
    g.bench_function("posteriors", |b| b.iter(|| map.posteriors().len()));
    g.finish();
    let one = median_time(11, || {
        std::hint::black_box(gather_all());
    });
    let all = median_time(11, || {
        std::hint::black_box(map.posteriors());
    });
    println!(
        "global map lookups: posterior(key) median {:.0} ns per voxel; posteriors() median {:.1} ms ({} voxels held, {} in reach)",
        one.as_secs_f64() * 1e9 / keys.len() as f64,
        all.as_secs_f64() * 1e3,
        keys.len(),
        map.posteriors().len()
    );
}

criterion_group!(benches, bench, lookups);
criterion_main!(benches);
