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

const LANES: usize = 8;

/// Eight xorshift128 generators side by side (struct of arrays, so a step is a few vector instructions).
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
        // xorshift128 (Marsaglia 2003) per lane: shifts and xors only, so the step vectorises with SSE2
        // (xoshiro128++'s rotations kept the lanes scalar). The variates use the top 23 bits, where its
        // linear artefacts are weakest; the tests check the distributions.
        let [mut x, mut y, mut z, mut w] = self.s;
        let mut out = [0u32; LANES];
        for l in 0..LANES {
            let t = x[l] ^ (x[l] << 11);
            x[l] = y[l];
            y[l] = z[l];
            z[l] = w[l];
            w[l] = w[l] ^ (w[l] >> 19) ^ (t ^ (t >> 8));
            out[l] = w[l];
        }
        self.s = [x, y, z, w];
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

/// log₂ x for positive normal x, branch-free (vectorises): error below 3e-7 absolute plus the f32
/// rounding of the result.
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

/// 2^y for −126 < y < 127, branch-free (vectorises): relative error below 3e-7.
#[inline(always)]
pub(crate) fn exp2_fast(y: f32) -> f32 {
    // Round to the nearest integer by adding 1.5·2²³ (no float → int conversion, which would not
    // vectorise with Rust's saturating semantics): the integer sits in the low mantissa bits.
    const MAGIC: f32 = 12_582_912.0;
    let r = y + MAGIC;
    let i = r.to_bits().wrapping_sub(MAGIC.to_bits()) as i32;
    let x = (y - (r - MAGIC)) * core::f32::consts::LN_2; // |x| ≤ ½ ln 2
                                                         // e^x, |x| ≤ 0.347: Taylor to x⁶ leaves < 2e-8.
    let p = 1.0
        + x * (1.0
            + x * (0.5
                + x * (1.0 / 6.0 + x * (1.0 / 24.0 + x * (1.0 / 120.0 + x * (1.0 / 720.0))))));
    p * f32::from_bits((i.wrapping_add(127) as u32) << 23)
}

/// √x for finite x ≥ 0, branch-free (vectorises, unlike `libm::sqrtf`'s scalar instruction): the
/// bit-trick reciprocal square root and three Newton steps (relative error < 2e-7), times x.
#[inline(always)]
fn sqrt_fast(x: f32) -> f32 {
    let mut y = f32::from_bits(0x5F37_59DF_u32.wrapping_sub(x.to_bits() >> 1));
    let h = 0.5 * x;
    y *= 1.5 - h * y * y;
    y *= 1.5 - h * y * y;
    y *= 1.5 - h * y * y;
    x * y
}

/// Append `vals[l]` for every `ok[l]` to `out` at `n`, in order (as many as fit); returns how many. The
/// compaction is branch-free (a branch per lane would mispredict ~1 in 5) and, when a whole block fits,
/// stores straight into `out` (a scratch array read back as a vector stalls on store forwarding).
#[inline(always)]
fn compact<const N: usize>(out: &mut [f32], n: usize, vals: &[f32; N], ok: &[bool; N]) -> usize {
    let mut m = 0;
    match out.get_mut(n..n + N) {
        Some(block) => {
            for l in 0..N {
                block[m.min(N - 1)] = vals[l];
                m += usize::from(ok[l]);
            }
            m
        }
        None => {
            let mut kept = [0.0f32; N];
            for l in 0..N {
                kept[m.min(N - 1)] = vals[l];
                m += usize::from(ok[l]);
            }
            let take = m.min(out.len().saturating_sub(n));
            for (o, k) in out.iter_mut().skip(n).zip(&kept[..take]) {
                *o = *k;
            }
            take
        }
    }
}

/// Append the whole block `vals` to `out` at `n` (as many as fit); returns how many were written.
#[inline(always)]
fn put<const N: usize>(out: &mut [f32], n: usize, vals: &[f32; N]) -> usize {
    match out.get_mut(n..n + N) {
        Some(block) => {
            block.copy_from_slice(vals);
            N
        }
        None => {
            let take = N.min(out.len().saturating_sub(n));
            for (o, k) in out.iter_mut().skip(n).zip(vals) {
                *o = *k;
            }
            take
        }
    }
}

