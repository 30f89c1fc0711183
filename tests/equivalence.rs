//! Batch = streaming = merge = grouped spread = per-voxel observation statistics gathered, in f32, against an
//! f64 evaluation of the paper's equations.
//!
//! Tolerance: |f32 − f64| ≤ 1e-5 · (|f64| + scale), where scale is the magnitude of the inputs that enter the
//! quantity (max |y| for μ, Σ k·y² for Ψ). A pure relative bound is meaningless where an exact result is 0
//! by cancellation, so the input magnitude anchors it.

use latentbki::{obs::ObsStats, stats::VoxelStats, Prior};
use proptest::prelude::*;

const D: usize = 16;

/// The paper's batch update in f64, straight from §III-B.
fn oracle(prior: &Prior, batches: &[Vec<(f64, [f64; D])>]) -> (f64, [f64; D], [f64; D]) {
    let mut lambda = prior.lambda as f64;
    let mut mu = [prior.mean as f64; D];
    let mut psi = [prior.psi as f64; D];
    for batch in batches {
        let k_bar: f64 = batch.iter().map(|(k, _)| k).sum();
        if k_bar <= 0.0 {
            continue;
        }
        let y_bar: [f64; D] =
            core::array::from_fn(|d| batch.iter().map(|(k, y)| k * y[d]).sum::<f64>() / k_bar);
        let s_bar: [f64; D] = core::array::from_fn(|d| {
            batch
                .iter()
                .map(|(k, y)| k * (y[d] - y_bar[d]).powi(2))
                .sum()
        });
        let new_lambda = lambda + k_bar;
        for d in 0..D {
            let e = (y_bar[d] - mu[d]).powi(2);
            psi[d] += s_bar[d] + lambda * k_bar / new_lambda * e;
            mu[d] = (lambda * mu[d] + y_bar[d] * k_bar) / new_lambda;
        }
        lambda = new_lambda;
    }
    (lambda, mu, psi)
}

fn assert_close(
    what: &str,
    got: &VoxelStats<D>,
    exact: &(f64, [f64; D], [f64; D]),
    points: &[(f64, [f64; D])],
    prior: &Prior,
) {
    let y_scale = points
        .iter()
        .flat_map(|(_, y)| y.iter())
        .fold(prior.mean.abs() as f64, |a, v| a.max(v.abs()));
    let psi_scale = points
        .iter()
        .map(|(k, y)| k * y.iter().map(|v| v * v).fold(0.0, f64::max))
        .sum::<f64>()
        + prior.psi as f64
        + (prior.lambda as f64) * (prior.mean as f64).powi(2);
    let lam_scale: f64 = points.iter().map(|(k, _)| k).sum::<f64>() + prior.lambda as f64;
    let tol = |exact: f64, scale: f64| 1e-5 * (exact.abs() + scale);
    assert!(
        (got.lambda as f64 - exact.0).abs() <= tol(exact.0, lam_scale),
        "{what}: lambda {} vs {}",
        got.lambda,
        exact.0
    );
    for d in 0..D {
        assert!(
            (got.mean[d] as f64 - exact.1[d]).abs() <= tol(exact.1[d], y_scale),
            "{what}: mean[{d}] {} vs {}",
            got.mean[d],
            exact.1[d]
        );
        assert!(
            (got.psi[d] as f64 - exact.2[d]).abs() <= tol(exact.2[d], psi_scale),
            "{what}: psi[{d}] {} vs {}",
            got.psi[d],
            exact.2[d]
        );
    }
}

fn f32s(y: &[f64; D]) -> [f32; D] {
    y.map(|v| v as f32)
}

/// A weighted observation: very unequal weights (1e-4 … 1) and features of any sign, some large.
fn observation() -> impl Strategy<Value = (f64, [f64; D])> {
    let weight = prop_oneof![1e-4f64..1e-2, 0.01f64..1.0, Just(1.0)];
    let feature = prop_oneof![-1.0f64..1.0, -100.0f64..100.0];
    (weight, proptest::array::uniform16(feature))
        .prop_map(|(k, y)| ((k as f32) as f64, y.map(|v| (v as f32) as f64)))
}

