//! Sampling uncertainty (§III-D): draw features from a voxel's predictive, decode each draw against a
//! text embedding, report the variance of the score over the draws — the paper's expensive reference
//! for E-/D-optimality.
//!
//! Two modes ([`SamplingMode`]), because the authors' released code (`open_vocabulary_search.py`,
//! `sampling_for_variance`) does not sample the model's predictive:
//!
//! | | [`SamplingMode::Authors`] (their code) | [`SamplingMode::Sound`] (the model) |
//! |---|---|---|
//! | draw | torch `StudentT(df=λ, loc=μ, scale=t_var)`: every dimension its own χ² | multivariate t: one χ²_λ per draw shared by all dimensions |
//! | scale | t_var = (λ+1)/λ²·Ψ, passed as the scale (no square root) | √((λ+1)/λ²·Ψ) |
//! | score | plain dot of the back-projected, un-normalised draw with the normalised text embedding | cosine (what the map decodes with) |
//! | gate, draws | λ > 2, 30 | λ > 2 (the score's variance exists), 30 |
//! | reported | sample variance (n − 1) of the query's score | same |
//!
//! Each mode is a pure formula on given standard draws ([`authors_score_variance`],
//! [`sound_score_variance`]; tests compare them with f64 computations on fixed draws) plus a
//! [`Sampler`] that makes the draws fast in f32 with no allocation: eight xoshiro128++ streams side by
//! side (the loops vectorise), Student-t variates by Bailey's polar method (one t from two uniforms, a
//! log₂ and an exp₂, the same distribution torch draws as normal/√(χ²/λ)), normals by Marsaglia's polar
//! method, χ² by Marsaglia–Tsang. The authors' score is linear in the draw, so the constant part
//! (μ and the PCA mean) drops out of the variance and a draw costs one D-dimensional dot product with
//! t_var ⊙ W F̂_w (the decode folded into the compressed space, as in [`crate::decode`]).
//!
//! Host side only: nothing on the firmware path calls it (it needs neither heap nor f64, though).

use crate::decode::Codebook;
use crate::inference::Spread;
use crate::stats::VoxelStats;

/// Draws per voxel in the authors' code (`sample_size = 30`).
pub const AUTHORS_DRAWS: usize = 30;
/// Most draws a [`Sampler`] holds.
pub const MAX_DRAWS: usize = 64;

/// Which sampling procedure (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SamplingMode {
    /// The authors' released procedure, step for step.
    Authors,
    /// The model's predictive (multivariate t) decoded with the map's cosine score.
    Sound,
}

impl SamplingMode {
    /// Short name for tables.
    pub fn name(self) -> &'static str {
        match self {
            Self::Authors => "authors' procedure",
            Self::Sound => "multivariate t, cosine",
        }
    }
}

/// Sample variance (n − 1) of `xs` (two passes; NaN for fewer than 2 values).
fn variance(xs: &[f32]) -> f32 {
    let n = xs.len() as f32;
    let mean = xs.iter().sum::<f32>() / n;
    xs.iter().map(|x| (x - mean) * (x - mean)).sum::<f32>() / (n - 1.0)
}

/// The authors' sampling variance of category `category`'s score given standard Student-t(λ) draws
/// `t[k][d]` (one per draw and dimension): x_k = μ + t_var ⊙ t_k, score_k = (Wᵀx_k + m) · F_w/‖F_w‖.
/// `None` for λ ≤ 2, fewer than 2 draws or an unknown category.
pub fn authors_score_variance<const D: usize, const K: usize>(
    v: &VoxelStats<D>,
    codebook: &Codebook<D, K>,
    category: usize,
    t: &[[f32; D]],
) -> Option<f32> {
    let f = Spread::AuthorsTVar.factor(v.lambda)?;
    let c = codebook.categories().get(category)?;
    if t.len() < 2 || t.len() > MAX_DRAWS {
        return None;
    }
    // score_k = const + Σ_d a_d t_kd with a = t_var ⊙ W F_w / ‖F_w‖.
    let inv = 1.0 / c.norm;
    let a: [f32; D] = core::array::from_fn(|d| f * v.psi[d] * c.direction[d] * inv);
    let mut scores = [0.0f32; MAX_DRAWS];
    for (s, tk) in scores.iter_mut().zip(t) {
        *s = dot(&a, tk);
    }
    Some(variance(&scores[..t.len()]))
}

