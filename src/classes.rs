//! A closed-set segmenter's class scores as the map's features, so the base station decodes the robot's
//! classes — and answers queries in other words — without a vision-language network on the robot.
//!
//! A small robot often runs a segmenter that knows a few classes ("floor", "wall", "sofa") rather than a
//! vision-language network. Each class then gets a *prototype*: its text embedding compressed into the
//! feature space the base station decodes with, as int8 codes (`host-sim feature-space --classes … --out
//! DIR` writes them, with the feature space, as Rust constants). A point's feature is the mix of the
//! prototypes weighted by its class scores; the map averages those mixes per voxel, and the base station's
//! cosine decoding reads back the class — or how well any other phrase fits ("something to sit on" finds
//! the sofa), since the prototypes are real text embeddings.
//!
//! Integer only (one division per point, then `D` multiply-adds per class with a non-zero score; within
//! 0.51 of a code of the exact weighted mean), so an
//! MCU without an FPU runs no soft-float here.
//!
//! **The int8 code convention.** A code `c` stands for the feature value `scale · c`, the same `scale` for
//! every dimension and every point of a session (`Setup::with_int8_features(scale)`, sent in the session
//! header); codes are in −127..=127 (the map refuses −128). A class's prototype is
//! `round(W (e − m) / scale)`: `e` the class's text embedding, `m` and `W` the feature space's mean and
//! components (the `.npz` the base station decodes with), `scale` = the largest |component| of all
//! prototypes / 127, so the prototypes use the whole int8 range.

/// The per-class int8 prototypes of a feature space, as `host-sim feature-space` writes them.
///
/// ```
/// use latentbki::classes::ClassPrototypes;
///
/// // Three classes in a 4-d feature space (a real one is 64-d): int8 codes, code c = 0.01 · c.
/// const CLASSES: ClassPrototypes<4, 3> = ClassPrototypes::new(
///     0x1234_5678,
///     0.01,
///     [[100, 0, 0, 20], [0, 100, 0, -20], [0, 0, 127, 0]],
/// );
/// let mut feature = [0i8; 4];
/// // A confident "class 1" point gets class 1's prototype exactly…
/// CLASSES.mix(&[0, 255, 0], &mut feature).unwrap();
/// assert_eq!(feature, [0, 100, 0, -20]);
/// // …an uncertain one the score-weighted mix (scores in any unit: only their ratios count).
/// CLASSES.mix(&[3, 1, 0], &mut feature).unwrap();
/// assert_eq!(feature, [75, 25, 0, 10]);
/// // No score at all: no feature (skip the point).
/// assert!(CLASSES.mix(&[0, 0, 0], &mut feature).is_err());
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClassPrototypes<const D: usize, const K: usize> {
    /// Id of the feature space the prototypes live in ([`crate::Setup::with_feature_space`]; the
    /// base station checks its PCA against it).
    pub feature_space: u32,
    /// A code c stands for `scale` · c ([`crate::Setup::with_int8_features`]).
    pub scale: f32,
    /// Each class's feature as int8 codes, in the order of the segmenter's scores (never −128).
    pub codes: [[i8; D]; K],
}

/// Why [`ClassPrototypes::mix`] gave no feature.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum MixError {
    /// Every class score is zero: the segmenter saw none of its classes (skip the point).
    NoScore,
}

impl core::fmt::Display for MixError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::NoScore => f.write_str("every class score is zero"),
        }
    }
}

impl core::error::Error for MixError {}

impl<const D: usize, const K: usize> ClassPrototypes<D, K> {
    /// The prototypes of a feature space. Refused at compile time (in a `const`): no class, a code of
    /// −128, or a scale that is not finite and > 0.
    pub const fn new(feature_space: u32, scale: f32, codes: [[i8; D]; K]) -> Self {
        assert!(K > 0, "no class");
        assert!(
            scale.is_finite() && scale > 0.0,
            "scale must be finite and > 0"
        );
        let mut k = 0;
        while k < K {
            let mut d = 0;
            while d < D {
                assert!(
                    codes[k][d] != i8::MIN,
                    "a prototype holds the refused code -128"
                );
                d += 1;
            }
            k += 1;
        }
        Self {
            feature_space,
            scale,
            codes,
        }
    }

