//! The sampling formulas against f64 computations on fixed draws, and the variates' distributions.

use super::*;
use crate::decode::Pca;

const D: usize = 4;
const F: usize = 6;

/// A PCA 6 → 4 with orthonormal rows (a rotation of the first four axes) and a non-zero mean.
fn pca() -> Pca<D, F> {
    let (c, s) = (0.8f32, 0.6f32);
    Pca {
        mean: [0.3, -0.2, 0.1, 0.5, -0.4, 0.25],
        components: [
            [c, s, 0.0, 0.0, 0.0, 0.0],
            [-s, c, 0.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, 0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 0.0, 0.0, c, s],
        ],
    }
}

fn embeddings() -> [[f32; F]; 3] {
    [
        [1.0, 0.5, -0.3, 0.2, 0.0, 0.7],
        [-0.4, 1.2, 0.3, -0.8, 0.5, 0.1],
        [0.2, -0.1, 0.9, 0.4, -1.1, 0.3],
    ]
}

fn voxel() -> VoxelStats<D> {
    VoxelStats {
        lambda: 4.5,
        mean: [0.4, -0.3, 0.8, 0.1],
        psi: [0.9, 2.5, 0.4, 1.6],
    }
}

fn back_project_f64(p: &Pca<D, F>, x: &[f64; D]) -> [f64; F] {
    core::array::from_fn(|j| {
        p.mean[j] as f64
            + (0..D)
                .map(|d| p.components[d][j] as f64 * x[d])
                .sum::<f64>()
    })
}

fn variance_f64(xs: &[f64]) -> f64 {
    let n = xs.len() as f64;
    let m = xs.iter().sum::<f64>() / n;
    xs.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0)
}

/// The authors' formula, literally in f64 (their `StudentT(df, loc=μ, scale=t_var)` on the given
/// standard draws, `backproject_to_clip`, `@ clip_text.T` with the normalised text, variance / (n−1)),
/// equals the folded f32 computation on the same draws.
#[test]
fn authors_formula_equals_f64_on_fixed_draws() {
    let p = pca();
    let emb = embeddings();
    let cb = Codebook::<D, 3>::from_pca(&p, &emb).unwrap();
    let v = voxel();
    let mut sampler = Sampler::<D>::new(11);
    let mut t = [[0.0f32; D]; AUTHORS_DRAWS];
    sampler.fill_student_t(v.lambda, t.as_flattened_mut());
    let l = v.lambda as f64;
    for (c, e) in emb.iter().enumerate() {
        let norm = e.iter().map(|x| (*x as f64).powi(2)).sum::<f64>().sqrt();
        let scores: [f64; AUTHORS_DRAWS] = core::array::from_fn(|k| {
            let x: [f64; D] = core::array::from_fn(|d| {
                v.mean[d] as f64 + (l + 1.0) / (l * l) * v.psi[d] as f64 * t[k][d] as f64
            });
            let full = back_project_f64(&p, &x);
            (0..F).map(|j| full[j] * e[j] as f64 / norm).sum()
        });
        let want = variance_f64(&scores);
        let got = authors_score_variance(&v, &cb, c, &t).unwrap() as f64;
        assert!(
            (got - want).abs() <= 1e-5 * want,
            "category {c}: {got} vs {want}"
        );
    }
    let young = VoxelStats { lambda: 2.0, ..v };
    assert!(
        authors_score_variance(&young, &cb, 0, &t).is_none(),
        "λ > 2 gate"
    );
    assert!(authors_score_variance(&v, &cb, 3, &t).is_none());
    assert!(authors_score_variance(&v, &cb, 0, &t[..1]).is_none());
}

/// The sound formula (multivariate t: √scale, one χ² per draw; cosine of the back-projected draw),
/// literally in f64, equals the f32 computation on the same draws.
#[test]
fn sound_formula_equals_f64_on_fixed_draws() {
    let p = pca();
    let emb = embeddings();
    let cb = Codebook::<D, 3>::from_pca(&p, &emb).unwrap();
    let v = voxel();
    let mut sampler = Sampler::<D>::new(12);
    let mut z = [[0.0f32; D]; AUTHORS_DRAWS];
    sampler.fill_normal(z.as_flattened_mut());
    let chi2: [f32; AUTHORS_DRAWS] = core::array::from_fn(|_| sampler.chi_squared(v.lambda));
    let l = v.lambda as f64;
    for (c, e) in emb.iter().enumerate() {
        let norm = e.iter().map(|x| (*x as f64).powi(2)).sum::<f64>().sqrt();
        let scores: [f64; AUTHORS_DRAWS] = core::array::from_fn(|k| {
            let w = (l / chi2[k] as f64).sqrt();
            let x: [f64; D] = core::array::from_fn(|d| {
                let sd = ((l + 1.0) / (l * l) * v.psi[d] as f64).sqrt();
                v.mean[d] as f64 + sd * z[k][d] as f64 * w
            });
            let full = back_project_f64(&p, &x);
            let fnorm = full.iter().map(|x| x * x).sum::<f64>().sqrt();
            (0..F).map(|j| full[j] * e[j] as f64).sum::<f64>() / (fnorm * norm)
        });
        let want = variance_f64(&scores);
        let got = sound_score_variance(&v, &cb, c, &z, &chi2).unwrap() as f64;
        assert!(
            (got - want).abs() <= 1e-4 * want,
            "category {c}: {got} vs {want}"
        );
    }
    assert!(sound_score_variance(&v, &cb, 0, &z, &chi2[..5]).is_none());
}

