//! Inference and uncertainty from a voxel's posterior (§III-C, §III-D).
//!
//! The posterior predictive of a voxel is a Student-t with λ degrees of freedom, location μ and scale
//! (λ+1)/λ² · Ψ. E-optimality (largest eigenvalue — the diagonal is the eigenvalues) and D-optimality
//! (geometric mean of the eigenvalues) summarise its spread in one number. Two spreads are in use, and
//! they are not proportional across voxels, so they rank voxels differently ([`Spread`]):
//!
//! - **the authors' `t_var`** = (λ+1)/λ² · Ψ, the Student-t *scale*, gated at λ > 2 — what the released
//!   code (`publish_map.py`) summarises and what the paper's figures show;
//! - **the Student-t covariance** = λ/(λ−2) · t_var = (λ+1)/(λ(λ−2)) · Ψ, which exists only for λ > 2.
//!
//! The ratio λ/(λ−2) is 3 at λ = 3 and 1.25 at λ = 10: the covariance ranks young voxels as more
//! uncertain. Where the paper's experiments are reproduced the default is the authors' ([`Spread::PAPER`]).
//! Sampling uncertainty is in [`crate::sampling`].

use crate::stats::VoxelStats;

/// Which spread of the predictive the optimality criteria summarise (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Spread {
    /// The authors' t_var = (λ+1)/λ² · Ψ (the Student-t scale), defined for λ > 2 as in their code.
    AuthorsTVar,
    /// The Student-t covariance (λ+1)/(λ(λ−2)) · Ψ, defined for λ > 2.
    StudentTCovariance,
}

impl Spread {
    /// The convention of the paper's experiments (the authors' released code).
    pub const PAPER: Self = Self::AuthorsTVar;

    /// Multiplier of Ψ for a voxel of confidence `lambda`; `None` for λ ≤ 2 (or NaN).
    #[inline]
    pub fn factor(self, lambda: f32) -> Option<f32> {
        if !(lambda > 2.0) {
            return None;
        }
        Some(match self {
            Self::AuthorsTVar => (lambda + 1.0) / (lambda * lambda),
            Self::StudentTCovariance => (lambda + 1.0) / (lambda * (lambda - 2.0)),
        })
    }

    /// Short name for tables.
    pub fn name(self) -> &'static str {
        match self {
            Self::AuthorsTVar => "authors' t_var",
            Self::StudentTCovariance => "Student-t covariance",
        }
    }
}

/// E- and D-optimality of one voxel in one [`Spread`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Optimality {
    /// E-optimality: the largest diagonal entry.
    pub e: f32,
    /// D-optimality: exp(mean log diagonal); 0 if a diagonal entry is 0, NaN if one is negative.
    pub d: f32,
}

impl<const D: usize> VoxelStats<D> {
    /// Multiplier (λ+1)/λ² turning Ψ into the Student-t scale; `None` for λ ≤ 0.
    pub fn scale_factor(&self) -> Option<f32> {
        (self.lambda > 0.0).then(|| (self.lambda + 1.0) / (self.lambda * self.lambda))
    }

    /// The authors' t_var = (λ+1)/λ² · Ψ, with their gate λ > 2.
    pub fn t_var(&self) -> Option<[f32; D]> {
        self.spread(Spread::AuthorsTVar)
    }

    /// The diagonal of `spread`; `None` for λ ≤ 2.
    pub fn spread(&self, spread: Spread) -> Option<[f32; D]> {
        let f = spread.factor(self.lambda)?;
        Some(self.psi.map(|p| f * p))
    }

    /// E- and D-optimality of `spread` in one pass over Ψ; `None` for λ ≤ 2.
    ///
    /// D-optimality needs Σ log Ψ_d: instead of D logarithms it sums the exponent fields and multiplies
    /// the mantissas (each in [1, 2), renormalised every 16 products), then takes one log₂ — the same
    /// value to f32 rounding, ~10× faster (`benches/uncertainty.rs`).
    pub fn optimality(&self, spread: Spread) -> Option<Optimality> {
        let f = spread.factor(self.lambda)?;
        let (max, mean_log2) = max_and_mean_log2(&self.psi);
        Some(Optimality {
            e: f * max,
            d: f * exp2(mean_log2),
        })
    }

