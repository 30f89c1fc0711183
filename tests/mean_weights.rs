//! Per-dimension weights of the local map's mean codes (`quant::MeanWeights`, feature `mean-weights`): on
//! features whose spread falls with the component (as PCA components do) they cut the map's μ error, all
//! ones leave the codes as they were, and bad weights are refused without touching the map.
#![cfg(feature = "mean-weights")]

use latentbki::nalgebra::Isometry3;
use latentbki::quant::{Cooling, MeanWeights};
use latentbki::{
    key::VoxelKey, local_map::LocalMap, obs::ObsStats, packed_len, sink::Evicted, sink::SinkFull,
    ConfigError, MapConfig,
};
use std::collections::HashMap;

const D: usize = 16;
const P: usize = packed_len(D);
/// Few hot voxels, so voxels cool (decode, merge, re-encode) many times.
type Map = LocalMap<D, 512, P, 4>;

/// Spread of component i: 1, 0.5, then 0.06 (the demo's PCA falls from 0.52 to 0.06 in 5 components).
fn spread(i: usize) -> f32 {
    match i {
        0 => 1.0,
        1 => 0.5,
        _ => 0.06,
    }
}

/// Points in 40 voxels of a 0.1 m grid, each voxel visited in turns; features of a class mean plus noise
/// with the spreads above.
fn points(n: usize) -> (Vec<[f32; 3]>, Vec<[f32; D]>) {
    let mut s = 0x1234_5677u32;
    let mut r = move || {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        s as f32 / u32::MAX as f32 - 0.5
    };
    (0..n)
        .map(|k| {
            let v = (k / 3) % 40;
            let p = [
                0.05 + 0.1 * (v % 8) as f32,
                0.05 + 0.1 * (v / 8) as f32,
                0.05,
            ];
            let class = if v % 3 == 0 { 0.8 } else { -0.6 };
            let y = core::array::from_fn(|i| {
                let mean = if i < 2 { class * spread(i) } else { 0.0 };
                mean + 2.0 * r() * spread(i)
            });
            (p, y)
        })
        .unzip()
}

struct Collect(HashMap<VoxelKey, ObsStats<D>>);

impl latentbki::sink::EvictionSink<D> for Collect {
    fn evict(&mut self, v: Evicted<'_, D>) -> Result<(), SinkFull> {
        self.0.insert(v.key, *v.obs);
        Ok(())
    }
}

fn configured(weights: Option<MeanWeights>) -> Box<Map> {
    let mut m = Box::new(Map::EMPTY);
    m.configure(MapConfig::default(), 5.0).unwrap();
    m.set_cooling(Cooling::Float).unwrap();
    if let Some(w) = weights {
        m.set_mean_weights(w).unwrap();
    }
    m
}

/// Every voxel of the map after `pts`, flushed.
fn run(weights: Option<MeanWeights>, pts: &(Vec<[f32; 3]>, Vec<[f32; D]>)) -> Collect {
    let mut m = configured(weights);
    let mut sink = Collect(HashMap::new());
    let pose = Isometry3::identity();
    for (p, y) in pts.0.chunks(7).zip(pts.1.chunks(7)) {
        assert_eq!(m.add_points(&pose, p, y, &mut sink), p.len());
    }
    assert!(m.counters().cooled > 1000, "{}", m.counters().cooled);
    m.flush(&mut sink).unwrap();
    sink
}

/// RMS over voxels of ‖Δm‖/‖m‖ against f32 statistics of the same points; and whether every count is
/// exact.
fn error(got: &Collect, pts: &(Vec<[f32; 3]>, Vec<[f32; D]>)) -> f64 {
    let mut truth: HashMap<VoxelKey, ObsStats<D>> = HashMap::new();
    let config = MapConfig::default();
    for (p, y) in pts.0.iter().zip(&pts.1) {
        let k = VoxelKey::from_position(*p, 1.0 / config.voxel_size()).unwrap();
        truth.entry(k).or_insert(ObsStats::EMPTY).add_point(y);
    }
    assert_eq!(truth.len(), got.0.len());
    let mut sq = 0.0f64;
    for (k, t) in &truth {
        let g = &got.0[k];
        assert_eq!(g.count, t.count, "every point counted once");
        let num: f64 = g
            .mean
            .iter()
            .zip(&t.mean)
            .map(|(a, b)| f64::from(a - b).powi(2))
            .sum();
        let den: f64 = t.mean.iter().map(|b| f64::from(*b).powi(2)).sum();
        sq += num / den;
    }
    (sq / truth.len() as f64).sqrt()
}

