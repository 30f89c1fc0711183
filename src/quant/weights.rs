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
//! 0.0165. The unweighed map ([`MeanWeights::ONES`], the default) keeps the coarser grid, so its codes stay
//! as they were.
//!
//! Features whose dimensions spread alike (not PCA-sorted: the firmware self-test's codebook vectors) get
//! [`MeanWeights::EQUAL`] from their spreads: every weight 1, on the finer grid. Every dimension already
//! uses its codes' range there, so the grid is all that is left to gain: on the self-test's nine scenarios
//! (`host-sim --example firmware_accuracy -- thumbv7em --twin`, base station with 8-bit packed summaries
//! against the f32 reference) 0.0236 → 0.0133, the scanning LiDAR's voxels (visited by one beam at a
//! time, so re-encoded once per few points) 0.0383 → 0.0188. Having no shifts, they are also taken by a
//! map that cools int8 sums in fixed point (whose integer merge stays on its own grid).

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
    /// Whether the codes use the finer grid ([`super::QuantVoxel::reencode_fine`]): true for weights from
    /// breakpoints or spreads, false only for [`Self::ONES`].
    fine: bool,
}

impl MeanWeights {
    /// Every weight 1 on the coarser grid: one step for every dimension (the unweighed map's codes, bit
    /// for bit; the default).
    pub const ONES: Self = Self {
        from: [0; MAX_MEAN_SHIFT],
        fine: false,
    };

    /// Every weight 1 on the finer grid: [`Self::from_spreads`] of spreads all alike (see the module doc).
    /// No shifts, so a map cooling int8 sums in fixed point takes them too.
    pub const EQUAL: Self = Self {
        from: [0; MAX_MEAN_SHIFT],
        fine: true,
    };

    /// Weights from breakpoints (checked by [`Self::validate`] when a map takes them); no breakpoints is
    /// [`Self::ONES`].
    pub const fn new(from: [u16; MAX_MEAN_SHIFT]) -> Self {
        Self {
            from,
            fine: from[0] != 0,
        }
    }

    /// Whether these are [`Self::ONES`]: every weight 1 on the coarser grid (a map with them codes as one
    /// without weights).
    pub const fn is_ones(&self) -> bool {
        self.from[0] == 0 && !self.fine
    }

    /// Whether some dimension has a weight other than 1 (a shift): what a map's fixed-point merge of int8
    /// sums cannot honour.
    pub const fn has_shifts(&self) -> bool {
        self.from[0] != 0
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
    /// spread to within a factor √2. The codes use the finer grid (spreads all alike give [`Self::EQUAL`]);
    /// without a finite lead spread > 0 the weights are [`Self::ONES`].
    ///
    /// Measured on the demo's tile (the robot's map against the f32 reference of all points, RMS
    /// ‖Δμ‖/‖μ‖, with the finer grid a weighed map codes on): these weights 0.0165; one octave less
    /// everywhere 0.0177 (on the coarse grid it was the better rule, 0.0261 against 0.0296: there the
    /// largest of ≈ 60 small weighed components, 2–3 of their spread, set the scale more often).
    pub fn from_spreads(spreads: &[f32]) -> Self {
        let mut w = Self::EQUAL;
        let Some(&lead) = spreads.first().filter(|&&s| s > 0.0 && s.is_finite()) else {
            return Self::ONES;
        };
        let mut shift = 0usize;
        for (i, &s) in spreads.iter().enumerate().skip(1) {
            let want = if s > 0.0 && s.is_finite() {
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

    /// Weigh a mean for coding (`mᵢ · 2^sᵢ`, `up`) or back (`mᵢ · 2^−sᵢ`). Exact: powers of two. Nothing
    /// to do without shifts.
    pub fn apply(&self, mean: &mut [f32], up: bool) {
        if !self.has_shifts() {
            return;
        }
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

    /// [`Self::reencode`] of statistics whose every scatter is 0 (a voxel of one point; see
    /// [`super::QuantVoxel::reencode_unscattered_here`]).
    #[inline]
    pub(crate) fn reencode_unscattered<const D: usize, const P: usize>(
        &self,
        codes: &mut super::QuantVoxel<D, P>,
        stats: &crate::obs::ObsStats<D>,
        dither: &mut super::Dither,
    ) {
        if self.is_ones() {
            codes.reencode_unscattered_here::<false>(stats, dither)
        } else {
            codes.reencode_unscattered_here::<true>(stats, dither)
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
        // Equal spreads: all ones on the finer grid; none (or no valid lead): the unweighed map's. A bad
        // spread keeps the shift so far.
        let equal = MeanWeights::from_spreads(&[1.0; 8]);
        assert_eq!(equal, MeanWeights::EQUAL);
        assert!(!equal.is_ones() && !equal.has_shifts() && equal.validate(8).is_ok());
        assert!(MeanWeights::from_spreads(&[]).is_ones());
        assert!(MeanWeights::from_spreads(&[0.0, 1.0]).is_ones());
        assert!(MeanWeights::new([0; MAX_MEAN_SHIFT]).is_ones());
        let w = MeanWeights::from_spreads(&[1.0, 0.2, f32::NAN, 0.0, 0.01]);
        let shifts: [u32; 5] = core::array::from_fn(|i| w.shift(i));
        assert_eq!(shifts, [0, 2, 2, 2, 7]);
        assert!(w.validate(5).is_ok());
    }
}
