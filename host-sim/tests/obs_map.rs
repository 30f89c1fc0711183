//! The observation map (store n, m, S per voxel; gather through the kernel when asked) equals the literal
//! paper update of the reference map: on random batches (proptest), on both scenes' real geometry and
//! with non-centred features. Relative errors are printed (`-- --nocapture`) with their tails.

use host_sim::eval::scenes::{SceneKind, SceneOptions, SceneSource};
use host_sim::{ObsMap, ReferenceMap};
use latentbki::nalgebra::{Isometry3, Translation3, UnitQuaternion};
use latentbki::{obs::ObsLookup, stats::VoxelStats, KernelMode, MapConfig, Prior};
use proptest::prelude::*;

/// Largest relative differences over every voxel in reach: λ, μ (per voxel ‖Δμ‖∞ relative to the larger
/// of ‖μ‖∞ and the features' magnitude `scale`: a mean that cancels to near zero keeps the rounding of the
/// features that cancelled, so a pure relative bound would be meaningless there), Ψ (per dimension |ΔΨ|/Ψ).
#[derive(Debug, Default)]
struct Diff {
    lambda: Vec<f64>,
    mean: Vec<f64>,
    psi: Vec<f64>,
}

impl Diff {
    fn max(v: &[f64]) -> f64 {
        v.iter().copied().fold(0.0, f64::max)
    }
    fn p95(v: &[f64]) -> f64 {
        let mut s = v.to_vec();
        s.sort_by(f64::total_cmp);
        s.get(s.len() * 95 / 100).copied().unwrap_or(0.0)
    }
    fn worst(&self) -> f64 {
        Self::max(&self.lambda)
            .max(Self::max(&self.mean))
            .max(Self::max(&self.psi))
    }
    fn line(&self) -> String {
        format!(
            "λ max {:.1e}; μ p95 {:.1e} max {:.1e}; Ψ p95 {:.1e} max {:.1e}",
            Self::max(&self.lambda),
            Self::p95(&self.mean),
            Self::max(&self.mean),
            Self::p95(&self.psi),
            Self::max(&self.psi)
        )
    }
}

fn compare<const D: usize>(obs: &ObsMap<D>, reference: &ReferenceMap<D>, scale: f32) -> Diff {
    let posts = obs.posteriors_sorted();
    assert_eq!(
        posts.len(),
        reference.len(),
        "voxels in reach differ from the voxels the reference map reached"
    );
    let mut diff = Diff::default();
    for (key, p) in &posts {
        let r: &VoxelStats<D> = reference
            .get(key)
            .unwrap_or_else(|| panic!("{key:?} in reach but not in the reference map"));
        diff.lambda
            .push(((p.lambda - r.lambda) / r.lambda).abs() as f64);
        let norm = r.mean.iter().fold(scale, |a, v| a.max(v.abs())).max(1e-12);
        let dm = p
            .mean
            .iter()
            .zip(&r.mean)
            .fold(0.0f32, |a, (x, y)| a.max((x - y).abs()));
        diff.mean.push((dm / norm) as f64);
        for (x, y) in p.psi.iter().zip(&r.psi) {
            diff.psi.push(((x - y) / y).abs() as f64);
        }
    }
    diff
}

/// Deterministic 64-d features per class: a class prototype plus noise.
fn feature<const D: usize>(class: u16, i: usize, offset: f32) -> [f32; D] {
    let h = |a: u64| {
        let z = host_sim::sim::mix(a);
        (z >> 40) as f32 / (1u64 << 24) as f32 - 0.5
    };
    core::array::from_fn(|d| {
        offset + h(u64::from(class) * 131 + d as u64) + 0.3 * h((i as u64) << 8 | d as u64)
    })
}

fn scene_equivalence(scene: SceneKind) {
    use host_sim::sim::vocab::D;
    let options = SceneOptions {
        tile_frames: 20,
        ..SceneOptions::default()
    };
    let source = SceneSource::new(scene, &options, 7).unwrap();
    let seq = source.sequence(source.budget(), false);
    let mut obs = ObsMap::<D>::new(seq.config).unwrap();
    let mut reference = ReferenceMap::<D>::new(seq.config).unwrap();
    let mut i = 0;
    for frame in &seq.frames {
        let pts: Vec<[f32; 3]> = frame.points.iter().map(|p| p.position).collect();
        let feats: Vec<[f32; D]> = frame
            .points
            .iter()
            .map(|p| {
                i += 1;
                feature(p.class, i, 0.0)
            })
            .collect();
        // Points are in the map frame already.
        let a = obs.integrate(&Isometry3::identity(), &pts, &feats);
        let b = reference.integrate(&Isometry3::identity(), &pts, &feats);
        assert_eq!(a, b);
    }
    let diff = compare(&obs, &reference, 0.0);
    println!(
        "{}: {} points, {} observed voxels, {} in reach: {}",
        scene.name(),
        obs.points(),
        obs.observed_len(),
        reference.len(),
        diff.line()
    );
    assert!(diff.worst() <= 1e-5, "{}", diff.line());
}

#[test]
fn tile_equals_the_reference_map() {
    scene_equivalence(SceneKind::Tile);
}