/// (sin πx, cos πx) for |x| < 1, branch-free (vectorises): the half angle h = πx/2 by Taylor series
/// (to h¹¹ and h¹², error below 6e-8), then the double-angle formulas.
#[inline(always)]
fn sin_cos_pi(x: f32) -> (f32, f32) {
    let h = x * core::f32::consts::FRAC_PI_2;
    let h2 = h * h;
    let s = h
        * (1.0
            + h2 * (-1.0 / 6.0
                + h2 * (1.0 / 120.0
                    + h2 * (-1.0 / 5040.0 + h2 * (1.0 / 362_880.0 + h2 * (-1.0 / 39_916_800.0))))));
    let c = 1.0
        + h2 * (-0.5
            + h2 * (1.0 / 24.0
                + h2 * (-1.0 / 720.0
                    + h2 * (1.0 / 40_320.0
                        + h2 * (-1.0 / 3_628_800.0 + h2 * (1.0 / 479_001_600.0))))));
    (2.0 * s * c, c * c - s * s)
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
    /// χ² per draw (sound mode) or the per-draw normal (authors' mode).
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
                t[l] = a * sqrt_fast(nu * (p - 1.0) / w);
            }
            n += compact(out, n, &t, &ok);
        }
    }

    /// Fill `out` with standard normal variates (Box–Muller, both of each pair).
    fn fill_normal(&mut self, out: &mut [f32]) {
        // Box–Muller: no rejection, so no compaction; both of each pair are used.
        let mut n = 0;
        while n < out.len() {
            let (u, v) = (self.rng.next(), self.rng.next());
            let mut z = [0.0f32; 2 * LANES];
            for l in 0..LANES {
                let r = sqrt_fast(-2.0 * core::f32::consts::LN_2 * log2_fast(open_unit(u[l])));
                let (s, c) = sin_cos_pi(signed_unit(v[l]));
                z[l] = r * c;
                z[l + LANES] = r * s;
            }
            n += put(out, n, &z);
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

    /// Fill `out` with χ² variates of `nu` > 2 degrees of freedom: 2·Gamma(ν/2) by Marsaglia–Tsang,
    /// eight lanes at a time (the squeeze accepts ~98 %; the logarithmic test runs only for a round where
    /// some lane needs it).
    fn fill_chi_squared(&mut self, nu: f32, out: &mut [f32]) {
        let d = 0.5 * nu - 1.0 / 3.0;
        let c = 1.0 / sqrt_fast(9.0 * d);
        let mut normals = [0.0f32; 8 * LANES];
        let mut n = 0;
        while n < out.len() {
            self.fill_normal(&mut normals);
            for x in normals.chunks_exact(LANES) {
                let u = self.rng.next();
                let mut g = [0.0f32; LANES];
                let mut ok = [false; LANES];
                let mut doubt = [false; LANES];
                for l in 0..LANES {
                    let v = 1.0 + c * x[l];
                    let v3 = v * v * v;
                    let x2 = x[l] * x[l];
                    let u = open_unit(u[l]);
                    // `&`, not `&&`: no branch, so the loop vectorises.
                    ok[l] = (v > 0.0) & (u < 1.0 - 0.0331 * x2 * x2);
                    doubt[l] = (v > 0.0) & !ok[l];
                    g[l] = 2.0 * d * v3;
                }
                if doubt.iter().any(|&b| b) {
                    // The logarithmic test for every lane at once (branch-free, vectorises); only the
                    // doubtful lanes take its answer.
                    for l in 0..LANES {
                        let v = 1.0 + c * x[l];
                        let v = if doubt[l] { v } else { 1.0 };
                        let v3 = v * v * v;
                        let lhs = core::f32::consts::LN_2 * log2_fast(open_unit(u[l]));
                        let rhs = 0.5 * x[l] * x[l]
                            + d * (1.0 - v3 + 3.0 * core::f32::consts::LN_2 * log2_fast(v));
                        ok[l] |= doubt[l] & (lhs < rhs);
                    }
                }
                n += compact(out, n, &g, &ok);
                if n == out.len() {
                    return;
                }
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
                zeta[k] as f64
                    * (l * (0..D).map(|d| a[d] * a[d] / g[k][d] as f64).sum::<f64>()).sqrt()
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
    fn fast_elementary_functions_are_accurate() {
        let mut worst = [0.0f64; 3];
        for i in 1..200_000 {
            let x = i as f32 / 200_000.0; // (0, 1): the polar method's W, Box–Muller's u
            let l = log2_fast(x) as f64;
            // Absolute error plus the f32 rounding of the result.
            worst[0] = worst[0].max((l - (x as f64).log2()).abs() / (1.0 + l.abs()));
            let y = i as f32 * (46.0 / 200_000.0);
            let e = exp2_fast(y) as f64;
            worst[1] = worst[1].max((e / 2f64.powf(y as f64) - 1.0).abs());
            let z = x * 1e4 * (i as f32);
            let r = sqrt_fast(z) as f64;
            worst[2] = worst[2].max((r / (z as f64).sqrt() - 1.0).abs());
        }
        assert!(
            worst[0] < 5e-7 && worst[1] < 5e-7 && worst[2] < 5e-7,
            "{worst:?}"
        );
        assert_eq!(sqrt_fast(0.0), 0.0);
        let mut trig = 0.0f64;
        for i in -100_000..100_000 {
            let x = i as f32 / 100_000.0;
            let (s, c) = sin_cos_pi(x);
            let a = core::f64::consts::PI * x as f64;
            trig = trig
                .max((s as f64 - libm::sin(a)).abs())
                .max((c as f64 - libm::cos(a)).abs());
        }
        assert!(trig < 5e-7, "sin/cos error {trig:e}");
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
}
