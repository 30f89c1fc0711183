//! The on-device map's bookkeeping: every point counted exactly once through cooling and evictions, window
//! moves that copy nothing, bounded lookups, bad input, a sink that refuses, and posteriors gathered from the
//! quantized statistics.

use latentbki::nalgebra::{Isometry3, Translation3};
use latentbki::{
    key::VoxelKey, local_map::LocalMap, obs::ObsStats, packed_len, sink::Evicted, sink::SinkFull,
    stats::VoxelStats, MapConfig,
};
use std::collections::HashMap;

const D: usize = 16;
const P: usize = packed_len(D);

fn boxed<const CAP: usize>(window: f32) -> Box<LocalMap<D, CAP, P>> {
    let mut m = Box::new(LocalMap::<D, CAP, P>::EMPTY);
    m.configure(MapConfig::default(), window).unwrap();
    m
}

/// Deterministic points on a corridor floor and walls around x, with class-like features.
fn frame(seed: u32, x: f32, n: usize) -> (Vec<[f32; 3]>, Vec<[f32; D]>) {
    let mut s = seed.wrapping_mul(747796405).max(1);
    let mut r = move || {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        s as f32 / u32::MAX as f32
    };
    let mut pts = Vec::new();
    let mut feats = Vec::new();
    for _ in 0..n {
        let wall = r() < 0.5;
        let p = if wall {
            [
                x + r() * 2.0 - 1.0,
                if r() < 0.5 { -1.0 } else { 1.0 },
                r() * 2.0,
            ]
        } else {
            [x + r() * 2.0 - 1.0, r() * 2.0 - 1.0, 0.0]
        };
        let mut y = [0.0f32; D];
        y[usize::from(wall)] = 1.0;
        for v in y.iter_mut() {
            *v += (r() - 0.5) * 0.2;
        }
        pts.push(p);
        feats.push(y);
    }
    (pts, feats)
}

#[derive(Default)]
struct Collect {
    points: f64,
    voxels: Vec<(VoxelKey, u32, ObsStats<D>)>,
    refuse: bool,
}

impl latentbki::sink::EvictionSink<D> for Collect {
    fn evict(&mut self, v: Evicted<'_, D>) -> Result<(), SinkFull> {
        if self.refuse {
            return Err(SinkFull);
        }
        self.points += f64::from(v.obs.count);
        self.voxels.push((v.key, v.residency, *v.obs));
        Ok(())
    }
}

#[test]
fn bytes_per_voxel() {
    let b = LocalMap::<64, 2048, { packed_len(64) }>::BYTES_PER_VOXEL;
    println!(
        "bytes per voxel at D = 64: {b} (slot + index); f32 posterior: {}",
        core::mem::size_of::<VoxelStats<64>>()
    );
    assert!(b < core::mem::size_of::<VoxelStats<64>>() / 3);
}

/// `RAM_BYTES` is the map's size: exactly when every part is a whole number of 8-byte words (so always on a
/// 32-bit MCU, whose words are 4 bytes: the firmware sizes its map from it, `CAP` = budget /
/// `BYTES_PER_VOXEL`), and within one word of it on a 64-bit host otherwise (a hot entry of D = 13 is
/// 132 bytes, an odd `CAP`'s index half a word: the compiler packs small fields into the rest).
#[test]
fn ram_bytes_is_the_maps_size() {
    use core::mem::size_of;
    type Board = LocalMap<64, 1228, { packed_len(64) }>;
    assert_eq!(Board::RAM_BYTES, size_of::<Board>());
    type Even = LocalMap<13, 78, { packed_len(13) }, 4>;
    assert_eq!(Even::RAM_BYTES, size_of::<Even>());
    for (formula, size) in [
        (
            LocalMap::<13, 77, { packed_len(13) }, 5>::RAM_BYTES,
            size_of::<LocalMap<13, 77, { packed_len(13) }, 5>>(),
        ),
        (
            LocalMap::<64, 1228, { packed_len(64) }, 33>::RAM_BYTES,
            size_of::<LocalMap<64, 1228, { packed_len(64) }, 33>>(),
        ),
    ] {
        assert!(formula.abs_diff(size) <= 8, "{formula} vs {size}");
    }
}