/// The χ² form of the authors' formula, literally in f64 on fixed draws: score_k − const =
/// ζ_k·√(λ Σ_d a_d²/G_kd), a = t_var ⊙ W F_w/‖F_w‖ with W F_w from the full-dimensional embedding.
#[test]
fn authors_chi2_form_equals_f64_on_fixed_draws() {
    let p = pca();
    let emb = embeddings();
    let cb = Codebook::<D, 3>::from_pca(&p, &emb).unwrap();
    let v = voxel();
    let mut sampler = Sampler::<D>::new(13);
    let mut g = [[0.0f32; D]; AUTHORS_DRAWS];
    sampler.fill_chi_squared(v.lambda, g.as_flattened_mut());
    let mut zeta = [0.0f32; AUTHORS_DRAWS];
    sampler.fill_normal(&mut zeta);
    let l = v.lambda as f64;
    for (c, e) in emb.iter().enumerate() {
        let norm = e.iter().map(|x| (*x as f64).powi(2)).sum::<f64>().sqrt();
        let a: [f64; D] = core::array::from_fn(|d| {
            let wf: f64 = (0..F)
                .map(|j| p.components[d][j] as f64 * e[j] as f64)
                .sum();
            (l + 1.0) / (l * l) * v.psi[d] as f64 * wf / norm
        });
        let scores: [f64; AUTHORS_DRAWS] = core::array::from_fn(|k| {
            zeta[k] as f64 * (l * (0..D).map(|d| a[d] * a[d] / g[k][d] as f64).sum::<f64>()).sqrt()
        });
        let want = variance_f64(&scores);
        let got = authors_score_variance_from_chi2(&v, &cb, c, &g, &zeta).unwrap() as f64;
        assert!(
            (got - want).abs() <= 1e-5 * want,
            "category {c}: {got} vs {want}"
        );
    }
    assert!(authors_score_variance_from_chi2(&v, &cb, 0, &g, &zeta[..4]).is_none());
}

/// The sampler's authors' path (χ² form, one normal per draw) and the literal per-dimension Student-t
/// draws give the same distribution of the 30-draw variance: both means match the exact expectation
/// Σ_d a_d² λ/(λ−2), and their quartiles agree.
#[test]
fn authors_chi2_form_has_the_literal_distribution() {
    let p = pca();
    let cb = Codebook::<D, 3>::from_pca(&p, &embeddings()).unwrap();
    let v = VoxelStats {
        lambda: 9.0,
        ..voxel()
    };
    let c = cb.categories()[1];
    let f = (v.lambda + 1.0) / (v.lambda * v.lambda);
    let exact: f64 = (0..D)
        .map(|d| (f * v.psi[d] * c.direction[d] / c.norm) as f64)
        .map(|a| a * a * v.lambda as f64 / (v.lambda as f64 - 2.0))
        .sum();
    const REPS: usize = 6000;
    let mut s = Sampler::<D>::new(21);
    let mut fast = [0.0f32; REPS];
    let mut literal = [0.0f32; REPS];
    let mut t = [[0.0f32; D]; AUTHORS_DRAWS];
    for r in 0..REPS {
        fast[r] = s
            .score_variance(SamplingMode::Authors, &v, &cb, 1, AUTHORS_DRAWS)
            .unwrap();
        s.fill_student_t(v.lambda, t.as_flattened_mut());
        literal[r] = authors_score_variance(&v, &cb, 1, &t).unwrap();
    }
    for (name, xs) in [("fast", &mut fast), ("literal", &mut literal)] {
        let (m, _) = moments(&xs[..]);
        assert!(
            (m / exact - 1.0).abs() < 0.04,
            "{name}: mean {m} vs {exact}"
        );
        xs.sort_by(f32::total_cmp);
    }
    for q in [REPS / 4, REPS / 2, 3 * REPS / 4] {
        let (a, b) = (fast[q] as f64, literal[q] as f64);
        assert!((a / b - 1.0).abs() < 0.05, "quantile {q}: {a} vs {b}");
    }
}

