//! How the number of hot (f32) voxels `H` trades RAM for re-encodes on the device.
//!
//! A point accumulates into its voxel's hot f32 statistics; a voxel is quantized (decoded, merged,
//! re-encoded) only when it cools — when another voxel needs its hot entry. This runs the firmware
//! self-test's sensor patterns — 4,096-point depth frames (`latentbki_selftest::SELF_TEST[1]`; a point
//! updates one voxel whatever f is), the 8×8 ToF and the 2D scanning LiDAR — through maps that differ only
//! in `H` and prints how many voxels cooled per 1,000 points, and the hot tier's size. A second table gives
//! the floor no replacement policy can beat: Belady's optimum (evict the hot voxel needed again furthest in
//! the future, which needs the future) on each pattern's sequence of voxels, and the first visits (distinct
//! voxels), which every policy pays at any `H`. Deterministic: counts, not timings.
//! Run: `cargo run --release -p host-sim --example hot_sweep`.

use latentbki::{
    key::to_map_frame, local_map::LocalMap, obs::ObsStats, packed_len, sink::Evicted,
    sink::SinkFull,
};
use latentbki_selftest::SELF_TEST;
use std::collections::{BTreeSet, HashMap};

use host_sim::sim::vocab::D;
const P: usize = packed_len(D);
const CAP: usize = latentbki_selftest::SELF_TEST_CAPACITY;

fn discard(_: Evicted<'_, D>) -> Result<(), SinkFull> {
    Ok(())
}

/// (points integrated, voxels cooled) over self-test scenario `s`.
fn cooled<const H: usize>(s: usize) -> (u32, u32) {
    let sc = &SELF_TEST[s];
    let mut map = Box::new(LocalMap::<D, CAP, P, H>::EMPTY);
    map.configure(sc.map_config().expect("self-test config"), sc.window_radius)
        .expect("self-test window");
    let mut y = [0.0f32; D];
    for frame in 0..sc.frames {
        let view = sc.scene.view(frame);
        let pose = view.pose();
        map.move_window(view.origin, &mut discard);
        for zone in 0..sc.scene.sensor.zones() {
            if let Some(o) = sc.scene.observe(&view, frame, zone, &mut y) {
                let _ = map.add_point(to_map_frame(&pose, o.point), &y, &mut discard);
            }
        }
    }
    let c = map.counters();
    (c.points, c.cooled)
}

/// Scenario `s`'s points as the sequence of their voxels (dense ids in order of first visit).
fn voxel_sequence(s: usize) -> Vec<u32> {
    let sc = &SELF_TEST[s];
    let inv_voxel = 1.0 / sc.map_config().expect("self-test config").voxel_size();
    let mut ids: HashMap<[i32; 3], u32> = HashMap::new();
    let mut seq = Vec::new();
    let mut y = [0.0f32; D];
    for frame in 0..sc.frames {
        let view = sc.scene.view(frame);
        let pose = view.pose();
        for zone in 0..sc.scene.sensor.zones() {
            if let Some(o) = sc.scene.observe(&view, frame, zone, &mut y) {
                let p = to_map_frame(&pose, o.point);
                if let Ok(k) = latentbki::key::VoxelKey::from_position(p, inv_voxel) {
                    let next = ids.len() as u32;
                    seq.push(*ids.entry(k.as_array()).or_insert(next));
                }
            }
        }
    }
    seq
}

/// Fewest hot-tier misses (a miss = a voxel entering the tier, so one cooling) of any replacement policy
/// with `h` entries: Belady's MIN, which evicts the entry whose next use is furthest away.
fn belady_misses(seq: &[u32], h: usize) -> usize {
    let mut next_use = vec![usize::MAX; seq.len()];
    let mut seen: HashMap<u32, usize> = HashMap::new();
    for (t, v) in seq.iter().enumerate().rev() {
        next_use[t] = seen.insert(*v, t).unwrap_or(usize::MAX);
    }
    let mut held: HashMap<u32, usize> = HashMap::new(); // voxel → its next use
    let mut by_next: BTreeSet<(usize, u32)> = BTreeSet::new();
    let mut misses = 0;
    for (t, &v) in seq.iter().enumerate() {
        if let Some(n) = held.insert(v, next_use[t]) {
            by_next.remove(&(n, v));
        } else {
            misses += 1;
            if by_next.len() == h {
                if let Some(far) = by_next.pop_last() {
                    held.remove(&far.1);
                }
            }
        }
        by_next.insert((next_use[t], v));
    }
    misses
}

fn floor_row(name: &str, s: usize) {
    let seq = voxel_sequence(s);
    let per_k = |n: usize| 1000.0 * n as f32 / seq.len().max(1) as f32;
    let distinct = seq.iter().copied().max().map_or(0, |m| m as usize + 1);
    print!(
        "| {name} | {} | {distinct} | {:.0} |",
        seq.len(),
        per_k(distinct)
    );
    for h in [8, 32, 128, 144, 160, 192, 254] {
        print!(" {:.0} |", per_k(belady_misses(&seq, h)));
    }
    println!();
}

fn row<const H: usize>() {
    let hot_bytes = core::mem::size_of::<ObsStats<D>>() + 20;
    let per_k = |s: usize| {
        let (points, c) = cooled::<H>(s);
        1000.0 * c as f32 / points.max(1) as f32
    };
    println!(
        "| {H} | {:.1} KiB | {:.0} | {:.0} | {:.0} |",
        (H * hot_bytes) as f32 / 1024.0,
        per_k(1),
        per_k(named("tof_f3")),
        per_k(named("lidar_f3")),
    );
}

/// The self-test scenario of that name.
fn named(name: &str) -> usize {
    SELF_TEST
        .iter()
        .position(|s| s.name == name)
        .expect("a self-test scenario")
}

fn main() {
    println!("| H | hot tier | cooled per 1,000 points: depth frames | 8×8 ToF | 2D LiDAR |");
    println!("|---|---|---|---|---|");
    row::<8>();
    row::<16>();
    row::<32>();
    row::<64>();
    row::<128>();
    row::<144>();
    row::<160>();
    row::<192>();
    row::<254>();
    println!();
    println!("| pattern | points | distinct voxels | first visits per 1,000 points (any H) | fewest coolings per 1,000 points, any policy (Belady): H = 8 | 32 | 128 | 144 | 160 | 192 | 254 |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    floor_row("depth frames", 1);
    floor_row("8×8 ToF", named("tof_f3"));
    floor_row("2D LiDAR", named("lidar_f3"));
}
