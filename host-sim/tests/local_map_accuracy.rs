//! The quantized on-device map against the f32 reference map on the real labelled LiDAR tile.
//!
//! Features are per-class unit embeddings plus noise (isotropic Gaussian, and 10 % of points take another
//! class's embedding, as a segmentation network's confusions do), D = 64. The robot sweeps the tile with an
//! 8 m window, so voxels are evicted (and some observed again later): the evicted residencies are merged as
//! the base station merges them, then compared voxel by voxel with the reference map of all points.

use host_sim::sim::tile::Tile;
use host_sim::ReferenceMap;
use latentbki::nalgebra::Isometry3;
use latentbki::rand_xoshiro::rand_core::{RngCore, SeedableRng};
use latentbki::rand_xoshiro::Xoshiro256PlusPlus;
use latentbki::{
    packed_len, Codebook, Evicted, LocalMap, MapConfig, SinkFull, VoxelKey, VoxelStats,
};
use std::collections::HashMap;

const D: usize = 64;
const P: usize = packed_len(D);
const CAP: usize = 12_000;

fn gauss(rng: &mut Xoshiro256PlusPlus) -> f32 {
    let u1 = (rng.next_u32() >> 8) as f32 / (1u32 << 24) as f32 + 1e-7;
    let u2 = (rng.next_u32() >> 8) as f32 / (1u32 << 24) as f32;
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f32::consts::PI * u2).cos()
}

fn class_embeddings(n: usize, rng: &mut Xoshiro256PlusPlus) -> Vec<[f32; D]> {
    (0..n)
        .map(|_| {
            let mut e: [f32; D] = core::array::from_fn(|_| gauss(rng));
            let norm = e.iter().map(|v| v * v).sum::<f32>().sqrt();
            e.iter_mut().for_each(|v| *v /= norm);
            e
        })
        .collect()
}

struct Merge<'a> {
    prior: VoxelStats<D>,
    merged: &'a mut HashMap<VoxelKey, VoxelStats<D>>,
}