fn prior() -> impl Strategy<Value = Prior> {
    prop_oneof![
        Just(Prior::default()),
        (0.0f32..3.0, -1.0f32..1.0, 0.0f32..2.0).prop_map(|(lambda, mean, psi)| Prior {
            lambda,
            mean,
            psi
        }),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// One batch through the paper's update, the same points one at a time, and two halves built
    /// independently then merged all give the f64 posterior.
    #[test]
    fn batch_streaming_merge_agree(
        prior in prior(),
        earlier in proptest::collection::vec(observation(), 0..20),
        batch in proptest::collection::vec(observation(), 0..60),
        split in 0usize..60,
    ) {
        let exact = oracle(&prior, &[earlier.clone(), batch.clone()]);
        let all: Vec<_> = earlier.iter().chain(&batch).cloned().collect();
        let start = VoxelStats::<D>::from_prior(&prior);

        // (a) batch: the earlier batch, then the new batch's moments (k̄, ȳ, S̄) in one update.
        let mut a = start;
        for points in [&earlier, &batch] {
            let mut moments = VoxelStats::<D>::EMPTY;
            for (k, y) in points.iter() {
                moments.absorb_point(*k as f32, &f32s(y));
            }
            a.absorb(&moments);
        }
        assert_close("batch", &a, &exact, &all, &prior);

        // (b) streaming: point by point.
        let mut b = start;
        for (k, y) in &all {
            b.absorb_point(*k as f32, &f32s(y));
        }
        assert_close("streaming", &b, &exact, &all, &prior);

        // (c) merge: two maps' statistics of the same voxel (data only, as the maps keep them), merged,
        // then the prior once.
        let cut = split.min(all.len());
        let (mut c, mut other) = (VoxelStats::<D>::EMPTY, VoxelStats::<D>::EMPTY);
        for (k, y) in &all[..cut] { c.absorb_point(*k as f32, &f32s(y)); }
        for (k, y) in &all[cut..] { other.absorb_point(*k as f32, &f32s(y)); }
        c.absorb(&other);
        let mut merged = start;
        merged.absorb(&c);
        assert_close("merge", &merged, &exact, &all, &prior);

        // (d) grouped: points grouped with unit weight, each group seen through one kernel weight
        // (what `spread` does for points that share a voxel).
        let mut g = start;
        for chunk in all.chunks(3) {
            let k = chunk[0].0 as f32;
            let mut group = VoxelStats::<D>::EMPTY;
            for (_, y) in chunk { group.absorb_point(1.0, &f32s(y)); }
            g.absorb_scaled(k, &group);
        }
        let regrouped: Vec<_> = all.chunks(3).flat_map(|c| c.iter().map(move |(_, y)| (c[0].0, *y))).collect();
        let exact_g = oracle(&prior, std::slice::from_ref(&regrouped));
        assert_close("grouped", &g, &exact_g, &regrouped, &prior);

        // (e) observation statistics, as the maps keep them: each group of unit-weight points is one
        // voxel's (n, m, S) (Welford), gathered through its kernel weight (Chan), then the posterior.
        let mut gathered = ObsStats::<D>::EMPTY;
        for chunk in all.chunks(3) {
            let mut voxel = ObsStats::<D>::EMPTY;
            for (_, y) in chunk { voxel.add_point(&f32s(y)); }
            gathered.merge_scaled(chunk[0].0 as f32, &voxel);
        }
        let mut e = start;
        e.absorb_observations(1.0, &gathered);
        assert_close("gathered observations", &e, &exact_g, &regrouped, &prior);
    }
}

#[test]
fn empty_batch_and_single_point() {
    let prior = Prior::default();
    let start = VoxelStats::<D>::from_prior(&prior);
    let mut v = start;
    v.absorb(&VoxelStats::EMPTY);
    assert_eq!(v, start, "an empty batch changes nothing");
    let y = [2.5f32; D];
    v.absorb_point(0.7, &y);
    assert_eq!(v.lambda, 0.7);
    assert_eq!(
        v.mean, y,
        "with λ₀ = 0 the first point's feature is the mean"
    );
    assert_eq!(v.psi, [1.0; D], "a single point adds no scatter");
}