    /// E-optimality of the Student-t covariance (the largest predictive variance); `None` for λ ≤ 2.
    /// The authors' convention is `optimality(Spread::AuthorsTVar)`.
    pub fn e_optimality(&self) -> Option<f32> {
        self.optimality(Spread::StudentTCovariance).map(|o| o.e)
    }

    /// D-optimality of the Student-t covariance (geometric mean of the predictive variances); `None` for
    /// λ ≤ 2. The authors' convention is `optimality(Spread::AuthorsTVar)`.
    pub fn d_optimality(&self) -> Option<f32> {
        self.optimality(Spread::StudentTCovariance).map(|o| o.d)
    }
}

/// (max x, mean log₂ x) over `xs`. Positive normal values take the fast path; anything else (0,
/// subnormal, negative, non-finite) the exact one, with log₂ 0 = −∞ and log₂ of a negative = NaN, as
/// numpy's `log` gives in the authors' code.
fn max_and_mean_log2<const D: usize>(xs: &[f32; D]) -> (f32, f32) {
    const L: usize = 8;
    // Up to 16 mantissas (each in [1, 2)) per lane are multiplied before the lane is renormalised.
    const BLOCK: usize = 16 * L;
    if D == 0 {
        return (0.0, 0.0);
    }
    let mut max = [0.0f32; L];
    let mut exps = [0i32; L];
    let mut bad = [0u32; L];
    let mut sum = 0.0f32;
    let whole = D - D % L;
    for block in xs[..whole].chunks(BLOCK) {
        let mut prod = [1.0f32; L];
        for c in block.chunks_exact(L) {
            for l in 0..L {
                let x = c[l];
                let bits = x.to_bits();
                // Positive, normal and finite: 0x0080_0000 ≤ bits ≤ 0x7F7F_FFFF.
                bad[l] |= u32::from(bits.wrapping_sub(0x0080_0000) >= 0x7F00_0000);
                exps[l] += (bits >> 23) as i32 - 127;
                prod[l] *= f32::from_bits((bits & 0x007F_FFFF) | 0x3F80_0000);
                max[l] = if x > max[l] { x } else { max[l] };
            }
        }
        let mut p = 1.0f32;
        for l in 0..L {
            let bits = prod[l].to_bits();
            exps[l] += (bits >> 23) as i32 - 127;
            p *= f32::from_bits((bits & 0x007F_FFFF) | 0x3F80_0000); // 8 factors < 2: p < 256
        }
        sum += crate::f32math::log2(p);
    }
    let mut m = max.iter().fold(0.0f32, |a, &b| if b > a { b } else { a });
    sum += exps.iter().sum::<i32>() as f32;
    let mut any_bad = bad.iter().any(|&b| b != 0);
    for &x in &xs[whole..] {
        m = if x > m { x } else { m };
        any_bad |= !(x > 0.0 && x.is_finite());
        sum += crate::f32math::log2(x);
    }
    if any_bad {
        // Exact path: 0 gives −∞ (D-optimality 0), a negative NaN, like numpy.
        let mut m = f32::NEG_INFINITY;
        let mut sum = 0.0f32;
        for &x in xs {
            m = if x.is_nan() || m.is_nan() {
                f32::NAN
            } else {
                m.max(x)
            };
            sum += if x < 0.0 || x.is_nan() {
                f32::NAN
            } else if x == 0.0 {
                f32::NEG_INFINITY
            } else {
                libm::log2f(x)
            };
        }
        return (m, sum / D as f32);
    }
    (m, sum / D as f32)
}