/// The sound sampling variance of category `category`'s cosine score given standard normal draws
/// `z[k][d]` and one χ²_λ draw `chi2[k]` per draw: x_k = μ + √scale ⊙ z_k · √(λ/χ²_k).
/// `None` for λ ≤ 2, fewer than 2 draws, mismatched lengths or an unknown category.
pub fn sound_score_variance<const D: usize, const K: usize>(
    v: &VoxelStats<D>,
    codebook: &Codebook<D, K>,
    category: usize,
    z: &[[f32; D]],
    chi2: &[f32],
) -> Option<f32> {
    Spread::AuthorsTVar.factor(v.lambda)?; // the λ > 2 gate
    let f = v.scale_factor()?;
    if category >= codebook.len() || z.len() < 2 || z.len() != chi2.len() || z.len() > MAX_DRAWS {
        return None;
    }
    let sd: [f32; D] = core::array::from_fn(|d| libm::sqrtf(f * v.psi[d]));
    let mut scores = [0.0f32; MAX_DRAWS];
    let mut x = [0.0f32; D];
    for ((s, zk), &g) in scores.iter_mut().zip(z).zip(chi2) {
        let w = libm::sqrtf(v.lambda / g.max(f32::MIN_POSITIVE));
        for d in 0..D {
            x[d] = v.mean[d] + sd[d] * zk[d] * w;
        }
        *s = codebook.score(&x, category);
    }
    Some(variance(&scores[..z.len()]))
}

fn dot<const D: usize>(a: &[f32; D], b: &[f32; D]) -> f32 {
    // Four partial sums: shorter dependency chains, and the loop vectorises.
    let mut acc = [0.0f32; 8];
    let chunks = a.chunks_exact(8).zip(b.chunks_exact(8));
    for (x, y) in chunks {
        for l in 0..8 {
            acc[l] += x[l] * y[l];
        }
    }
    let tail = D - D % 8;
    let mut s = acc.iter().sum::<f32>();
    for d in tail..D {
        s += a[d] * b[d];
    }
    s
}

const LANES: usize = 8;

/// Eight xoshiro128++ generators side by side (struct of arrays, so a step is a few vector instructions).
#[derive(Clone, Debug)]
struct LaneRng {
    s: [[u32; LANES]; 4],
}

impl LaneRng {
    fn seed_from_u64(seed: u64) -> Self {
        // SplitMix64 expands the seed; a zero lane state is impossible (each lane gets 128 mixed bits).
        let mut x = seed;
        let mut next = || {
            x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = x;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        };
        let mut s = [[0u32; LANES]; 4];
        for l in 0..LANES {
            let (a, b) = (next(), next());
            s[0][l] = a as u32;
            s[1][l] = (a >> 32) as u32;
            s[2][l] = b as u32;
            s[3][l] = (b >> 32) as u32 | 1;
        }
        Self { s }
    }

    #[inline(always)]
    fn next(&mut self) -> [u32; LANES] {
        let [s0, s1, s2, s3] = &mut self.s;
        let mut out = [0u32; LANES];
        for l in 0..LANES {
            out[l] = s0[l].wrapping_add(s3[l]).rotate_left(7).wrapping_add(s0[l]);
            let t = s1[l] << 9;
            s2[l] ^= s0[l];
            s3[l] ^= s1[l];
            s1[l] ^= s2[l];
            s0[l] ^= s3[l];
            s2[l] ^= t;
            s3[l] = s3[l].rotate_left(11);
        }
        out
    }
}

/// A uniform in (−1, 1), never 0: (k + ½)·2⁻²² − 1 for the top 23 bits k (exact in f32).
#[inline(always)]
fn signed_unit(u: u32) -> f32 {
    ((u >> 9) as f32 + 0.5) * (1.0 / 4_194_304.0) - 1.0
}

/// A uniform in (0, 1), never 0.
#[inline(always)]
fn open_unit(u: u32) -> f32 {
    ((u >> 9) as f32 + 0.5) * (1.0 / 8_388_608.0)
}

/// log₂ x for positive normal x, branch-free (vectorises): error below 3e-7 absolute.
#[inline(always)]
fn log2_fast(x: f32) -> f32 {
    let bits = x.to_bits();
    let e = ((bits >> 23) as i32 - 127) as f32;
    let m = f32::from_bits((bits & 0x007F_FFFF) | 0x3F80_0000);
    let big = m > core::f32::consts::SQRT_2;
    let m = if big { m * 0.5 } else { m };
    let e = if big { e + 1.0 } else { e };
    let t = (m - 1.0) / (m + 1.0);
    let t2 = t * t;
    let series = 1.0 + t2 * (1.0 / 3.0 + t2 * (1.0 / 5.0 + t2 * (1.0 / 7.0 + t2 * (1.0 / 9.0))));
    e + 2.0 * core::f32::consts::LOG2_E * t * series
}

