//! Per-dimension weights of the mean codes: each dimension's code step follows its spread.
//!
//! Why: a voxel's mean is coded as [`super::MU_BITS`]-bit codes on one per-voxel scale, set by its largest
//! component. Features reach the robot PCA-reduced, and the spread of a PCA component falls steeply with its
//! index (on the demo's tile the first 5 of 64 hold ≈ 88 % of ‖m‖²), so the step is set by the leading
//! components and the small ones are coded with a few levels around zero: with one scale, 87 % of the map's
//! μ error lay outside the 8 leading components. Weighing dimension i by 2^−sᵢ (coding mᵢ·2^sᵢ on the
//! voxel's scale) gives it a step 2^sᵢ times finer, so every dimension uses its codes' range.
//!
//! Powers of two because multiplying by one is exact (the decoded mean is the code times the scale times
//! 2^−sᵢ, nothing else rounds) and because fixed-point code applies one as a shift. Only the *relative*
//! weights matter (the scale is per voxel), so the leading dimension has shift 0.
//!
//! The shifts are given as breakpoints, because PCA components come sorted by spread: dimension i has shift
//! sᵢ = the number of used entries of `from` that are ≤ i. Sixteen bytes whatever D is, `Copy` and `const`.
//! [`MeanWeights::ONES`] (all weights 1) is today's codes, bit for bit.
//!
//! A weighed map also codes on a finer grid ([`super::QuantVoxel::reencode_fine`]): once the small
//! components use their range, the slack the scale keeps (kept until the largest |mᵢ| falls to ¼ of the top
//! code, 25 % headroom) is the largest error left. On the demo's tile (the robot's map against the f32
//! reference of all points, RMS ‖Δμ‖/‖μ‖): one step 0.0664, weights 0.0296, weights and the finer grid
//! 0.0165. The unweighed map keeps the coarser grid, so its codes (and the boards' streams) stay as they
//! were.

use crate::config::ConfigError;

/// Most shift steps (a dimension's weight is at least 2^−`MAX_MEAN_SHIFT`).
pub const MAX_MEAN_SHIFT: usize = 8;

/// Per-dimension weights 2^−sᵢ of a local map's mean codes (see the module doc).
///
/// ```
/// use latentbki::quant::MeanWeights;
///
/// // Dimension 0 at weight 1, dimension 1 at 1/2, 2..=4 at 1/4, the rest at 1/8.
/// let w = MeanWeights::new([1, 2, 5, 0, 0, 0, 0, 0]);
/// assert_eq!((0..7).map(|i| w.shift(i)).collect::<Vec<_>>(), [0, 1, 2, 2, 2, 3, 3]);
/// assert!(w.validate(64).is_ok() && w.validate(4).is_err());
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MeanWeights {
    /// Breakpoints: entry j (if non-zero) is the first dimension whose shift is at least j + 1. Used
    /// entries are non-decreasing and below D; unused ones are 0 and only follow used ones.
    pub from: [u16; MAX_MEAN_SHIFT],
}

impl MeanWeights {
    /// Every weight 1: one step for every dimension (today's codes).
    pub const ONES: Self = Self {
        from: [0; MAX_MEAN_SHIFT],
    };

    /// Weights from breakpoints (checked by [`Self::validate`] when a map takes them).
    pub const fn new(from: [u16; MAX_MEAN_SHIFT]) -> Self {
        Self { from }
    }

    /// Whether every weight is 1.
    pub const fn is_ones(&self) -> bool {
        self.from[0] == 0
    }

    /// Whether these weights are valid for D-dimensional means: used breakpoints non-decreasing, each in
    /// 1..D, no used entry after an unused one.
    pub fn validate(&self, dim: usize) -> Result<(), ConfigError> {
        let mut prev = 1usize;
        let mut ended = false;
        for &f in &self.from {
            let f = usize::from(f);
            if f == 0 {
                ended = true;
            } else if ended || f < prev || f >= dim {
                return Err(ConfigError::MeanWeights);
            } else {
                prev = f;
            }
        }
        Ok(())
    }

    /// The shift sᵢ of dimension i (its weight is 2^−sᵢ).
    pub fn shift(&self, i: usize) -> u32 {
        self.from
            .iter()
            .filter(|&&f| f != 0 && usize::from(f) <= i)
            .count() as u32
    }