impl latentbki::EvictionSink<D> for Merge<'_> {
    fn evict(&mut self, v: Evicted<'_, D>) -> Result<(), SinkFull> {
        let prior = self.prior;
        self.merged
            .entry(v.key)
            .and_modify(|m| m.merge(v.stats, &prior))
            .or_insert(*v.stats);
        Ok(())
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn run(prior_psi: f32) {
    let tile = Tile::builtin().unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
    let classes = class_embeddings(6, &mut rng);
    let codebook = Codebook::<D, 8>::from_embeddings(&classes).unwrap();
    let prior = latentbki::Prior {
        psi: prior_psi,
        ..Default::default()
    };
    let config = MapConfig::new(0.1, 0.5, 3, prior, latentbki::KernelMode::VoxelOffset).unwrap();

    let mut reference = ReferenceMap::<D>::new(config).unwrap();
    let mut local = Box::new(LocalMap::<D, CAP, P>::EMPTY);
    local.configure(config, 8.0).unwrap();
    let mut merged = HashMap::new();
    let mut sink = Merge {
        prior: *reference.prior(),
        merged: &mut merged,
    };

    // A sweep along x and back: 40 frames, each a third of the tile points within 7.5 m of the pose (map frame).
    let (lo, hi) = tile.bounds;
    for step in 0..40 {
        let t = step as f32 / 19.0;
        let x = if step < 20 {
            lo[0] + t * (hi[0] - lo[0])
        } else {
            hi[0] - (t - 1.0) * (hi[0] - lo[0])
        };
        let pose_xyz = [x, 0.5 * (lo[1] + hi[1]), lo[2] + 5.0];
        let mut pts = Vec::new();
        let mut feats = Vec::new();
        for (p, &c) in tile.points.iter().zip(&tile.classes) {
            let d2: f32 = (0..3).map(|a| (p[a] - pose_xyz[a]).powi(2)).sum();
            if d2 > 7.5 * 7.5 || rng.next_u32() % 3 != 0 {
                continue;
            }
            let seen = if rng.next_u32() % 10 == 0 {
                (c as usize + 1) % classes.len()
            } else {
                c as usize
            };
            let y: [f32; D] = core::array::from_fn(|i| classes[seen][i] + 0.1 * gauss(&mut rng));
            pts.push(*p);
            feats.push(y);
        }
        let pose = Isometry3::translation(pose_xyz[0], pose_xyz[1], pose_xyz[2]);
        // Points are in the map frame: the pose only places the window (identity transform for points).
        reference.integrate(&Isometry3::identity(), &pts, &feats);
        local.move_window(pose_xyz, &mut sink);
        for (p, y) in pts.iter().zip(&feats) {
            let _ = local.add_point(*p, y, &mut sink);
        }
        local.end_batch(&mut sink);
        let _ = pose;
    }
    assert_eq!(local.rejections().total(), 0, "{:?}", local.rejections());
    let evictions = local.counters().evicted;
    local.flush(&mut sink).unwrap();

    let mut agree = 0usize;
    let mut var_rel = Vec::new();
    let mut trace_rel = Vec::new();
    let mut lambda_rel: f64 = 0.0;
    let (mut dmu2, mut mu2) = (0.0f64, 0.0f64);
    for (key, r) in reference.voxels() {
        let q = merged
            .get(key)
            .expect("every reference voxel reached the base station");
        lambda_rel = lambda_rel.max(((q.lambda - r.lambda) / r.lambda).abs() as f64);
        for i in 0..D {
            dmu2 += f64::from(q.mean[i] - r.mean[i]).powi(2);
            mu2 += f64::from(r.mean[i]).powi(2);
        }
        if codebook.argmax(&q.mean).unwrap().0 == codebook.argmax(&r.mean).unwrap().0 {
            agree += 1;
        }
        if let (Some(vq), Some(vr)) = (q.predictive_variance(), r.predictive_variance()) {
            let (mut tq, mut tr) = (0.0f64, 0.0f64);
            for i in 0..D {
                var_rel.push(((vq[i] - vr[i]) / vr[i]).abs() as f64);
                tq += vq[i] as f64;
                tr += vr[i] as f64;
            }
            trace_rel.push(((tq - tr) / tr).abs());
        }
    }
    assert_eq!(merged.len(), reference.len());
    let agreement = agree as f64 / reference.len() as f64;
    let (med_dim, med_trace) = (median(var_rel), median(trace_rel));
    println!(
        "prior psi {prior_psi}: voxels {} (evictions during the run {evictions}); argmax agreement {:.4}; predictive variance median rel. error per dimension {:.4}, of the trace {:.4}; max λ rel. error {lambda_rel:.2e}; μ relative RMS error {:.4}; {} B/voxel",
        reference.len(),
        agreement,
        med_dim,
        med_trace,
        (dmu2 / mu2).sqrt(),
        LocalMap::<D, CAP, P>::BYTES_PER_VOXEL
    );
    assert!(evictions > 1000, "the window must evict during the sweep");
    assert!(agreement >= 0.99, "argmax agreement {agreement}");
    assert!(
        med_dim <= 0.05,
        "per-dimension predictive variance median relative error {med_dim}"
    );
    assert!(lambda_rel < 1e-3);
    assert!(
        (dmu2 / mu2).sqrt() < 0.1,
        "μ relative RMS error {}",
        (dmu2 / mu2).sqrt()
    );
}

fn on_big_stack(f: impl FnOnce() + Send + 'static) {
    // The map is a few MB: give the test thread room for the by-value construction in debug builds.
    std::thread::Builder::new()
        .stack_size(64 << 20)
        .spawn(f)
        .unwrap()
        .join()
        .unwrap();
}

/// The default prior (Ψ₀ = 1, the authors'): the prior dominates the scatter of unit-norm features.
#[test]
fn quantized_map_matches_reference_on_the_real_tile() {
    on_big_stack(|| run(1.0));
}

/// A weak prior (Ψ₀ = 10⁻³): Ψ is the observed scatter, spread over orders of magnitude — the hard case
/// for the logarithmic Ψ codes.
#[test]
fn quantized_map_matches_reference_with_a_weak_prior() {
    on_big_stack(|| run(1e-3));
}