/// 2^y for 0 ≤ y < 127, branch-free: relative error below 3e-7.
#[inline(always)]
fn exp2_fast(y: f32) -> f32 {
    let i = y as i32; // y ≥ 0: truncation is the floor
    let f = y - i as f32 - 0.5; // [−½, ½)
    let x = f * core::f32::consts::LN_2;
    // e^x, |x| ≤ 0.347: Taylor to x⁶ leaves < 2e-8.
    let p = 1.0
        + x * (1.0
            + x * (0.5 + x * (1.0 / 6.0 + x * (1.0 / 24.0 + x * (1.0 / 120.0 + x * (1.0 / 720.0))))));
    p * core::f32::consts::SQRT_2 * f32::from_bits(((i + 127) as u32) << 23)
}

/// The variate generators: the lane RNG and a few cached normals.
#[derive(Clone, Debug)]
struct Variates {
    rng: LaneRng,
    normals: [f32; 2 * LANES],
    normals_left: usize,
}

/// Draws for [`SamplingMode`]s, fast and without allocation: reuse one per thread.
#[derive(Clone, Debug)]
pub struct Sampler<const D: usize> {
    gen: Variates,
    draws: [[f32; D]; MAX_DRAWS],
    chi2: [f32; MAX_DRAWS],
}

impl<const D: usize> Sampler<D> {
    /// A sampler seeded with `seed` (same seed, same draws).
    pub fn new(seed: u64) -> Self {
        Self {
            gen: Variates {
                rng: LaneRng::seed_from_u64(seed),
                normals: [0.0; 2 * LANES],
                normals_left: 0,
            },
            draws: [[0.0; D]; MAX_DRAWS],
            chi2: [0.0; MAX_DRAWS],
        }
    }

    /// Fill `out` with standard Student-t variates of `nu` > 2 degrees of freedom.
    pub fn fill_student_t(&mut self, nu: f32, out: &mut [f32]) {
        self.gen.fill_student_t(nu, out);
    }

    /// Fill `out` with standard normal variates.
    pub fn fill_normal(&mut self, out: &mut [f32]) {
        self.gen.fill_normal(out);
    }

    /// A χ² variate of `nu` > 2 degrees of freedom.
    pub fn chi_squared(&mut self, nu: f32) -> f32 {
        self.gen.chi_squared(nu)
    }
    /// Sampling uncertainty of one voxel: the variance over `draws` draws (≤ [`MAX_DRAWS`]) of the score
    /// of `category` in `codebook`, by `mode`. `None` for λ ≤ 2, fewer than 2 draws or an unknown
    /// category (checked before anything is drawn).
    pub fn score_variance<const K: usize>(
        &mut self,
        mode: SamplingMode,
        v: &VoxelStats<D>,
        codebook: &Codebook<D, K>,
        category: usize,
        draws: usize,
    ) -> Option<f32> {
        if !(v.lambda > 2.0) || !(2..=MAX_DRAWS).contains(&draws) || category >= codebook.len() {
            return None;
        }
        match mode {
            SamplingMode::Authors => {
                let t = &mut self.draws[..draws];
                self.gen.fill_student_t(v.lambda, t.as_flattened_mut());
                authors_score_variance(v, codebook, category, t)
            }
            SamplingMode::Sound => {
                let z = &mut self.draws[..draws];
                self.gen.fill_normal(z.as_flattened_mut());
                let chi2 = &mut self.chi2[..draws];
                for g in chi2.iter_mut() {
                    *g = self.gen.chi_squared(v.lambda);
                }
                sound_score_variance(v, codebook, category, z, chi2)
            }
        }
    }

    /// The authors' procedure for every category at once (their code decodes each draw into all
    /// categories): variances written into `out` (as many as fit); returns how many. 0 if gated.
    pub fn authors_all_categories<const K: usize>(
        &mut self,
        v: &VoxelStats<D>,
        codebook: &Codebook<D, K>,
        draws: usize,
        out: &mut [f32],
    ) -> usize {
        if !(v.lambda > 2.0) || !(2..=MAX_DRAWS).contains(&draws) {
            return 0;
        }
        let t = &mut self.draws[..draws];
        self.gen.fill_student_t(v.lambda, t.as_flattened_mut());
        let mut n = 0;
        for (c, o) in out.iter_mut().enumerate().take(codebook.len()) {
            if let Some(var) = authors_score_variance(v, codebook, c, t) {
                *o = var;
                n += 1;
            }
        }
        n
    }
}