fn moments(xs: &[f32]) -> (f64, f64) {
    let n = xs.len() as f64;
    let m = xs.iter().map(|&x| x as f64).sum::<f64>() / n;
    let v = xs.iter().map(|&x| (x as f64 - m).powi(2)).sum::<f64>() / (n - 1.0);
    (m, v)
}

/// The fast variates have their distributions' moments and central probabilities.
#[test]
fn variates_have_their_distributions() {
    let mut s = Sampler::<D>::new(3);
    let mut buf = [0.0f32; 200_000];
    s.fill_normal(&mut buf);
    let (m, v) = moments(&buf);
    assert!(m.abs() < 0.01 && (v - 1.0).abs() < 0.01, "normal: {m} {v}");
    let inside = buf.iter().filter(|x| x.abs() < 1.0).count() as f64 / buf.len() as f64;
    assert!((inside - 0.682_689).abs() < 0.004, "P(|z| < 1) = {inside}");
    for nu in [3.5f32, 10.0] {
        s.fill_student_t(nu, &mut buf);
        let (m, v) = moments(&buf);
        let want = nu as f64 / (nu as f64 - 2.0);
        assert!(m.abs() < 0.02, "t({nu}) mean {m}");
        // ν = 3.5 has a heavy fourth moment: the sample variance converges slowly.
        let tol = if nu < 4.0 { 0.15 } else { 0.03 };
        assert!(
            (v / want - 1.0).abs() < tol,
            "t({nu}) variance {v} vs {want}"
        );
        // P(|T| < 1): 0.6187 (ν = 3.5), 0.6591 (ν = 10), by numerical integration of the density.
        let p = if nu < 4.0 { 0.6187 } else { 0.6591 };
        let inside = buf.iter().filter(|x| x.abs() < 1.0).count() as f64 / buf.len() as f64;
        assert!(
            (inside - p).abs() < 0.005,
            "t({nu}): P(|T| < 1) = {inside} vs {p}"
        );
    }
    let g: [f32; 20_000] = core::array::from_fn(|_| s.chi_squared(6.0));
    let (m, v) = moments(&g);
    assert!(
        (m - 6.0).abs() < 0.1 && (v / 12.0 - 1.0).abs() < 0.05,
        "χ²₆: {m} {v}"
    );
    // The vectorised fill, at a small and a large ν (mean ν, variance 2ν).
    for nu in [2.5f32, 40.0] {
        s.fill_chi_squared(nu, &mut buf);
        let (m, v) = moments(&buf);
        let nu = nu as f64;
        assert!((m / nu - 1.0).abs() < 0.01, "χ²({nu}) mean {m}");
        assert!((v / (2.0 * nu) - 1.0).abs() < 0.03, "χ²({nu}) variance {v}");
        assert!(buf.iter().all(|&x| x > 0.0 && x.is_finite()));
    }
}

#[test]
fn sampler_gates_and_grows_with_scatter() {
    let p = pca();
    let cb = Codebook::<D, 3>::from_pca(&p, &embeddings()).unwrap();
    let mut s = Sampler::<D>::new(5);
    let tight = voxel();
    let loose = tight;
    let tight = VoxelStats {
        psi: tight.psi.map(|x| 0.01 * x),
        ..tight
    };
    for mode in [SamplingMode::Authors, SamplingMode::Sound] {
        let a = s.score_variance(mode, &tight, &cb, 1, 30).unwrap();
        let b = s.score_variance(mode, &loose, &cb, 1, 30).unwrap();
        assert!(b > 3.0 * a, "{mode:?}: tight {a} loose {b}");
        let young = VoxelStats {
            lambda: 2.0,
            ..tight
        };
        assert!(s.score_variance(mode, &young, &cb, 1, 30).is_none());
        assert!(s.score_variance(mode, &tight, &cb, 1, 1).is_none());
        assert!(s.score_variance(mode, &tight, &cb, 3, 30).is_none());
        assert!(s
            .score_variance(mode, &tight, &cb, 1, MAX_DRAWS + 1)
            .is_none());
    }
    let mut all = [0.0f32; 3];
    assert_eq!(s.authors_all_categories(&tight, &cb, 30, &mut all), 3);
    assert!(all.iter().all(|&v| v > 0.0));
}
