//! Forgetting on the on-device map: statistics decay lazily — when read, cooled, merged or evicted — to the
//! weighted moments of every point (each weighed 2^(−age/half-life)), through the hot tier, cooling and
//! eviction; off by default and with the `Timeless` clock nothing changes and no byte is added.

use latentbki::forget::{Fading, Forgetting, Stamped};
use latentbki::{
    key::VoxelKey, local_map::LocalMap, obs::ObsLookup, obs::ObsStats, packed_len, sink::Evicted,
    sink::SinkFull, MapConfig,
};
use std::collections::HashMap;

const D: usize = 8;
const P: usize = packed_len(D);
/// Two hot entries, so voxels cool (and re-heat) all the time.
type Fades = LocalMap<D, 64, P, 2, Fading>;
type Plain = LocalMap<D, 64, P, 2>;

/// The feature of voxel `v` at tick `t`: the scene changes at tick 8 (each voxel swaps its class).
fn feature(v: usize, t: u32, j: usize) -> [f32; D] {
    let class = (v + usize::from(t >= 8)) % 3;
    core::array::from_fn(|d| {
        let base = if d % 3 == class { 0.8 } else { -0.2 };
        base + 0.05 * (((j * 7 + d * 3 + t as usize) % 5) as f32 - 2.0)
    })
}

/// Voxel centres along x, two voxels apart (0.1 m voxels by default).
fn position(v: usize) -> [f32; 3] {
    [0.05 + 0.2 * v as f32, 0.05, 0.05]
}

/// Which voxels see points at tick t: voxel 0 every tick, 1 until tick 4, 2 at ticks 2 and 9, 3 every
/// third tick.
fn seen(v: usize, t: u32) -> usize {
    match v {
        0 => 3,
        1 if t < 4 => 2,
        2 if t == 2 || t == 9 => 4,
        3 if t.is_multiple_of(3) => 1,
        _ => 0,
    }
}

#[derive(Default)]
struct Collect(Vec<(VoxelKey, ObsStats<D>, u32)>);
impl latentbki::sink::EvictionSink<D> for Collect {
    fn evict(&mut self, v: Evicted<'_, D>) -> Result<(), SinkFull> {
        self.0.push((v.key, *v.obs, v.time));
        Ok(())
    }
}

/// Run ticks 0..12 into `map` (set_time per tick when `timed`); the exact reference per voxel.
fn run<C: latentbki::forget::MapClock>(
    map: &mut LocalMap<D, 64, P, 2, C>,
    f: &Forgetting,
    timed: bool,
) -> HashMap<VoxelKey, Stamped<D>> {
    let mut want: HashMap<VoxelKey, Stamped<D>> = HashMap::new();
    let mut sink = Collect::default();
    for t in 0..12u32 {
        if timed {
            map.set_time(t);
        }
        for v in 0..4 {
            for j in 0..seen(v, t) {
                let y = feature(v, t, j);
                map.add_point(position(v), &y, &mut sink).unwrap();
                let key = VoxelKey::from_position(position(v), 10.0).unwrap();
                want.entry(key)
                    .or_insert(Stamped::EMPTY)
                    .add_point(f, t, &y);
            }
        }
    }
    assert!(sink.0.is_empty(), "nothing evicted while the map has room");
    want
}

/// The widest step of the scatter codes, relative to the value below it.
const SCATTER_STEP: f32 = 1.0 / (1u32 << latentbki::quant::PSI_STEPS_LOG2) as f32;

fn assert_close(got: &ObsStats<D>, want: &ObsStats<D>, what: &str) {
    assert!(
        (got.count - want.count).abs() <= 1e-5 * want.count,
        "{what}: n {} vs {}",
        got.count,
        want.count
    );
    for d in 0..D {
        // 7-bit mean codes against a per-voxel scale of ≈ 0.9; scatter within one of its codes' steps
        // (2^−PSI_STEPS_LOG2 of the value at most).
        assert!(
            (got.mean[d] - want.mean[d]).abs() < 0.02,
            "{what}: m[{d}] {} vs {}",
            got.mean[d],
            want.mean[d]
        );
        assert!(
            (got.scatter[d] - want.scatter[d]).abs() <= SCATTER_STEP * want.scatter[d] + 1e-4,
            "{what}: S[{d}] {} vs {}",
            got.scatter[d],
            want.scatter[d]
        );
    }
}

#[test]
fn reads_and_evictions_equal_the_weighted_moments() {
    let f = Forgetting::new(3.0).unwrap();
    let mut map = Box::new(Fades::EMPTY);
    map.configure(MapConfig::default(), 4.0).unwrap();
    map.set_forgetting(Some(f)).unwrap();
    let want = run(&mut map, &f, true);
    assert!(map.counters().cooled > 10, "voxels cooled and re-heated");
    for now in [11, 12, 20] {
        map.set_time(now);
        for (key, w) in &want {
            let got = map.get(*key).unwrap();
            assert_close(&got, &w.at(&f, now), &format!("{key:?} read at {now}"));
            // What a view score gathers, without decoding: the same n to the bit.
            assert_eq!(map.observed_count(*key).to_bits(), got.count.to_bits());
        }
    }
    // Voxel 1 took 8 points until tick 3 (n = 5.85 then): by tick 20 they weigh 2^(−17/3) as much.
    let v1 = VoxelKey::from_position(position(1), 10.0).unwrap();
    let n = map.get(v1).unwrap().count;
    assert!((n - 5.85 * (-17.0f32 / 3.0).exp2()).abs() < 0.01, "n = {n}");
    // Evicted voxels carry the stamp of their last change and the statistics as of then.
    let mut sink = Collect::default();
    map.flush(&mut sink).unwrap();
    assert_eq!(sink.0.len(), want.len());
    for (key, obs, time) in sink.0 {
        let w = want[&key];
        assert_eq!(time, w.time, "{key:?}: stamp of the last change");
        assert_close(&obs, &w.obs, &format!("{key:?} evicted"));
    }
}

#[test]
fn off_by_default_and_timeless_maps_are_unchanged() {
    let f = Forgetting::new(3.0).unwrap();
    let mut fades = Box::new(Fades::EMPTY);
    fades.configure(MapConfig::default(), 4.0).unwrap();
    assert_eq!(fades.forgetting(), None);
    let mut plain = Box::new(Plain::EMPTY);
    plain.configure(MapConfig::default(), 4.0).unwrap();
    assert_eq!(
        plain.set_forgetting(Some(f)),
        Err(latentbki::ConfigError::Forgetting),
        "a timeless map keeps no stamps"
    );
    // The clock runs, forgetting is off: the same statistics, bit for bit, as a map without a clock.
    let want = run(&mut fades, &f, true);
    run(&mut plain, &f, false);
    for key in want.keys() {
        assert_eq!(fades.get(*key), plain.get(*key));
    }
    // A timeless map's layout is the paper's; the stamp costs 4 B per voxel (+ alignment) when forgetting.
    let plain_b = LocalMap::<64, 2048, { packed_len(64) }>::BYTES_PER_VOXEL;
    let fades_b = LocalMap::<64, 2048, { packed_len(64) }, 32, Fading>::BYTES_PER_VOXEL;
    println!("bytes per voxel at D = 64: {plain_b} timeless, {fades_b} with the Fading clock");
    assert_eq!(fades_b, plain_b + 4);
}