impl Variates {
    /// Fill `out` with standard Student-t variates of `nu` > 2 degrees of freedom (Bailey's polar method:
    /// U, V uniform in (−1, 1), W = U² + V² < 1, T = U·√(ν(W^(−2/ν) − 1)/W)).
    fn fill_student_t(&mut self, nu: f32, out: &mut [f32]) {
        let k = -2.0 / nu;
        let mut n = 0;
        while n < out.len() {
            let (u, v) = (self.rng.next(), self.rng.next());
            let mut t = [0.0f32; LANES];
            let mut ok = [false; LANES];
            for l in 0..LANES {
                let a = signed_unit(u[l]);
                let b = signed_unit(v[l]);
                let w = a * a + b * b;
                ok[l] = w < 1.0;
                let w = if ok[l] { w } else { 0.5 };
                let p = exp2_fast(k * log2_fast(w));
                t[l] = a * libm::sqrtf(nu * (p - 1.0) / w);
            }
            for l in 0..LANES {
                if ok[l] {
                    if let Some(o) = out.get_mut(n) {
                        *o = t[l];
                        n += 1;
                    }
                }
            }
        }
    }

    /// Fill `out` with standard normal variates (Marsaglia's polar method, both of each pair).
    fn fill_normal(&mut self, out: &mut [f32]) {
        let mut n = 0;
        while n < out.len() {
            let (u, v) = (self.rng.next(), self.rng.next());
            let mut z = [[0.0f32; 2]; LANES];
            let mut ok = [false; LANES];
            for l in 0..LANES {
                let a = signed_unit(u[l]);
                let b = signed_unit(v[l]);
                let w = a * a + b * b;
                ok[l] = w < 1.0;
                let w = if ok[l] { w } else { 0.5 };
                let f = libm::sqrtf(-2.0 * core::f32::consts::LN_2 * log2_fast(w) / w);
                z[l] = [a * f, b * f];
            }
            for l in 0..LANES {
                if ok[l] {
                    for v in z[l] {
                        if let Some(o) = out.get_mut(n) {
                            *o = v;
                            n += 1;
                        }
                    }
                }
            }
        }
    }

    fn normal(&mut self) -> f32 {
        if self.normals_left == 0 {
            let mut buf = [0.0f32; 2 * LANES];
            self.fill_normal(&mut buf);
            self.normals = buf;
            self.normals_left = buf.len();
        }
        self.normals_left -= 1;
        self.normals[self.normals_left]
    }

    /// A χ² variate of `nu` > 2 degrees of freedom: 2·Gamma(ν/2) by Marsaglia–Tsang (shape ≥ 1).
    fn chi_squared(&mut self, nu: f32) -> f32 {
        let d = 0.5 * nu - 1.0 / 3.0;
        let c = 1.0 / libm::sqrtf(9.0 * d);
        loop {
            let x = self.normal();
            let v = 1.0 + c * x;
            if v <= 0.0 {
                continue;
            }
            let v = v * v * v;
            let u = open_unit(self.rng.next()[0]);
            let x2 = x * x;
            if u < 1.0 - 0.0331 * x2 * x2
                || core::f32::consts::LN_2 * log2_fast(u) < 0.5 * x2 + d * (1.0 - v + libm::logf(v))
            {
                return 2.0 * d * v;
            }
        }
    }
}

#[cfg(test)]
mod tests {
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
            p.mean[j] as f64 + (0..D).map(|d| p.components[d][j] as f64 * x[d]).sum::<f64>()
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
            assert!((got - want).abs() <= 1e-5 * want, "category {c}: {got} vs {want}");
        }
        let young = VoxelStats { lambda: 2.0, ..v };
        assert!(authors_score_variance(&young, &cb, 0, &t).is_none(), "λ > 2 gate");
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
            assert!((got - want).abs() <= 1e-4 * want, "category {c}: {got} vs {want}");
        }
        assert!(sound_score_variance(&v, &cb, 0, &z, &chi2[..5]).is_none());
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
            assert!((v / want - 1.0).abs() < tol, "t({nu}) variance {v} vs {want}");
            // P(|T| < 1): 0.6187 (ν = 3.5), 0.6591 (ν = 10), by numerical integration of the density.
            let p = if nu < 4.0 { 0.6187 } else { 0.6591 };
            let inside = buf.iter().filter(|x| x.abs() < 1.0).count() as f64 / buf.len() as f64;
            assert!((inside - p).abs() < 0.005, "t({nu}): P(|T| < 1) = {inside} vs {p}");
        }
        let g: [f32; 20_000] = core::array::from_fn(|_| s.chi_squared(6.0));
        let (m, v) = moments(&g);
        assert!((m - 6.0).abs() < 0.1 && (v / 12.0 - 1.0).abs() < 0.05, "χ²₆: {m} {v}");
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
            assert!(s.score_variance(mode, &tight, &cb, 1, MAX_DRAWS + 1).is_none());
        }
        let mut all = [0.0f32; 3];
        assert_eq!(s.authors_all_categories(&tight, &cb, 30, &mut all), 3);
        assert!(all.iter().all(|&v| v > 0.0));
    }
}
