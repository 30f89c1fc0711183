//! How the number of hot (f32) voxels `H` trades RAM for re-encodes on the device.
//!
//! A point accumulates into its voxel's hot f32 statistics; a voxel is quantized (decoded, merged,
//! re-encoded) only when it cools — when another voxel needs its hot entry. This runs the firmware
//! self-test's sensor patterns — 4,096-point depth frames (`latentbki_selftest::SELF_TEST[1]`; a point
//! updates one voxel whatever f is), the 8×8 ToF and the 2D scanning LiDAR — through maps that differ only
//! in `H` and prints how many voxels cooled per 1,000 points, and the hot tier's size. Deterministic: counts, not timings.
//! Run: `cargo run --release -p host-sim --example hot_sweep`.

use latentbki::{
    key::to_map_frame, local_map::LocalMap, obs::ObsStats, packed_len, sink::Evicted,
    sink::SinkFull,
};
use latentbki_selftest::SELF_TEST;

const D: usize = 64;
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
    row::<254>();
}