#[test]
fn every_point_is_counted_once_through_pressure_and_moves() {
    let mut map = boxed::<600>(1.5);
    let mut sink = Collect::default();
    let mut points = 0;
    for step in 0..60 {
        let x = step as f32 * 0.25;
        let (p, f) = frame(step, x, 400);
        let pose = Isometry3::from_parts(Translation3::new(x, 0.0, 0.5), Default::default());
        // Points are generated in the map frame around x; the pose only moves the window.
        let local: Vec<[f32; 3]> = p.iter().map(|q| [q[0] - x, q[1], q[2] - 0.5]).collect();
        points += map.integrate(&pose, &local, &f, &mut sink);
    }
    assert!(
        sink.voxels.len() > 1000,
        "capacity pressure and moves must evict: {}",
        sink.voxels.len()
    );
    assert!(points > 20_000);
    let in_map: f64 = map.iter().map(|v| f64::from(v.obs.count)).sum();
    println!(
        "integrated {points}, in the map {in_map}, emitted {}, cooled {}",
        sink.points,
        map.counters().cooled
    );
    // Counts are exact: every point is in the map or was emitted, once.
    assert_eq!(in_map + sink.points, points as f64);
    assert!(
        map.counters().cooled > 1000,
        "the hot tier must cool voxels"
    );
    // The same voxel evicted twice comes with two residencies.
    let mut seen: HashMap<(VoxelKey, u32), usize> = HashMap::new();
    for (k, r, _) in &sink.voxels {
        *seen.entry((*k, *r)).or_default() += 1;
    }
    assert!(
        seen.values().all(|&c| c == 1),
        "a residency is emitted once"
    );
}

#[test]
fn window_moves_copy_nothing_and_lookups_stay_short() {
    let mut map = boxed::<4096>(2.0);
    let mut sink = Collect::default();
    let (p, f) = frame(1, 0.0, 3000);
    map.integrate(&Isometry3::identity(), &p, &f, &mut sink);
    let (mut mean_probe, mut max_probe) = (0.0f32, 0);
    for step in 1..=1000 {
        let before = map.counters();
        let x = step as f32 * 0.05;
        let evicted = map.move_window([x, 0.0, 0.0], &mut sink);
        let after = map.counters();
        // Only evicted slots are written; the rest of the map is not touched.
        assert_eq!(
            after.slots_written - before.slots_written,
            evicted as u32,
            "move {step}"
        );
        if step % 50 == 0 {
            let (p, f) = frame(step, x, 2000);
            let local: Vec<[f32; 3]> = p.iter().map(|q| [q[0] - x, q[1], q[2]]).collect();
            map.integrate(&Isometry3::translation(x, 0.0, 0.0), &local, &f, &mut sink);
            let (mean, max) = map.probe_stats();
            mean_probe = mean_probe.max(mean);
            max_probe = max_probe.max(max);
        }
    }
    println!("probe runs over the trajectory: worst mean {mean_probe:.2}, longest {max_probe}");
    assert!(
        mean_probe < 2.5,
        "lookup must stay O(1): mean probe run {mean_probe}"
    );
    assert!(max_probe <= 40, "longest probe run {max_probe}");
    // Everything left is inside the window (20 voxels): only voxels points fell in are stored.
    let c = map.centre();
    let worst = map.iter().map(|v| v.key.distance_squared(c)).max().unwrap();
    assert!(worst <= 20 * 20, "a voxel {worst} voxels² from the centre");
}

#[test]
fn bad_points_are_counted_and_never_stored() {
    let mut map = boxed::<256>(3.0);
    let mut sink = Collect::default();
    let pts = [
        [f32::NAN, 0.0, 0.0],
        [0.0, f32::INFINITY, 0.0],
        [0.0, 0.0, 0.0],
        [1e12, 0.0, 0.0],
        [50.0, 0.0, 0.0],
        [0.0; 3],
    ];
    let mut feats = [[0.5f32; D]; 6];
    feats[2][3] = f32::NAN;
    let n = map.integrate(&Isometry3::identity(), &pts, &feats, &mut sink);
    let r = map.rejections();
    assert_eq!(n, 1);
    assert_eq!(
        (
            r.non_finite_position,
            r.non_finite_feature,
            r.key_out_of_range,
            r.outside_window
        ),
        (2, 1, 1, 1)
    );
    assert!(map.iter().all(|v| v.obs.is_valid()));
    assert_eq!(map.get(VoxelKey::new(0, 0, 0)).unwrap().count, 1.0);
}