    /// Weights from each dimension's spread (e.g. the standard deviation of a PCA component over the
    /// features): sᵢ = round(log₂(spread₀ / spreadᵢ)), made non-decreasing and at most [`MAX_MEAN_SHIFT`];
    /// spreads that are not finite and > 0 keep the shift so far. Every dimension's step then follows its
    /// spread to within a factor √2.
    ///
    /// Measured on the demo's tile (the robot's map against the f32 reference of all points, RMS
    /// ‖Δμ‖/‖μ‖, with the finer grid a weighed map codes on): these weights 0.0165; one octave less
    /// everywhere 0.0177 (on the coarse grid it was the better rule, 0.0261 against 0.0296: there the
    /// largest of ≈ 60 small weighed components, 2–3 of their spread, set the scale more often).
    pub fn from_spreads(spreads: &[f32]) -> Self {
        let mut w = Self::ONES;
        let Some(&lead) = spreads.first() else {
            return w;
        };
        let mut shift = 0usize;
        for (i, &s) in spreads.iter().enumerate().skip(1) {
            let want = if s > 0.0 && s.is_finite() && lead > 0.0 && lead.is_finite() {
                libm::roundf(crate::f32math::log2(lead / s)).clamp(0.0, MAX_MEAN_SHIFT as f32)
                    as usize
            } else {
                shift
            };
            while shift < want {
                if let (Some(f), Ok(i)) = (w.from.get_mut(shift), u16::try_from(i)) {
                    *f = i;
                }
                shift += 1;
            }
        }
        w
    }

    /// Weigh a mean for coding (`mᵢ · 2^sᵢ`, `up`) or back (`mᵢ · 2^−sᵢ`). Exact: powers of two.
    pub fn apply(&self, mean: &mut [f32], up: bool) {
        let mut start = 0usize;
        for shift in 0..=MAX_MEAN_SHIFT as u32 {
            let end = match self.from.get(shift as usize) {
                Some(&f) if f != 0 => usize::from(f),
                _ => mean.len(),
            };
            // 2^±shift as its bit pattern (exponent 127 ± shift).
            let k = f32::from_bits(if up { 127 + shift } else { 127 - shift } << 23);
            for m in mean.get_mut(start..end).unwrap_or_default() {
                *m *= k;
            }
            if end >= mean.len() {
                break;
            }
            start = end;
        }
    }
}

#[cfg(feature = "mean-weights")]
impl MeanWeights {
    /// Re-encode `codes` in place for a weighed mean: [`super::QuantVoxel::reencode_fine`] (the finer
    /// grid) unless every weight is 1, where the codes stay those of [`super::QuantVoxel::reencode`], bit
    /// for bit.
    #[inline]
    pub(crate) fn reencode<const D: usize, const P: usize>(
        &self,
        codes: &mut super::QuantVoxel<D, P>,
        stats: &crate::obs::ObsStats<D>,
        dither: &mut super::Dither,
    ) {
        if self.is_ones() {
            codes.reencode_here(stats, dither)
        } else {
            codes.reencode_fine_here(stats, dither)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn breakpoints_give_shifts_and_are_checked() {
        let w = MeanWeights::new([2, 4, 4, 0, 0, 0, 0, 0]);
        let shifts: [u32; 6] = core::array::from_fn(|i| w.shift(i));
        assert_eq!(shifts, [0, 0, 1, 1, 3, 3]);
        assert!(w.validate(5).is_ok());
        assert_eq!(w.validate(4), Err(ConfigError::MeanWeights)); // a breakpoint at D
        for bad in [[3, 2, 0, 0, 0, 0, 0, 0], [2, 0, 3, 0, 0, 0, 0, 0]] {
            assert_eq!(
                MeanWeights::new(bad).validate(64),
                Err(ConfigError::MeanWeights)
            );
        }
        assert!(MeanWeights::ONES.is_ones() && MeanWeights::ONES.validate(1).is_ok());
        assert!(!w.is_ones());
    }

    #[test]
    fn weighing_is_exact_and_undone() {
        let w = MeanWeights::new([1, 3, 3, 5, 0, 0, 0, 0]);
        let mean: [f32; 6] = [0.3, -0.7, 1.1e-3, 5.5, -2.0e-5, 0.125];
        let mut m = mean;
        w.apply(&mut m, true);
        for (i, (a, b)) in m.iter().zip(&mean).enumerate() {
            assert_eq!(*a, b * (1u32 << w.shift(i)) as f32, "dimension {i}");
        }
        w.apply(&mut m, false);
        assert_eq!(m, mean);
    }

    #[test]
    fn weights_follow_the_spreads() {
        // The demo's PCA spreads: ratios 1, 1.5, 3.3, 3.9, 6, 8.5, 8.5: log₂ 0, 0.6, 1.7, 2.0, 2.6, 3.1, 3.1.
        let s = [0.52, 0.34, 0.157, 0.134, 0.087, 0.061, 0.061];
        let w = MeanWeights::from_spreads(&s);
        let shifts: [u32; 7] = core::array::from_fn(|i| w.shift(i));
        assert_eq!(shifts, [0, 1, 2, 2, 3, 3, 3]);
        assert!(w.validate(s.len()).is_ok());
        // Equal spreads, or none: all ones. A bad spread keeps the shift so far.
        assert!(MeanWeights::from_spreads(&[1.0; 8]).is_ones());
        assert!(MeanWeights::from_spreads(&[]).is_ones());
        let w = MeanWeights::from_spreads(&[1.0, 0.2, f32::NAN, 0.0, 0.01]);
        let shifts: [u32; 5] = core::array::from_fn(|i| w.shift(i));
        assert_eq!(shifts, [0, 2, 2, 2, 7]);
        assert!(w.validate(5).is_ok());
    }
}
