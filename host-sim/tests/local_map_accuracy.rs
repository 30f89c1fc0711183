//! The quantized on-device map against the f32 map on the real labelled LiDAR tile, over a long run.
//!
//! Features are per-class unit embeddings plus noise (isotropic Gaussian, and 10 % of points take another
//! class's embedding, as a segmentation network's confusions do), D = 64. The robot sweeps the tile back and
//! forth for 400 frames with an 8 m window, so voxels are evicted and observed again many times: the evicted
//! residencies are merged as the base station merges them, posteriors gathered, and compared voxel by voxel
//! with the f32 observation map of all points (itself equal to the paper's update: `tests/obs_map.rs`).
//! The same with int8 features (codes of one global scale) against the f32 reference of the unquantized
//! features. Run with `-- --nocapture` for the figures (medians and tails).

use host_sim::sim::tile::Tile;
use host_sim::ObsMap;
use latentbki::nalgebra::Isometry3;
use latentbki::{
    decode::Codebook, key::VoxelKey, local_map::LocalMap, obs::ObsStats, packed_len,
    quant::Cooling, sink::Evicted, sink::SinkFull, MapConfig,
};
use rand_xoshiro::rand_core::{RngCore, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::collections::HashMap;

use host_sim::sim::vocab::D;
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
    merged: &'a mut HashMap<VoxelKey, ObsStats<D>>,
}

impl latentbki::sink::EvictionSink<D> for Merge<'_> {
    fn evict(&mut self, v: Evicted<'_, D>) -> Result<(), SinkFull> {
        self.merged
            .entry(v.key)
            .and_modify(|m| m.merge(v.obs))
            .or_insert(*v.obs);
        Ok(())
    }
}

fn quantile(mut v: Vec<f64>, q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q) as usize]
}