#[test]
fn unpaired_points_and_an_unconfigured_map_are_counted() {
    // More points than features, then more features than points: the extras are counted, the pairs taken.
    let mut map = boxed::<256>(3.0);
    let mut sink = Collect::default();
    let pts = [[0.05f32, 0.05, 0.05]; 5];
    let feats = [[0.5f32; D]; 5];
    let id = Isometry3::identity();
    assert_eq!(map.integrate(&id, &pts, &feats[..3], &mut sink), 3);
    assert_eq!(map.integrate(&id, &pts[..1], &feats, &mut sink), 1);
    assert_eq!(map.rejections().unpaired, 2 + 4);
    assert_eq!(map.rejections().total(), 6);
    assert_eq!(map.get(VoxelKey::new(0, 0, 0)).unwrap().count, 4.0);

    // A map never configured has no kernel: it refuses (and counts) rather than swallowing points.
    let mut blank = Box::new(LocalMap::<D, 256, P>::EMPTY);
    assert_eq!(blank.integrate(&id, &pts, &feats, &mut sink), 0);
    assert_eq!(blank.rejections().no_room, 5);
    assert!(blank.is_empty());
}

#[test]
fn a_refusing_sink_loses_nothing() {
    let mut map = boxed::<64>(3.0);
    let mut sink = Collect::default();
    let (p, f) = frame(3, 0.0, 500);
    let mut taken = map.integrate(&Isometry3::identity(), &p, &f, &mut sink);
    assert_eq!(map.len(), 64);
    let held: Vec<_> = map.iter().map(|v| (v.key, v.residency)).collect();
    sink.refuse = true;
    let (p, f) = frame(4, 0.0, 500);
    taken += map.integrate(&Isometry3::identity(), &p, &f, &mut sink);
    map.move_window([40.0, 0.0, 0.0], &mut sink);
    // Every voxel held is still held; refusals and rejected points are counted.
    let counters = map.counters();
    assert!(counters.refused > 0);
    assert!(map.rejections().no_room > 0);
    for (k, r) in &held {
        let v = map.iter().find(|v| v.key == *k).expect("voxel kept");
        assert_eq!(v.residency, *r);
    }
    let in_map: f64 = map.iter().map(|v| f64::from(v.obs.count)).sum();
    assert_eq!(in_map + sink.points, taken as f64, "nothing taken was lost");
    // Once the sink drains, the map empties completely into it.
    sink.refuse = false;
    let n = map.len();
    assert_eq!(map.flush(&mut sink), Ok(n));
    assert!(map.is_empty());
    assert_eq!(sink.points, taken as f64);
}

/// The gathered posterior of the quantized map follows the f32 gather of the same points (no eviction):
/// λ exact, μ within the codes' rounding.
#[test]
fn posteriors_gather_through_the_kernel() {
    let mut map = boxed::<4096>(3.0);
    let mut sink = Collect::default();
    let (p, f) = frame(5, 0.0, 3000);
    assert_eq!(
        map.integrate(&Isometry3::identity(), &p, &f, &mut sink),
        3000
    );
    assert!(sink.voxels.is_empty());
    let lut: latentbki::kernel::KernelLut =
        latentbki::kernel::KernelLut::new(&MapConfig::default()).unwrap();
    // f32 statistics of the same points, per voxel.
    let mut exact: HashMap<VoxelKey, ObsStats<D>> = HashMap::new();
    for (q, y) in p.iter().zip(&f) {
        let k = VoxelKey::from_position(*q, 10.0).unwrap();
        exact.entry(k).or_default().add_point(y);
    }
    struct Exact<'a>(&'a HashMap<VoxelKey, ObsStats<D>>);
    impl latentbki::obs::ObsLookup<D> for Exact<'_> {
        fn observed(&self, key: VoxelKey) -> Option<ObsStats<D>> {
            self.0.get(&key).copied()
        }
    }
    let prior = MapConfig::default().prior();
    let mut worst_mu = 0.0f32;
    let mut answerable = 0;
    for v in map.iter() {
        for o in lut.offsets() {
            let t = v.key.offset(*o);
            let got: VoxelStats<D> = map.posterior(t);
            let want = latentbki::obs::gather_posterior(&lut, &Exact(&exact), &prior, t).unwrap();
            assert!((got.lambda - want.lambda).abs() <= 1e-5 * want.lambda);
            let norm = want.mean.iter().map(|m| m * m).sum::<f32>().sqrt();
            let err = got
                .mean
                .iter()
                .zip(&want.mean)
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f32>()
                .sqrt();
            worst_mu = worst_mu.max(err / norm);
        }
    }
    for k in exact.keys() {
        for o in lut.offsets() {
            let t = k.offset(*o);
            let first = lut
                .offsets()
                .iter()
                .map(|p| t.offset(*p))
                .find(|n| exact.contains_key(n));
            if first == Some(*k) {
                answerable += 1;
            }
        }
    }
    println!(
        "worst relative μ error {worst_mu:.3}; answerable {}",
        map.answerable()
    );
    // One voxel's codes alone (a voxel in reach of no other) carry the codes' full rounding: 6-bit codes
    // with stochastic rounding stay within two steps per component, ≈ 2·√D·1.25/31/√D of a unit mean.
    assert!(worst_mu < 0.2, "μ relative error {worst_mu}");
    assert_eq!(map.answerable(), answerable);
    assert!(map.answerable() > 3 * map.len());
}

