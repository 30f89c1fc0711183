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
//! Each mode is a pure formula on given standard draws ([`authors_score_variance`] on per-dimension
//! Student-t draws, [`authors_score_variance_from_chi2`] on their χ² parts, [`sound_score_variance`]; tests
//! compare each with an f64 computation on fixed draws) plus a [`Sampler`] that makes the draws fast in
//! f32 with no allocation: eight xorshift128 streams side by side (the loops vectorise), normals by
//! Box–Muller (no rejection), χ² by Marsaglia–Tsang, Student-t by Bailey's polar method. The authors' score
//! is linear in the draw, so the constant part (μ and the PCA mean) drops out of the variance and a draw
//! is one D-dimensional dot product with t_var ⊙ W F̂_w (the decode folded into the compressed space, as
//! in [`crate::decode`]); and since torch draws each t as Z·√(λ/G), given the G's that dot product is
//! normal, so the [`Sampler`] draws one normal per draw instead of D (the same distribution; a test
//! compares the two).
//!
//! Host side only: nothing on the firmware path calls it (it needs neither heap nor f64, though).

mod variates;

use crate::decode::Codebook;
use crate::inference::Spread;
use crate::stats::VoxelStats;
use variates::Variates;

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

/// The authors' score is linear in a draw: score_k = const + Σ_d a_d t_kd with a = t_var ⊙ W F_w / ‖F_w‖.
/// `None` for λ ≤ 2 or an unknown category.
fn authors_coefficients<const D: usize, const K: usize>(
    v: &VoxelStats<D>,
    codebook: &Codebook<D, K>,
    category: usize,
) -> Option<[f32; D]> {
    let f = Spread::AuthorsTVar.factor(v.lambda)?;
    let c = codebook.categories().get(category)?;
    let inv = 1.0 / c.norm;
    Some(core::array::from_fn(|d| {
        f * v.psi[d] * c.direction[d] * inv
    }))
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
    if t.len() < 2 || t.len() > MAX_DRAWS {
        return None;
    }
    let a = authors_coefficients(v, codebook, category)?;
    let mut scores = [0.0f32; MAX_DRAWS];
    for (s, tk) in scores.iter_mut().zip(t) {
        *s = dot(&a, tk);
    }
    Some(variance(&scores[..t.len()]))
}

/// The authors' sampling variance computed from the χ² parts of their draws: torch draws each
/// dimension's t as Z_kd·√(λ/G_kd) (Z normal, G χ²_λ), and the score is linear in the draw, so given the
/// G's the score's random part Σ_d a_d Z_kd √(λ/G_kd) is normal with variance λ·Σ_d a_d²/G_kd: one normal
/// `zeta[k]` per draw replaces D of them — the same distribution as [`authors_score_variance`] (a test
/// checks it), for the χ² draws `chi2[k][d]`. `None` as for [`authors_score_variance`].
pub fn authors_score_variance_from_chi2<const D: usize, const K: usize>(
    v: &VoxelStats<D>,
    codebook: &Codebook<D, K>,
    category: usize,
    chi2: &[[f32; D]],
    zeta: &[f32],
) -> Option<f32> {
    if chi2.len() < 2 || chi2.len() != zeta.len() || chi2.len() > MAX_DRAWS {
        return None;
    }
    let a = authors_coefficients(v, codebook, category)?;
    let a2: [f32; D] = core::array::from_fn(|d| v.lambda * a[d] * a[d]);
    let mut scores = [0.0f32; MAX_DRAWS];
    for ((s, g), z) in scores.iter_mut().zip(chi2).zip(zeta) {
        let mut acc = [0.0f32; D];
        for d in 0..D {
            acc[d] = a2[d] / g[d];
        }
        *s = z * libm::sqrtf(acc.iter().sum::<f32>());
    }
    Some(variance(&scores[..chi2.len()]))
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

/// Draws for [`SamplingMode`]s, fast and without allocation: reuse one per thread.
#[derive(Clone, Debug)]
pub struct Sampler<const D: usize> {
    gen: Variates,
    draws: [[f32; D]; MAX_DRAWS],
    /// χ² per draw (sound mode) or the per-draw normal (authors' mode).
    chi2: [f32; MAX_DRAWS],
}

impl<const D: usize> Sampler<D> {
    /// A sampler seeded with `seed` (same seed, same draws).
    pub fn new(seed: u64) -> Self {
        Self {
            gen: Variates::new(seed),
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

    /// Fill `out` with χ² variates of `nu` > 2 degrees of freedom.
    pub fn fill_chi_squared(&mut self, nu: f32, out: &mut [f32]) {
        self.gen.fill_chi_squared(nu, out);
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
                let g = &mut self.draws[..draws];
                self.gen.fill_chi_squared(v.lambda, g.as_flattened_mut());
                let zeta = &mut self.chi2[..draws];
                self.gen.fill_normal(zeta);
                authors_score_variance_from_chi2(v, codebook, category, g, zeta)
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

#[cfg(test)]
mod tests;
