//! The random variates behind the [`super::Sampler`]: eight xorshift128 streams side by side (struct of
//! arrays, so the loops vectorise), and from them uniforms, normals (Box–Muller, no rejection), χ²
//! (Marsaglia–Tsang) and Student-t (Bailey's polar method), written into caller buffers without a branch
//! per lane. The elementary functions are [`crate::f32math`]'s branch-free variants.

use crate::f32math::{exp2, log2_normal, sin_cos_pi, sqrt};

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

/// The variate generators: the lane RNG and a few cached normals.
#[derive(Clone, Debug)]
pub(super) struct Variates {
    rng: LaneRng,
    normals: [f32; 2 * LANES],
    normals_left: usize,
}

impl Variates {
    /// Generators seeded with `seed` (same seed, same variates).
    pub(super) fn new(seed: u64) -> Self {
        Self {
            rng: LaneRng::seed_from_u64(seed),
            normals: [0.0; 2 * LANES],
            normals_left: 0,
        }
    }

    /// Fill `out` with standard Student-t variates of `nu` > 2 degrees of freedom (Bailey's polar method:
    /// U, V uniform in (−1, 1), W = U² + V² < 1, T = U·√(ν(W^(−2/ν) − 1)/W)).
    pub(super) fn fill_student_t(&mut self, nu: f32, out: &mut [f32]) {
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
                let p = exp2(k * log2_normal(w));
                t[l] = a * sqrt(nu * (p - 1.0) / w);
            }
            n += compact(out, n, &t, &ok);
        }
    }

    /// Fill `out` with standard normal variates (Box–Muller, both of each pair).
    pub(super) fn fill_normal(&mut self, out: &mut [f32]) {
        // Box–Muller: no rejection, so no compaction; both of each pair are used.
        let mut n = 0;
        while n < out.len() {
            let (u, v) = (self.rng.next(), self.rng.next());
            let mut z = [0.0f32; 2 * LANES];
            for l in 0..LANES {
                let r = sqrt(-2.0 * core::f32::consts::LN_2 * log2_normal(open_unit(u[l])));
                let (s, c) = sin_cos_pi(signed_unit(v[l]));
                z[l] = r * c;
                z[l + LANES] = r * s;
            }
            n += put(out, n, &z);
        }
    }

    pub(super) fn normal(&mut self) -> f32 {
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
    pub(super) fn chi_squared(&mut self, nu: f32) -> f32 {
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
                || core::f32::consts::LN_2 * log2_normal(u)
                    < 0.5 * x2 + d * (1.0 - v + libm::logf(v))
            {
                return 2.0 * d * v;
            }
        }
    }

    /// Fill `out` with χ² variates of `nu` > 2 degrees of freedom: 2·Gamma(ν/2) by Marsaglia–Tsang,
    /// eight lanes at a time (the squeeze accepts ~98 %; the logarithmic test runs only for a round where
    /// some lane needs it).
    pub(super) fn fill_chi_squared(&mut self, nu: f32, out: &mut [f32]) {
        let d = 0.5 * nu - 1.0 / 3.0;
        let c = 1.0 / sqrt(9.0 * d);
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
                        let lhs = core::f32::consts::LN_2 * log2_normal(open_unit(u[l]));
                        let rhs = 0.5 * x[l] * x[l]
                            + d * (1.0 - v3 + 3.0 * core::f32::consts::LN_2 * log2_normal(v));
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