/// Every point handed to `integrate` is either integrated or counted as rejected, never both — also when
/// groups are refused for lack of room (a fuzzing finding).
#[test]
fn every_point_is_integrated_or_counted_once() {
    let mut map = boxed::<64>(3.0);
    let mut refuse = false;
    let mut sink = |_v: Evicted<'_, D>| {
        refuse = !refuse;
        if refuse {
            Err(SinkFull)
        } else {
            Ok(())
        }
    };
    for step in 0..20 {
        let (p, f) = frame(step, 0.0, 300);
        let before = map.rejections().total();
        let n = map.integrate(&Isometry3::identity(), &p, &f, &mut sink);
        let rejected = (map.rejections().total() - before) as usize;
        assert_eq!(n + rejected, p.len(), "step {step}");
    }
    assert!(
        map.rejections().no_room > 0,
        "the test must exercise refused groups"
    );
}

#[test]
fn residency_numbers_never_repeat_past_16_bits() {
    // A small pool swept along a 400 m line and back, ten times: every allocation evicts a voxel, over 2¹⁶ of
    // them. Each eviction closes one residency; the base station tells a voxel's contributions apart by
    // (key, residency), so no residency may be handed out twice — least of all to a revisited voxel.
    let mut map = boxed::<64>(1_500.0);
    let mut sink = Collect::default();
    let y = [1.0f32; D];
    // A point updates only its own voxel: ten passes up and down a 400 m line.
    let xs = (0..10).flat_map(|_| (0..4_000).chain((0..4_000).rev()));
    for x in xs {
        map.add_point([x as f32 * 0.1 + 0.05, 0.05, 0.05], &y, &mut sink)
            .unwrap();
    }
    map.flush(&mut sink).unwrap();
    let mut residencies: Vec<u32> = sink.voxels.iter().map(|v| v.1).collect();
    let n = residencies.len();
    assert!(n > 1 << 16, "only {n} evictions: the test must pass 2¹⁶");
    residencies.sort_unstable();
    residencies.dedup();
    assert_eq!(
        residencies.len(),
        n,
        "a residency number was handed out twice"
    );
    let revisited = {
        let mut keys: Vec<VoxelKey> = sink.voxels.iter().map(|v| v.0).collect();
        keys.sort_unstable();
        let all = keys.len();
        keys.dedup();
        all - keys.len()
    };
    assert!(revisited > 1_000, "the sweep back must re-allocate voxels");
}

/// A hot voxel the window left behind (its eviction refused) is still refused as outside the window,
/// whether it is the previous point's voxel or one the map finds without its index; once the sink takes
/// it, it leaves, and points there stay refused.
#[test]
fn a_stranded_hot_voxel_refuses_points() {
    let mut m = boxed::<64>(1.0);
    let mut sink = Collect {
        refuse: true,
        ..Collect::default()
    };
    let y = [0.5f32; D];
    let (a, b) = ([0.05, 0.05, 0.05], [0.25, 0.05, 0.05]);
    for _ in 0..3 {
        m.add_point(a, &y, &mut sink).unwrap();
        m.add_point(b, &y, &mut sink).unwrap();
    }
    let before = m.get(VoxelKey::new(0, 0, 0)).unwrap();
    // 5 m away: both voxels are outside the 1 m window, and the sink refuses them.
    m.move_window([5.0, 0.0, 0.0], &mut sink);
    let outside = m.rejections().outside_window;
    // `b` was the previous point's voxel, `a` is found as a recent hot voxel: both refused.
    assert!(m.add_point(b, &y, &mut sink).is_err());
    assert!(m.add_point(a, &y, &mut sink).is_err());
    assert_eq!(m.rejections().outside_window, outside + 2);
    assert_eq!(m.get(VoxelKey::new(0, 0, 0)).unwrap(), before);
    // The sink takes them at the next move: gone, and still refused.
    sink.refuse = false;
    m.move_window([5.0, 0.0, 0.0], &mut sink);
    assert!(m.get(VoxelKey::new(0, 0, 0)).is_none());
    assert!(m.add_point(a, &y, &mut sink).is_err());
    assert_eq!(m.rejections().outside_window, outside + 3);
    assert_eq!(sink.points, 6.0);
}