    /// Class `class`'s feature (an argmax-only segmenter's point), or `None` past the last class.
    pub fn class(&self, class: usize) -> Option<&[i8; D]> {
        self.codes.get(class)
    }

    /// The feature of a point whose class scores are `scores` (one per class, any unit: probabilities
    /// × 255, an NPU's uint8 softmax, counts; only their ratios count): the prototypes mixed by the
    /// scores, rounded to int8 codes. A point with a single non-zero score gets that class's prototype
    /// exactly. Integer only.
    pub fn mix(&self, scores: &[u8; K], out: &mut [i8; D]) -> Result<(), MixError> {
        let total: u32 = scores.iter().map(|&s| u32::from(s)).sum();
        if total == 0 {
            return Err(MixError::NoScore);
        }
        // Weights in 1/32768ths: w = floor(2¹⁵ s / total) through one reciprocal (s ≤ total, so s · r ≤ 2²⁴
        // never overflows); the rounding remainder goes to the best class, so the weights sum to 2¹⁵
        // exactly and a lone class's prototype comes out unchanged.
        const ONE: u32 = 1 << 15;
        let r = (1u32 << 24) / total;
        let mut weights = [0u16; K];
        let (mut sum, mut best) = (0u32, 0);
        for (k, (w, &s)) in weights.iter_mut().zip(scores).enumerate() {
            let v = (u32::from(s) * r) >> 9;
            *w = v as u16; // ≤ 2¹⁵
            sum += v;
            if s > scores[best] {
                best = k;
            }
        }
        // sum ≤ 2¹⁵: each floor is at most the exact share.
        weights[best] += ONE.saturating_sub(sum) as u16;
        if u32::from(weights[best]) == ONE {
            *out = self.codes[best];
            return Ok(());
        }
        // Σ w c over the classes: |Σ| ≤ 2¹⁵ · 127 fits an i32.
        let mut acc = [0i32; D];
        for (proto, &w) in self.codes.iter().zip(&weights) {
            if w == 0 {
                continue;
            }
            let w = i32::from(w);
            for (a, &c) in acc.iter_mut().zip(proto) {
                *a += w * i32::from(c);
            }
        }
        for (o, a) in out.iter_mut().zip(acc) {
            // Round half up: a convex mix of codes in −127..=127 stays there.
            *o = ((a + (1 << 14)) >> 15) as i8;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const P: ClassPrototypes<3, 3> =
        ClassPrototypes::new(7, 0.5, [[127, -127, 0], [-127, 127, 5], [0, 0, -127]]);

    #[test]
    fn a_lone_class_gets_its_prototype_whatever_its_score() {
        let mut out = [0; 3];
        for s in 1..=255u8 {
            for k in 0..3 {
                let mut scores = [0u8; 3];
                scores[k] = s;
                P.mix(&scores, &mut out).unwrap();
                assert_eq!(&out, P.class(k).unwrap());
            }
        }
    }

    #[test]
    fn a_mix_is_the_weighted_mean_rounded() {
        let mut out = [0; 3];
        for a in (0..=255u8).step_by(7) {
            for b in (0..=255u8).step_by(11) {
                for c in (0..=255u8).step_by(13) {
                    let scores = [a, b, c];
                    let total = f64::from(a) + f64::from(b) + f64::from(c);
                    if total == 0.0 {
                        assert_eq!(P.mix(&scores, &mut out), Err(MixError::NoScore));
                        continue;
                    }
                    P.mix(&scores, &mut out).unwrap();
                    for d in 0..3 {
                        let exact: f64 = (0..3)
                            .map(|k| f64::from(scores[k]) * f64::from(P.codes[k][d]))
                            .sum::<f64>()
                            / total;
                        assert!(
                            (f64::from(out[d]) - exact).abs() <= 0.51,
                            "{scores:?} d={d}: {} vs {exact}",
                            out[d]
                        );
                        assert!(out[d] != i8::MIN);
                    }
                }
            }
        }
    }
}
