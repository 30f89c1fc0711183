//! What a held voxel is worth in answerable voxels, by map size: the figure behind `boards/measure.sh`'s
//! "answerable voxels per KiB of map RAM" (issue 18).
//!
//! Runs the firmware self-test's full-map scenario (`full_map`: 24 depth frames of the room, f = 3) — the
//! same `Mapper`, scene and configuration as the board — through maps that differ only in their capacity, and
//! prints, after the last frame, the voxels held, the voxels answerable (held, or within the kernel's reach
//! of a held one: `LocalMap::answerable`), the map's RAM at today's bytes per voxel, answerable voxels per
//! KiB, and the bytes per held voxel (slot and index) that 35 per KiB would allow at that capacity with the
//! hot tier and the rest as they are. On these dense surfaces the held voxels' neighbourhoods overlap more as
//! the map grows, so a narrower slot that buys more voxels in the same RAM buys few answerable ones.
//! Deterministic: counts, not timings. Run: `cargo run --release -p host-sim --example answerable_sweep`.

use latentbki::local_map::LocalMap;
use latentbki::quant::packed_len;
use latentbki::Mapper;
use latentbki_selftest::{
    self as selftest, Chunk, SELF_TEST, SELF_TEST_CAPACITY, SELF_TEST_FRAME_BYTES,
    SELF_TEST_QUEUE_BYTES,
};

use host_sim::sim::vocab::D;
const P: usize = packed_len(D);
/// The per-KiB goal of issue 18.
const GOAL: f64 = 35.0;

fn row<const CAP: usize>() {
    type Map<const CAP: usize> = LocalMap<D, CAP, P>;
    let mut mapper =
        Box::new(Mapper::<D, CAP, P, SELF_TEST_QUEUE_BYTES, SELF_TEST_FRAME_BYTES>::EMPTY);
    let mut chunk = Box::new(Chunk::<D, 16>::ZERO);
    let scenario = SELF_TEST
        .iter()
        .find(|s| s.name == "full_map")
        .expect("the self-test has a full-map scenario");
    scenario.configure(&mut mapper).expect("self-test setup");
    let mut buf = vec![0u8; 8 << 20]; // the frames the board would send
    let mut uart: &mut [u8] = &mut buf[..];
    let (mut held, mut answerable) = (0, 0);
    selftest::run(
        scenario,
        &mut mapper,
        &mut chunk,
        &mut uart,
        &mut (),
        |i, _, m| {
            if i + 1 == scenario.frames {
                (held, answerable) = (m.len(), m.answerable());
            }
        },
    )
    .expect("self-test run");
    let ram = Map::<CAP>::RAM_BYTES as f64;
    let rest = ram - (CAP * Map::<CAP>::BYTES_PER_VOXEL) as f64;
    let allowed = (answerable as f64 / GOAL * 1024.0 - rest) / CAP as f64;
    println!(
        "| {CAP}{} | {held} | {answerable} | {:.2} | {:.1} | {:.1} | {allowed:.0} |",
        if CAP == SELF_TEST_CAPACITY {
            " (the board's)"
        } else {
            ""
        },
        answerable as f64 / held.max(1) as f64,
        ram / 1024.0,
        answerable as f64 / (ram / 1024.0),
    );
}

fn main() {
    println!(
        "full-map scenario, f = 3, {} B per held voxel (slot and index), hot tier and the rest {} B",
        LocalMap::<D, 1, P>::BYTES_PER_VOXEL,
        LocalMap::<D, 0, P>::RAM_BYTES
    );
    println!("| capacity | held | answerable | per held | map RAM (KiB) | per KiB | B/voxel for {GOAL} per KiB |");
    println!("|---:|---:|---:|---:|---:|---:|---:|");
    row::<800>();
    row::<1_000>();
    // 1,228: the board's at 120 B per voxel (one row when the board's is that).
    if SELF_TEST_CAPACITY != 1_228 {
        row::<1_228>();
    }
    row::<SELF_TEST_CAPACITY>();
    row::<1_600>();
    row::<2_000>();
    row::<3_000>();
}
