//! Per-dimension weights of the map's mean codes ([`crate::quant::MeanWeights`]): every dimension's code
//! step follows its spread. The codes hold the weighed mean (mᵢ · 2^sᵢ); the map weighs a mean before it
//! encodes it and weighs it back right after decoding, so nothing else sees the weights.
//!
//! Behind the `mean-weights` feature: without it the weights are a zero-sized "all ones" whose calls
//! compile to nothing (no flash on the boards, the same codes bit for bit), and a setup with other weights
//! is refused. With it, all-ones weights take the same path as before: the same codes bit for bit.
//!
//! The fixed-point cooling of int8 sums (`Cooling::Fixed`, thumbv6m and riscv32imac) is refused with
//! weights other than 1 ([`ConfigError::MeanWeightsFixedCooling`]): its integer merge decodes and
//! re-encodes the codes on one step, and honouring the weights there (a shift per dimension in each of its
//! passes) is flash those boards do not have; they have no FPU, so their f32 cooling is soft float. A map
//! with weights cools in f32. `MeanWeights::EQUAL` (all ones on the finer grid) is taken: its f32 merges
//! code on that grid, its integer ones on their own.

use super::LocalMap;
use crate::config::ConfigError;
use crate::forget::MapClock;
use crate::quant::MeanWeights;

/// The weights a map keeps.
#[cfg(feature = "mean-weights")]
pub(super) type Weights = MeanWeights;

/// Without the feature: all ones, nothing to do.
#[cfg(not(feature = "mean-weights"))]
#[derive(Clone, Copy, Debug)]
pub(super) struct Weights;

#[cfg(not(feature = "mean-weights"))]
impl Weights {
    pub(super) const ONES: Self = Self;
    #[inline(always)]
    pub(super) const fn has_shifts(&self) -> bool {
        false
    }
    #[inline(always)]
    pub(super) fn apply(&self, _mean: &mut [f32], _up: bool) {}
    #[inline(always)]
    pub(super) fn reencode<const D: usize, const P: usize>(
        &self,
        codes: &mut crate::quant::QuantVoxel<D, P>,
        stats: &crate::obs::ObsStats<D>,
        dither: &mut crate::quant::Dither,
    ) {
        codes.reencode_here(stats, dither)
    }
    #[inline(always)]
    pub(super) fn reencode_unscattered<const D: usize, const P: usize>(
        &self,
        codes: &mut crate::quant::QuantVoxel<D, P>,
        stats: &crate::obs::ObsStats<D>,
        dither: &mut crate::quant::Dither,
    ) {
        codes.reencode_unscattered_here::<false>(stats, dither)
    }
}

impl<const D: usize, const CAP: usize, const P: usize, const H: usize, C: MapClock>
    LocalMap<D, CAP, P, H, C>
{
    /// Weigh the mean codes of this map's voxels per dimension (after [`Self::configure`], before the
    /// first point: a map that holds voxels refuses other weights, since their codes are on its own).
    /// [`MeanWeights::ONES`] is always taken; others need the `mean-weights` feature, valid breakpoints for
    /// D and the f32 cooling ([`crate::quant::Cooling::Float`]).
    pub fn set_mean_weights(&mut self, weights: MeanWeights) -> Result<(), ConfigError> {
        if weights == self.mean_weights() {
            return Ok(());
        }
        if !self.is_empty() {
            return Err(ConfigError::MeanWeights);
        }
        if weights.is_ones() {
            self.mean_weights = Weights::ONES;
            return Ok(());
        }
        #[cfg(not(feature = "mean-weights"))]
        return Err(ConfigError::MeanWeights);
        #[cfg(feature = "mean-weights")]
        {
            weights.validate(D)?;
            if weights.has_shifts() && self.cooling() == crate::quant::Cooling::Fixed {
                return Err(ConfigError::MeanWeightsFixedCooling);
            }
            self.mean_weights = weights;
            Ok(())
        }
    }

    /// The weights of the mean codes ([`MeanWeights::ONES`] unless set).
    pub fn mean_weights(&self) -> MeanWeights {
        #[cfg(feature = "mean-weights")]
        return self.mean_weights;
        #[cfg(not(feature = "mean-weights"))]
        return MeanWeights::ONES;
    }
}
