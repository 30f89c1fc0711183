//! `fleet`: how many voxel summaries per second one base station takes into one SQLite map database
//! when its robots arrive on 1, 4, 16 and 64 links at once — the whole path the CLI runs (a reader
//! thread per TCP connection, one receiving loop, per-link decoders, the exact merge, commits every
//! 250 ms with the acknowledgements written back after each) — and what bounds it: the same bytes applied
//! in memory on one thread (no database), and the commits' share.
//!
//! The streams: 64 robots (their own ids and sessions), 40 scans each along the streaming tests' street,
//! written once; with N links each link carries 64 / N robots' streams one after another, so every run
//! moves the same summaries. Each connection writes as fast as the loop reads. Run:
//! `cargo bench -p host-sim --bench fleet`; it prints one line per link count (median of 3 runs).

#[path = "../tests/stream_common/mod.rs"]
mod stream_common;

use host_sim::base_station::store::SqliteStore;
use host_sim::base_station::BaseStation;
use host_sim::cli::station::links::{spawn_link, LinkIds, Source};
use host_sim::cli::station::{channel, pump, PumpOptions};
use host_sim::link::SplitMix;
use latentbki::wire::SummaryCodec;
use std::io::Write;
use std::net::{TcpListener, TcpStream};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::{Duration, Instant};
use stream_common::*;

const ROBOTS: u16 = 64;

/// Each robot's whole stream.
fn streams() -> Vec<Vec<u8>> {
    let world = World::new(SummaryCodec::DEFAULT);
    (1..=ROBOTS)
        .map(|robot| {
            let mut rig = RobotRig::new(&world, robot, 2.5);
            let mut rng = SplitMix::new(u64::from(robot));
            let y = 0.25 * f32::from(robot % 16);
            for i in 0..40 {
                let x = 1.0 + 0.3 * i as f32 + f32::from(robot / 16) * 12.0;
                let (pose, pts, feats) = scan(&world, &mut rng, x, y, 300, 1.6);
                rig.step(&pose, &pts, &feats, 16_384);
            }
            rig.finish();
            std::mem::take(&mut rig.uart.0)
        })
        .collect()
}

/// One run over `links` TCP connections into a fresh database: (final summaries merged, seconds).
fn run(streams: &[Vec<u8>], links: usize, dir: &std::path::Path, n: usize) -> (u64, f64) {
    let db = dir.join(format!("fleet-{links}-{n}.db"));
    let mut store = SqliteStore::open(&db).unwrap();
    let mut base = BaseStation::<D>::open(&mut store).unwrap();
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    // Link i carries robots i, i + links, …
    let payloads: Vec<Vec<u8>> = (0..links)
        .map(|l| {
            streams
                .iter()
                .skip(l)
                .step_by(links)
                .flat_map(|s| s.iter().copied())
                .collect()
        })
        .collect();
    let start = Instant::now();
    let clients: Vec<_> = payloads
        .into_iter()
        .map(|p| {
            std::thread::spawn(move || {
                let mut c = TcpStream::connect(addr).unwrap();
                c.write_all(&p).unwrap();
                c.shutdown(std::net::Shutdown::Write).unwrap();
                // Read the acknowledgements until the base station closes its side.
                let _ = std::io::copy(&mut c, &mut std::io::sink());
            })
        })
        .collect();
    let (tx, events) = channel();
    let ids = LinkIds::default();
    for _ in 0..links {
        let (s, peer) = listener.accept().unwrap();
        let source = Source {
            name: peer.to_string(),
            read: Box::new(s.try_clone().unwrap()),
            write: Some(Box::new(s)),
        };
        spawn_link(tx.clone(), &ids, source);
    }
    drop(tx);
    let options = PumpOptions {
        commit_every: Duration::from_millis(250),
        duration: None,
        stop: Arc::new(AtomicBool::new(false)),
    };
    pump(&mut base, Some(&mut store), &events, &options).unwrap();
    let took = start.elapsed().as_secs_f64();
    drop(base);
    drop(store);
    for c in clients {
        let _ = c.join();
    }
    let mut check = SqliteStore::open_read_only(&db).unwrap();
    let b = BaseStation::<D>::open(&mut check).unwrap();
    let s = b.sessions();
    assert_eq!(s.len(), usize::from(ROBOTS));
    assert!(s.values().all(|v| v.seq.lost == 0));
    let summaries: u64 = b
        .map()
        .unwrap()
        .voxels()
        .map(|(_, v)| v.closed.len() as u64)
        .sum();
    (summaries, took)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    // `cargo bench` passes `--bench`; a filter that is not "fleet" skips the run.
    if std::env::args()
        .skip(1)
        .any(|a| !a.starts_with('-') && !"fleet".contains(a.as_str()))
    {
        return;
    }
    let streams = streams();
    let bytes: usize = streams.iter().map(Vec::len).sum();
    // What bounds it: the apply alone, on one thread, in memory.
    let mut apply = Vec::new();
    let (mut summaries, mut merged) = (0, 0);
    for _ in 0..3 {
        let mut base = BaseStation::<D>::adopting();
        let t = Instant::now();
        for s in &streams {
            base.receive(s);
        }
        apply.push(t.elapsed().as_secs_f64());
        let st = base.stats();
        summaries = u64::from(st.merged + st.updated + st.ignored);
        merged = u64::from(st.merged);
    }
    let apply = median(apply);
    println!(
        "fleet: {ROBOTS} robots, {summaries} summaries, {:.1} MB of frames ({:.1} B per summary); applied in memory on one thread: {:.0} summaries/s",
        bytes as f64 / 1e6,
        bytes as f64 / summaries as f64,
        summaries as f64 / apply
    );
    let dir = tempfile::tempdir().unwrap();
    for links in [1, 4, 16, 64] {
        let mut rates = Vec::new();
        for n in 0..3 {
            let (m, t) = run(&streams, links, dir.path(), n);
            assert_eq!(m, merged, "the database holds every final summary once");
            rates.push(summaries as f64 / t);
        }
        let r = median(rates.clone());
        rates.sort_by(f64::total_cmp);
        println!(
            "fleet {links} links -> one SQLite database (commits every 250 ms, acknowledgements after each): median {r:.0} summaries/s (min {:.0}, max {:.0}; {:.1} MB/s of frames)",
            rates[0],
            rates[rates.len() - 1],
            r * bytes as f64 / summaries as f64 / 1e6
        );
    }
}