#[test]
fn weights_that_follow_the_spreads_cut_the_mean_error() {
    let pts = points(40 * 3 * 60);
    let spreads: [f32; D] = core::array::from_fn(spread);
    let weights = MeanWeights::from_spreads(&spreads);
    assert!(!weights.is_ones());
    let plain = error(&run(None, &pts), &pts);
    let weighed = error(&run(Some(weights), &pts), &pts);
    println!("RMS ‖Δm‖/‖m‖: one step {plain:.5}, weighed {weighed:.5} ({weights:?})");
    assert!(weighed < 0.75 * plain, "{weighed} vs {plain}");
}

#[test]
fn all_ones_are_the_codes_of_a_map_without_weights() {
    let pts = points(40 * 3 * 60);
    let a = run(None, &pts);
    let b = run(Some(MeanWeights::ONES), &pts);
    assert_eq!(a.0, b.0);
}

#[test]
fn bad_weights_are_refused_and_change_nothing() {
    let good = MeanWeights::new([1, 4, 0, 0, 0, 0, 0, 0]);
    let mut m = configured(None);
    assert_eq!(
        m.set_mean_weights(MeanWeights::new([4, 1, 0, 0, 0, 0, 0, 0])),
        Err(ConfigError::MeanWeights)
    );
    assert_eq!(
        m.set_mean_weights(MeanWeights::new([1, D as u16, 0, 0, 0, 0, 0, 0])),
        Err(ConfigError::MeanWeights)
    );
    assert!(m.mean_weights().is_ones());
    // The fixed-point cooling codes every dimension on one step: either order is refused.
    m.set_cooling(Cooling::Fixed).unwrap();
    assert_eq!(
        m.set_mean_weights(good),
        Err(ConfigError::MeanWeightsFixedCooling)
    );
    m.set_cooling(Cooling::Float).unwrap();
    m.set_mean_weights(good).unwrap();
    assert_eq!(
        m.set_cooling(Cooling::Fixed),
        Err(ConfigError::MeanWeightsFixedCooling)
    );
    assert_eq!(m.cooling(), Cooling::Float);
    // A map that holds voxels keeps the weights its codes are on (its own are taken again).
    let pts = points(10);
    let mut sink = Collect(HashMap::new());
    m.add_points(&Isometry3::identity(), &pts.0, &pts.1, &mut sink);
    assert_eq!(
        m.set_mean_weights(MeanWeights::ONES),
        Err(ConfigError::MeanWeights)
    );
    assert_eq!(m.set_mean_weights(good), Ok(()));
    assert_eq!(m.mean_weights(), good);
}

/// Features whose components spread alike (the firmware self-test's): their weights are all ones on the
/// finer grid (`MeanWeights::EQUAL`), which cuts the map's μ error, and a map cooling int8 sums in fixed
/// point takes them (no shift to honour).
#[test]
fn equal_spreads_code_on_the_finer_grid() {
    let weights = MeanWeights::from_spreads(&[0.3; D]);
    assert_eq!(weights, MeanWeights::EQUAL);
    // Every component spread alike: the noise of `points` scaled to the lead's spread everywhere.
    let (p, y) = points(40 * 3 * 60);
    let y: Vec<[f32; D]> = y
        .iter()
        .map(|f| core::array::from_fn(|i| f[i] / spread(i)))
        .collect();
    let pts = (p, y);
    let plain = error(&run(None, &pts), &pts);
    let fine = error(&run(Some(weights), &pts), &pts);
    println!("RMS ‖Δm‖/‖m‖, spreads alike: one step {plain:.5}, finer grid {fine:.5}");
    assert!(fine < 0.8 * plain, "{fine} vs {plain}");
    let mut m = configured(None);
    m.set_cooling(Cooling::Fixed).unwrap();
    m.set_mean_weights(weights).unwrap();
    assert_eq!(m.mean_weights(), MeanWeights::EQUAL);
    m.set_cooling(Cooling::Float).unwrap();
    m.set_cooling(Cooling::Fixed).unwrap();
}