/// 2^x in f32 (the D-optimality's one power): the polynomial of [`crate::sampling`], with the range kept
/// inside f32's normal exponents (−∞ and anything below 2⁻¹²⁶ give 0, NaN stays NaN).
fn exp2(x: f32) -> f32 {
    if x.is_nan() {
        return f32::NAN;
    }
    if !(x > -126.0) {
        return 0.0;
    }
    crate::f32math::exp2(x.min(127.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn voxel(lambda: f32) -> VoxelStats<3> {
        VoxelStats {
            lambda,
            mean: [1.0, 0.0, 0.0],
            psi: [4.0, 1.0, 0.25],
        }
    }

    #[test]
    fn both_conventions_follow_their_formulas() {
        let v = voxel(4.0);
        let f = v.scale_factor().unwrap();
        let scale = v.psi.map(|p| f * p);
        assert!((scale[0] - 5.0 / 16.0 * 4.0).abs() < 1e-6);
        assert_eq!(v.t_var().unwrap(), scale, "t_var is the Student-t scale");
        let var = v.spread(Spread::StudentTCovariance).unwrap();
        assert!((var[0] - 2.0 * 5.0 / 16.0 * 4.0).abs() < 1e-6);
        let cov = v.optimality(Spread::StudentTCovariance).unwrap();
        assert!((cov.e - var[0]).abs() < 1e-6);
        assert!((cov.d - libm::cbrtf(var[0] * var[1] * var[2])).abs() < 1e-5);
        let tv = v.optimality(Spread::AuthorsTVar).unwrap();
        assert!((tv.e - scale[0]).abs() < 1e-6);
        assert!((tv.d - libm::cbrtf(scale[0] * scale[1] * scale[2])).abs() < 1e-5);
        // The two differ by λ/(λ−2) = 2 here, 3 at λ = 3, 1.25 at λ = 10: not a common factor.
        assert!((cov.e / tv.e - 2.0).abs() < 1e-5);
        let r3 = voxel(3.0).optimality(Spread::StudentTCovariance).unwrap().e
            / voxel(3.0).optimality(Spread::AuthorsTVar).unwrap().e;
        assert!((r3 - 3.0).abs() < 1e-5);
        for s in [Spread::AuthorsTVar, Spread::StudentTCovariance] {
            assert!(voxel(2.0).optimality(s).is_none(), "λ ≤ 2 is gated");
            assert!(voxel(f32::NAN).optimality(s).is_none());
        }
        assert!(voxel(2.0).t_var().is_none());
        assert!(voxel(0.0).scale_factor().is_none());
        assert_eq!(v.e_optimality(), Some(cov.e));
        assert_eq!(v.d_optimality(), Some(cov.d));
    }

    /// The one-log D-optimality equals the mean of D logarithms in f64, over Ψ spanning 2⁻⁶⁰…2⁶⁰.
    #[test]
    fn fast_d_optimality_equals_the_f64_formula() {
        let mut s = 0x9E37_79B9u32;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            s
        };
        let mut worst = 0.0f64;
        for trial in 0..2000 {
            let spread = [1.0f32, 8.0, 60.0][trial % 3];
            let psi: [f32; 64] = core::array::from_fn(|_| {
                libm::exp2f(spread * ((next() as f32 / u32::MAX as f32) - 0.5) * 2.0)
            });
            let v = VoxelStats::<64> {
                lambda: 2.5 + (next() % 1000) as f32,
                mean: [0.0; 64],
                psi,
            };
            for sp in [Spread::AuthorsTVar, Spread::StudentTCovariance] {
                let o = v.optimality(sp).unwrap();
                let l = v.lambda as f64;
                let f = match sp {
                    Spread::AuthorsTVar => (l + 1.0) / (l * l),
                    Spread::StudentTCovariance => (l + 1.0) / (l * (l - 2.0)),
                };
                let tv: [f64; 64] = psi.map(|p| f * p as f64);
                let d = libm::exp(tv.iter().map(|x| libm::log(*x)).sum::<f64>() / 64.0);
                let e = tv.iter().cloned().fold(0.0, f64::max);
                worst = worst.max((o.d as f64 - d).abs() / d);
                assert!((o.e as f64 - e).abs() <= 1e-6 * e);
            }
        }
        assert!(worst < 2e-5, "worst D-optimality relative error {worst:e}");
        // Zero and negative entries: numpy's log gives −∞ and NaN.
        let mut v = voxel(5.0);
        v.psi[1] = 0.0;
        assert_eq!(v.optimality(Spread::AuthorsTVar).unwrap().d, 0.0);
        v.psi[1] = -1.0;
        assert!(v.optimality(Spread::AuthorsTVar).unwrap().d.is_nan());
    }
}
