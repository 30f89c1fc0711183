//! What a voxel store updated in place, one point at a time, would do to the map's accuracy — the question
//! behind issue 32's cheapest designs (a code one point updates in place, no f32 hot tier).
//!
//! Why it matters: every re-encode rounds (stochastically: unbiased, but with variance). Rounding after
//! every point of a voxel adds that variance once per point; earlier roundings shrink by n/(n+1) at each
//! later point, so after N points the mean carries ≈ √(N/3) single roundings — a random walk that grows with
//! the voxel's points. The shipped map rounds once per *visit* (its f32 hot tier merges a visit's points
//! exactly, `src/local_map/hot.rs`), and a visit of a dense sensor is many points.
//!
//! This runs the firmware self-test's sensor patterns (depth frames, the 8×8 ToF, the 2D LiDAR; their real
//! features) through three stores with today's codes (`latentbki::quant`, on the boards' finer grid) and
//! compares each voxel's μ with the f32 mean of its points (RMS and 95th percentile of ‖Δμ‖/‖μ‖ over the
//! voxels, each voxel once):
//! - *once*: the f32 statistics encoded once at the end (the codes' own floor);
//! - *per visit*: the shipped `LocalMap` (its hot tier of 32, every eviction kept);
//! - *per point*: decode, merge the point, re-encode, for every point (what a store without a hot tier
//!   does, whatever its code costs).
//!
//! Deterministic. Run: `cargo run --release -p host-sim --example rounding_walk`.

use latentbki::{
    key::{to_map_frame, VoxelKey},
    local_map::LocalMap,
    obs::ObsStats,
    packed_len,
    quant::{Dither, MeanWeights, QuantVoxel},
    sink::{Evicted, SinkFull},
};
use latentbki_selftest::SELF_TEST;
use std::collections::HashMap;

use host_sim::sim::vocab::D;
const P: usize = packed_len(D);
const CAP: usize = latentbki_selftest::SELF_TEST_CAPACITY;

/// ‖a − b‖ / ‖b‖.
fn rel(a: &[f32; D], b: &[f32; D]) -> f64 {
    let (mut e, mut n) = (0.0f64, 0.0f64);
    for (x, y) in a.iter().zip(b) {
        e += f64::from(x - y).powi(2);
        n += f64::from(*y).powi(2);
    }
    (e / n.max(1e-30)).sqrt()
}

/// RMS and 95th percentile of the relative errors.
fn tails(mut errs: Vec<f64>) -> (f64, f64, usize) {
    errs.sort_by(f64::total_cmp);
    let rms = (errs.iter().map(|e| e * e).sum::<f64>() / errs.len().max(1) as f64).sqrt();
    let p95 = errs
        .get((errs.len() * 95 / 100).min(errs.len().saturating_sub(1)))
        .copied()
        .unwrap_or(0.0);
    (rms, p95, errs.len())
}

fn run(name: &str) {
    let s = SELF_TEST
        .iter()
        .position(|s| s.name == name)
        .expect("a self-test scenario");
    let sc = &SELF_TEST[s];
    let config = sc.map_config().expect("self-test config");
    let inv_voxel = 1.0 / config.voxel_size();
    let mut exact: HashMap<VoxelKey, ObsStats<D>> = HashMap::new();
    let mut per_point: HashMap<VoxelKey, QuantVoxel<D, P>> = HashMap::new();
    let mut dither = Dither::new(0x5EED_1234);
    let mut map = Box::new(LocalMap::<D, CAP, P>::EMPTY);
    // The whole scenario in one window, and every eviction kept: the per-visit store loses nothing.
    map.configure(config, 1.0e3).expect("window");
    map.set_mean_weights(MeanWeights::EQUAL).expect("weights");
    let mut evicted: HashMap<VoxelKey, ObsStats<D>> = HashMap::new();
    let mut keep = |v: Evicted<'_, D>| -> Result<(), SinkFull> {
        evicted.entry(v.key).or_insert(ObsStats::EMPTY).merge(v.obs);
        Ok(())
    };
    let mut y = [0.0f32; D];
    for frame in 0..sc.frames {
        let view = sc.scene.view(frame);
        let pose = view.pose();
        for zone in 0..sc.scene.sensor.zones() {
            let Some(o) = sc.scene.observe(&view, frame, zone, &mut y) else {
                continue;
            };
            let p = to_map_frame(&pose, o.point);
            let Ok(k) = VoxelKey::from_position(p, inv_voxel) else {
                continue;
            };
            let mut one = ObsStats::EMPTY;
            one.set_point(&y);
            exact.entry(k).or_insert(ObsStats::EMPTY).merge(&one);
            let code = per_point.entry(k).or_insert(QuantVoxel::EMPTY);
            let mut stats = code.decode();
            stats.merge(&one);
            *code = code.reencode_fine(&stats, &mut dither);
            let _ = map.add_point(p, &y, &mut keep);
        }
    }
    let _ = map.flush(&mut keep);
    let mut once_dither = Dither::new(7);
    let (mut once, mut visit, mut point) = (Vec::new(), Vec::new(), Vec::new());
    let mut points_per_voxel = Vec::new();
    // In key order: the once-encoding's dither is drawn voxel by voxel, so the order must not be the hash's.
    let mut keys: Vec<VoxelKey> = exact.keys().copied().collect();
    keys.sort_by_key(|k| k.as_array());
    for (k, truth) in keys.iter().filter_map(|k| exact.get(k).map(|t| (k, t))) {
        once.push(rel(
            &QuantVoxel::<D, P>::EMPTY
                .reencode_fine(truth, &mut once_dither)
                .decode()
                .mean,
            &truth.mean,
        ));
        if let Some(v) = evicted.get(k) {
            visit.push(rel(&v.mean, &truth.mean));
        }
        if let Some(q) = per_point.get(k) {
            point.push(rel(&q.decode().mean, &truth.mean));
        }
        points_per_voxel.push(truth.count);
    }
    points_per_voxel.sort_by(f32::total_cmp);
    let median_n = points_per_voxel
        .get(points_per_voxel.len() / 2)
        .copied()
        .unwrap_or(0.0);
    let c = map.counters();
    let fmt = |(rms, p95, _): (f64, f64, usize)| format!("{rms:.4} / {p95:.4}");
    println!(
        "| {name} | {} | {median_n:.0} | {:.2} | {} | {} | {} |",
        exact.len(),
        c.cooled as f32 / c.points.max(1) as f32,
        fmt(tails(once)),
        fmt(tails(visit)),
        fmt(tails(point)),
    );
}

fn main() {
    println!(
        "| scenario | voxels | median points a voxel | coolings a point (per visit) | μ RMS / p95, once | per visit (shipped) | per point |"
    );
    println!("|---|---:|---:|---:|---|---|---|");
    for name in ["depth_f3", "tof_f3", "lidar_f3", "full_map"] {
        run(name);
    }
}