#[test]
fn indoor_equals_the_reference_map() {
    scene_equivalence(SceneKind::Indoor);
}

#[test]
fn non_centred_features_match_f64() {
    // Features of mean 100 and spread 0.01, 3 batches in a 4-voxel cube: the posterior's Ψ against an f64
    // evaluation of the paper's equations over the union of all points.
    const D: usize = 4;
    let config = MapConfig::default();
    let mut obs = ObsMap::<D>::new(config).unwrap();
    let mut pts = Vec::new();
    let mut feats = Vec::new();
    for i in 0..600usize {
        let h = |a: u64| (host_sim::sim::mix(a) >> 40) as f64 / (1u64 << 24) as f64;
        pts.push([
            (0.4 * h(i as u64 * 7)) as f32,
            (0.4 * h(i as u64 * 7 + 1)) as f32,
            (0.4 * h(i as u64 * 7 + 2)) as f32,
        ]);
        feats.push(core::array::from_fn::<f32, D, _>(|d| {
            (100.0 + 0.02 * (h(i as u64 * 7 + 3 + d as u64) - 0.5)) as f32
        }));
    }
    for chunk in 0..3 {
        let r = chunk * 200..(chunk + 1) * 200;
        obs.integrate(&Isometry3::identity(), &pts[r.clone()], &feats[r]);
    }
    let lut: latentbki::kernel::KernelLut = latentbki::kernel::KernelLut::new(&config).unwrap();
    let prior = config.prior();
    let mut worst = 0.0f64;
    obs.for_each_posterior(|key, post| {
        // f64: k̄, ȳ, S̄ over every point, then the prior update.
        let mut w = 0.0f64;
        let mut s1 = [0.0f64; D];
        let mut ys = Vec::new();
        for (p, y) in pts.iter().zip(&feats) {
            let k_of =
                latentbki::key::VoxelKey::from_position(*p, 1.0 / config.voxel_size()).unwrap();
            let k = lut.weight_at(0, k_of.x - key.x, k_of.y - key.y, k_of.z - key.z) as f64;
            if k > 0.0 {
                w += k;
                for d in 0..D {
                    s1[d] += k * y[d] as f64;
                }
                ys.push((k, y));
            }
        }
        let m: [f64; D] = core::array::from_fn(|d| s1[d] / w);
        for d in 0..D {
            let s: f64 = ys
                .iter()
                .map(|(k, y)| k * (y[d] as f64 - m[d]).powi(2))
                .sum();
            let l0 = prior.lambda as f64;
            let psi = prior.psi as f64 + s + l0 * w / (l0 + w) * (m[d] - prior.mean as f64).powi(2);
            worst = worst.max((post.psi[d] as f64 - psi).abs() / psi);
        }
    });
    println!(
        "non-centred features (mean 100, spread 0.01): Ψ max relative error vs f64 {worst:.1e}"
    );
    assert!(worst <= 1e-3, "Ψ relative error {worst}");
}

fn point() -> impl Strategy<Value = ([f32; 3], [f32; 3])> {
    (
        prop::array::uniform3(-0.35f32..0.35),
        prop::array::uniform3(-3.0f32..3.0),
    )
}

fn pose() -> impl Strategy<Value = Isometry3<f32>> {
    (
        prop::array::uniform3(-1.0f32..1.0),
        prop::array::uniform3(-3.2f32..3.2),
    )
        .prop_map(|(t, r)| {
            Isometry3::from_parts(
                Translation3::new(t[0], t[1], t[2]),
                UnitQuaternion::from_euler_angles(r[0], r[1], r[2]),
            )
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn random_batches_equal_the_reference_map(
        batches in prop::collection::vec((pose(), prop::collection::vec(point(), 1..80)), 1..5),
        filter in prop::sample::select(vec![1u8, 3, 5]),
        prior_lambda in prop::sample::select(vec![0.0f32, 1.5]),
    ) {
        let prior = Prior { lambda: prior_lambda, mean: 0.1, psi: 1.0 };
        let config = MapConfig::new(0.1, 0.5, filter, prior, KernelMode::VoxelOffset).unwrap();
        let mut obs = ObsMap::<3>::new(config).unwrap();
        let mut reference = ReferenceMap::<3>::new(config).unwrap();
        for (pose, pts) in &batches {
            let (p, y): (Vec<_>, Vec<_>) = pts.iter().copied().unzip();
            prop_assert_eq!(obs.integrate(pose, &p, &y), reference.integrate(pose, &p, &y));
        }
        // The features' magnitude anchors μ's bound (as in `tests/equivalence.rs`).
        let scale = batches
            .iter()
            .flat_map(|(_, pts)| pts.iter().flat_map(|(_, y)| y.iter().map(|v| v.abs())))
            .fold(0.0f32, f32::max);
        let diff = compare(&obs, &reference, scale);
        prop_assert!(diff.worst() <= 1e-5, "{}", diff.line());
        // The single-voxel gather (the core's `gather`, hash lookups) equals the block traversal bit for bit.
        for (key, post) in obs.posteriors_sorted().iter().take(50) {
            prop_assert_eq!(&obs.posterior(*key), post);
        }
        prop_assert!(obs.observed_voxels().all(|(k, _)| obs.observed(k).is_some()));
    }
}
