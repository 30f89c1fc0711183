//! How the batch scratch size `G` (source-voxel groups held before a flush) trades RAM for re-encodes.
//!
//! Every flush decodes and re-encodes each voxel its groups reach, so a neighbour shared by groups of two
//! flushes is re-encoded twice. This runs the firmware self-test's 4,096-point depth frames (f = 1 and
//! f = 3, `synth::SELF_TEST[1..]`) through maps that differ only in `G` and prints the slot writes
//! (allocations + re-encodes + evictions) and the scratch's size. Deterministic: counts, not timings.
//! Run: `cargo run --release -p host-sim --example scratch_sweep`.

use latentbki::synth::SELF_TEST;
use latentbki::{packed_len, to_map_frame, Evicted, LocalMap, SinkFull, VoxelStats};

const D: usize = 64;
const P: usize = packed_len(D);
const CAP: usize = latentbki::synth::SELF_TEST_CAPACITY;

fn discard(_: Evicted<'_, D>) -> Result<(), SinkFull> {
    Ok(())
}

fn writes<const G: usize>(scenario: usize) -> u32 {
    let sc = &SELF_TEST[scenario];
    let mut map = Box::new(LocalMap::<D, CAP, P, G>::EMPTY);
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
        map.end_batch(&mut discard);
    }
    map.counters().slots_written
}

fn row<const G: usize>() {
    let group_bytes = core::mem::size_of::<VoxelStats<D>>() + 16;
    println!(
        "| {G} | {:.1} KiB | {} | {} |",
        (G * group_bytes) as f32 / 1024.0,
        writes::<G>(1),
        writes::<G>(2)
    );
}

fn main() {
    println!("| G | scratch | slot writes, f = 1 (8 × 4,096 points) | slot writes, f = 3 |");
    println!("|---|---|---|---|");
    row::<8>();
    row::<16>();
    row::<32>();
    row::<64>();
    row::<128>();
    row::<512>();
}