/// `int8_scale`: the device map takes the features as int8 codes of this scale (rounded, clamped to ±127);
/// the reference keeps the f32 features; `cooling`: how it cools their sums (what a board with / without an
/// FPU does).
fn run(prior_psi: f32, int8_scale: Option<f32>, cooling: Cooling) {
    let tile = Tile::builtin().unwrap();
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
    let classes = class_embeddings(6, &mut rng);
    let codebook = Codebook::<D, 8>::from_embeddings(&classes).unwrap();
    let prior = latentbki::Prior {
        psi: prior_psi,
        ..Default::default()
    };
    let config = MapConfig::new(0.1, 0.5, 3, prior, latentbki::KernelMode::VoxelOffset).unwrap();

    let mut reference = ObsMap::<D>::new(config).unwrap();
    let mut local = Box::new(LocalMap::<D, CAP, P>::EMPTY);
    local.configure(config, 8.0).unwrap();
    local.set_cooling(cooling).unwrap();
    if let Some(scale) = int8_scale {
        local.set_int8_scale(scale).unwrap();
    }
    let mut merged = HashMap::new();
    let mut sink = Merge {
        merged: &mut merged,
    };

    // Ten sweeps along x and back, 40 frames each: every frame a tenth of the tile points within 7.5 m of
    // the pose (map frame), so each place is seen in many frames of many sweeps.
    let (lo, hi) = tile.bounds;
    for step in 0..400 {
        let t = (step % 40) as f32 / 19.0;
        let x = if step % 40 < 20 {
            lo[0] + t * (hi[0] - lo[0])
        } else {
            hi[0] - (t - 1.0) * (hi[0] - lo[0])
        };
        let pose_xyz = [x, 0.5 * (lo[1] + hi[1]), lo[2] + 5.0];
        let mut pts = Vec::new();
        let mut feats = Vec::new();
        for (p, &c) in tile.points.iter().zip(&tile.classes) {
            let d2: f32 = (0..3).map(|a| (p[a] - pose_xyz[a]).powi(2)).sum();
            if d2 > 7.5 * 7.5 || rng.next_u32() % 10 != 0 {
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
        // Points are in the map frame: the pose only places the window.
        reference.integrate(&Isometry3::identity(), &pts, &feats);
        local.move_window(pose_xyz, &mut sink);
        for (p, y) in pts.iter().zip(&feats) {
            let _ = match int8_scale {
                Some(scale) => {
                    let codes = y.map(|v| (v / scale).round().clamp(-127.0, 127.0) as i8);
                    local.add_point_i8(*p, &codes, &mut sink)
                }
                None => local.add_point(*p, y, &mut sink),
            };
        }
    }
    assert_eq!(local.rejections().total(), 0, "{:?}", local.rejections());
    let counters = local.counters();
    local.flush(&mut sink).unwrap();

    let mut device = ObsMap::<D>::new(config).unwrap();
    for (k, o) in &merged {
        device.merge_observations(*k, o);
    }
    let (q_all, r_all) = (device.posteriors_sorted(), reference.posteriors_sorted());
    assert_eq!(q_all.len(), r_all.len(), "the same voxels are answered");
    let mut agree = 0usize;
    let (mut mu_rel, mut psi_rel, mut eopt_rel) = (Vec::new(), Vec::new(), Vec::new());
    let mut lambda_rel: f64 = 0.0;
    for ((kq, q), (kr, r)) in q_all.iter().zip(&r_all) {
        assert_eq!(kq, kr);
        lambda_rel = lambda_rel.max(((q.lambda - r.lambda) / r.lambda).abs() as f64);
        let (mut d2, mut n2) = (0.0f64, 0.0f64);
        for i in 0..D {
            d2 += f64::from(q.mean[i] - r.mean[i]).powi(2);
            n2 += f64::from(r.mean[i]).powi(2);
            psi_rel.push(f64::from(((q.psi[i] - r.psi[i]) / r.psi[i]).abs()));
        }
        mu_rel.push((d2 / n2).sqrt());
        if codebook.argmax(&q.mean).unwrap().0 == codebook.argmax(&r.mean).unwrap().0 {
            agree += 1;
        }
        if let (Some(eq), Some(er)) = (q.e_optimality(), r.e_optimality()) {
            eopt_rel.push(f64::from(((eq - er) / er).abs()));
        }
    }
    let n = r_all.len();
    let agreement = agree as f64 / n as f64;
    let mu_rms = (mu_rel.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt();
    let (mu_p95, mu_max) = (quantile(mu_rel.clone(), 0.95), quantile(mu_rel, 1.0));
    let (psi_med, psi_p95) = (quantile(psi_rel.clone(), 0.5), quantile(psi_rel, 0.95));
    let (e_med, e_p95) = (quantile(eopt_rel.clone(), 0.5), quantile(eopt_rel, 0.95));
    println!(
        "prior psi {prior_psi}, {}, 400 frames: {n} voxels answered, {} points, {} evictions, {} cooled; argmax agreement {:.4}; ‖Δμ‖/‖μ‖ RMS {mu_rms:.4} p95 {mu_p95:.4} max {mu_max:.4}; Ψ per dimension rel. error median {psi_med:.4} p95 {psi_p95:.4}; E-opt rel. error median {e_med:.4} p95 {e_p95:.4}; max λ rel. error {lambda_rel:.1e}; {} B/voxel",
        match int8_scale {
            Some(s) => format!("int8 features (scale {s:.5})"),
            None => "f32 features".to_string(),
        },
        reference.points(),
        counters.evicted,
        counters.cooled,
        agreement,
        LocalMap::<D, CAP, P>::BYTES_PER_VOXEL
    );
    assert!(
        counters.evicted > 10_000,
        "the window must evict and re-observe"
    );
    assert!(agreement >= 0.995, "argmax agreement {agreement}");
    assert!(
        mu_rms <= 0.03 && mu_p95 <= 0.06,
        "μ RMS {mu_rms}, p95 {mu_p95}"
    );
    if int8_scale.is_none() {
        // (int8 features: the bounds are argmax, μ and E-opt; Ψ is printed.)
        assert!(psi_p95 <= 0.10, "Ψ p95 {psi_p95}");
    }
    assert!(e_p95 <= 0.10, "E-opt p95 {e_p95}");
    assert!(lambda_rel < 1e-5);
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

/// The default prior (Ψ₀ = 1, the authors'): the prior weighs on the scatter of unit-norm features.
#[test]
fn quantized_map_matches_reference_on_the_real_tile() {
    on_big_stack(|| run(1.0, None, Cooling::NATIVE));
}

/// A weak prior (Ψ₀ = 10⁻³): Ψ is the observed scatter — the hard case for the scatter codes.
#[test]
fn quantized_map_matches_reference_with_a_weak_prior() {
    on_big_stack(|| run(1e-3, None, Cooling::NATIVE));
}

/// int8 features (one global scale: the features are within ±1, so 1/127), against the f32 reference of
/// the same features unquantized, their sums cooled in f32 (an FPU's way).
#[test]
fn int8_features_match_the_f32_reference() {
    on_big_stack(|| run(1.0, Some(1.0 / 127.0), Cooling::Float));
}

/// The same, cooled in fixed point (the way of thumbv6m and riscv32imac): the same bounds.
#[test]
fn int8_features_cooled_in_fixed_point_match_the_f32_reference() {
    on_big_stack(|| run(1.0, Some(1.0 / 127.0), Cooling::Fixed));
}
