//! The measurement build's view (`--features explorer-view`, `boards/measure.sh --explorer-view`; issue 21):
//! one candidate view the size of `host-sim explore`'s, scored after each frame, so that what one of the
//! explorer's views costs on the board is counted, not scaled from the 64-voxel wall.
//!
//! The view is the explorer's ray grid (`host-sim/src/explore/world.rs`, `RAYS`: 24 × 18 rays over a 640 ×
//! 480 camera 70° wide, 0.1–6 m) cast from the frame's own pose against the self-test room's surfaces: each
//! ray is one expected point in the voxel it hits (the board's 0.1 m voxels, so rays that land in one voxel
//! add up). The 432 hits (16 B each, 6,912 B) live in a static: the forgetting build's stack has 432 B to
//! spare. Casting, sorting and counting the voxels the view reaches run outside the counted region; only
//! `info_gain::view_score` is counted.

use crate::{Map, Markers};
use latentbki::key::VoxelKey;
use latentbki_selftest::{DepthSensor, Layout, Scenario};

/// Rays per view: `host-sim explore`'s `RAYS`.
pub const RAYS: (u16, u16) = (24, 18);
/// One expected point per ray, at most one hit each.
pub const HITS: usize = RAYS.0 as usize * RAYS.1 as usize;
/// The hits of one view, sorted by key, without repeats.
pub type Hits = [(VoxelKey, f32); HITS];

/// The explorer's camera as a grid of rays: tan(35°) across, × 480 / 640 down (`DepthCamera::default`).
const CAMERA: DepthSensor = DepthSensor {
    layout: Layout::Frustum,
    width: RAYS.0,
    height: RAYS.1,
    tan_half_x: 0.700_207_5,
    tan_half_y: 0.700_207_5 * 480.0 / 640.0,
    max_range: 6.0,
    range_noise: 0.0,
};
/// Nearest depth the explorer's camera returns (m).
const MIN_DEPTH: f32 = 0.1;

/// Cast the view's rays from frame `frame`'s pose, score the view against `m` (counted between the
/// markers) and report a `view` line: the hits (distinct voxels), the voxels the kernel reaches from them,
/// and the score's bits.
#[inline(never)]
pub fn score<M: Markers + Default>(
    s: usize,
    scenario: &Scenario,
    frame: u32,
    m: &Map,
    hits: &mut Hits,
) {
    let n = cast(scenario, frame, m, hits);
    let hits = &hits[..n];
    let score_bits = counted::<M>(m, hits);
    report!(
        "view s={} rays={} voxels={} reached={} score_bits={}",
        s,
        HITS,
        n,
        reached(m, hits),
        score_bits
    );
}

/// The counted region: `info_gain::view_score` between the markers (0 if it refuses the view). Out of
/// line, as [`cast`] and [`reached`]: the window's ring (4 KiB) is on the stack only while it runs, and
/// the sort's scratch is not stacked on it.
#[inline(never)]
fn counted<M: Markers + Default>(m: &Map, hits: &[(VoxelKey, f32)]) -> u32 {
    let mut probe = M::default();
    probe.start();
    let score = latentbki::info_gain::view_score(m.kernel(), m, m.prior().lambda, hits);
    probe.stop();
    M::report();
    score.map_or(0, f32::to_bits)
}

/// The view's hits: each ray that returns a depth in range adds one point to the voxel it hits; sorted by
/// key, repeats merged. Returns how many.
#[inline(never)]
fn cast(scenario: &Scenario, frame: u32, m: &Map, hits: &mut Hits) -> usize {
    let view = scenario.scene.view(frame);
    let inv = m.kernel().inv_voxel_size();
    let mut n = 0;
    for zone in 0..CAMERA.zones() {
        let ray = CAMERA.ray(zone);
        let dir = view.to_map(ray);
        let (t, _) = scenario.scene.room.cast(view.origin, dir);
        let depth = t * ray[2];
        if !(MIN_DEPTH..=CAMERA.max_range).contains(&depth) {
            continue;
        }
        let p: [f32; 3] = core::array::from_fn(|i| view.origin[i] + t * dir[i]);
        if let Ok(key) = VoxelKey::from_position(p, inv) {
            hits[n] = (key, 1.0);
            n += 1;
        }
    }
    // Sorted by insertion, not `sort_unstable`: its quicksort recurses with 820 B frames, which put the
    // stack over 8 KiB; this runs outside the counted region, where its ≈ n²/4 moves do not count.
    for r in 1..n {
        let mut i = r;
        while i > 0 && hits[i - 1].0 > hits[i].0 {
            hits.swap(i - 1, i);
            i -= 1;
        }
    }
    // Merge the repeats (rays in one voxel): their points add up.
    let mut w = 0;
    for r in 0..n {
        if w > 0 && hits[w - 1].0 == hits[r].0 {
            hits[w - 1].1 += hits[r].1;
        } else {
            hits[w] = hits[r];
            w += 1;
        }
    }
    w
}

/// How many voxels the view reaches: the distinct voxels within the kernel's offsets of a hit. Each is
/// counted by the first hit (in key order) that reaches it. The keys are x-major, so the earlier hits that
/// can reach a voxel around hit j lie in the x planes within twice the kernel's reach of it.
#[inline(never)]
fn reached(m: &Map, hits: &[(VoxelKey, f32)]) -> usize {
    let offsets = m.kernel().offsets();
    let reach = m.kernel().reach();
    let reaches = |g: &VoxelKey, k: &VoxelKey| {
        let d = [k.x - g.x, k.y - g.y, k.z - g.z];
        d.iter().all(|c| c.abs() <= reach)
            && offsets
                .iter()
                .any(|o| (0..3).all(|i| i32::from(o[i]) == d[i]))
    };
    let mut count = 0;
    for (j, (h, _)) in hits.iter().enumerate() {
        let from = hits[..j].partition_point(|(g, _)| g.x < h.x - 2 * reach);
        for o in offsets {
            let k = VoxelKey::new(
                h.x + i32::from(o[0]),
                h.y + i32::from(o[1]),
                h.z + i32::from(o[2]),
            );
            if !hits[from..j].iter().any(|(g, _)| reaches(g, &k)) {
                count += 1;
            }
        }
    }
    count
}