/// A window move keeps exactly the voxels within its radius of the new centre — after steps, long jumps
/// (the offset test on wrapped keys) and a jump beyond 2³⁰ voxels (the full keys) — and a voxel a refusing
/// sink did not take stays, to leave at the next move; nothing is lost on the way.
#[test]
fn a_move_keeps_exactly_the_voxels_within_the_radius() {
    let radius = 1.0f32; // 10 voxels of 0.1 m
    let mut map = boxed::<2048>(radius);
    let mut sink = Collect::default();
    let r2 = 10i64 * 10;
    let mut added = 0usize;
    // Metres: steps, a long jump, back, and a jump of 1.5 · 10⁸ m (1.5 · 10⁹ voxels, beyond 2³⁰).
    let path = [0.05, 0.3, 0.45, 7.0, 7.2, -3.0, 1.5e8, 1.5e8 + 0.35, 0.0];
    for (i, &x) in path.iter().enumerate() {
        // Refuse every eviction of the fourth move: its leavers stay (stranded) until the fifth.
        sink.refuse = i == 3;
        let before = sink.voxels.len();
        let held_before = map.len();
        let evicted = map.move_window([x, 0.0, 0.0], &mut sink);
        assert_eq!(evicted, sink.voxels.len() - before, "move {i}");
        assert_eq!(map.len(), held_before - evicted, "move {i}");
        let c = map.centre();
        if i != 3 {
            // Everything held is inside; everything evicted was outside.
            assert!(
                map.iter().all(|v| v.key.distance_squared(c) <= r2),
                "move {i}: a held voxel outside the window"
            );
            assert!(
                sink.voxels[before..]
                    .iter()
                    .all(|(k, _, _)| k.distance_squared(c) > r2),
                "move {i}: an evicted voxel was inside"
            );
        } else {
            assert_eq!(evicted, 0, "a refusing sink takes nothing");
        }
        // Fill the window around the new centre (its points in the sensor frame at the centre).
        let (p, f) = frame(i as u32 + 7, 0.0, 300);
        let pose = Isometry3::from_parts(Translation3::new(x, 0.0, 0.0), Default::default());
        added += map.add_points(&pose, &p, &f, &mut sink);
    }
    // Every point is either held or was evicted, once.
    let held: f64 = map.iter().map(|v| f64::from(v.obs.count)).sum();
    assert_eq!(held + sink.points, added as f64);
}

/// A voxel a refusing sink keeps while the robot travels holds the window's centre where moving it would
/// take the voxel's key out of the wrap range (2¹⁵ voxels on an axis): the centre follows the robot exactly
/// until then, the voxel stays readable, and it leaves (the centre moving) once the sink takes it. (A move
/// looks for such a key only once the distance travelled since the last move that left nothing outside
/// could have taken one there: this fails if that bound undercounts.)
#[test]
fn a_stranded_voxel_holds_the_centre_at_the_wrap_range() {
    let mut map = boxed::<64>(1.0); // 0.1 m voxels, a 10-voxel radius
    let mut sink = Collect::default();
    let y = [0.5f32; D];
    map.add_point([0.05, 0.05, 0.05], &y, &mut sink).unwrap();
    let held = VoxelKey::new(0, 0, 0);
    let before = map.get(held).unwrap();
    sink.refuse = true;
    // Steps of 1,000 voxels (100 m) along x: the voxel stays wrap-safe up to 32,767 voxels away.
    let mut held_at = None;
    for step in 1..=40 {
        let x = step as f32 * 100.0 + 0.05;
        let previous = map.centre();
        map.move_window([x, 0.05, 0.05], &mut sink);
        let wanted = VoxelKey::new(step * 1000, 0, 0);
        if wanted.x < 1 << 15 {
            assert_eq!(
                map.centre(),
                wanted,
                "step {step}: the centre follows the robot"
            );
        } else {
            assert_eq!(map.centre(), previous, "step {step}: the centre is held");
            held_at.get_or_insert(previous);
        }
        assert_eq!(map.get(held), Some(before), "step {step}: the voxel stays");
    }
    assert_eq!(held_at, Some(VoxelKey::new(32_000, 0, 0)));
    assert!(sink.voxels.is_empty());
    // The sink takes it: it leaves, and the centre reaches the robot.
    sink.refuse = false;
    map.move_window([4000.05, 0.05, 0.05], &mut sink);
    assert_eq!(map.centre(), VoxelKey::new(40_000, 0, 0));
    assert!(map.is_empty());
    assert_eq!(sink.voxels.len(), 1);
    assert_eq!(sink.voxels[0].0, held);
}
