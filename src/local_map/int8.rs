//! int8 features: a scale declared once, codes checked four at a time, exact integer sums per hot voxel
//! (no float operation per point; cooling by the target's [`Cooling`]: fixed point without an FPU).

use super::LocalMap;
use crate::batch::{locate_key, Rejection};
use crate::config::ConfigError;
use crate::forget::MapClock;
use crate::key::VoxelKey;
use crate::obs::code_in_range;
use crate::quant::{Cooling, Int8Fix};
use crate::sink::EvictionSink;
use nalgebra::Isometry3;

impl<const D: usize, const CAP: usize, const P: usize, const H: usize, C: MapClock>
    LocalMap<D, CAP, P, H, C>
{
    /// Declare the scale of int8 features: a code c stands for the feature value y = `scale` · c. Points
    /// with int8 features are refused (counted as [`Rejection::FeatureScale`]) until a valid scale is set,
    /// and after an invalid one (NaN, infinite, ≤ 0, or so large that 127·√D·scale exceeds
    /// [`crate::batch::FEATURE_LIMIT`]), which also returns an error. Voxels being observed keep what they
    /// took with the previous scale. [`Self::configure`] clears it.
    pub fn set_int8_scale(&mut self, scale: f32) -> Result<(), ConfigError> {
        let scale_ok = scale > 0.0
            && scale * f32::from(crate::obs::CODE_MAX) * libm::sqrtf(D as f32)
                <= crate::batch::FEATURE_LIMIT;
        // Sums taken with the previous scale become f32 statistics first.
        let old = self.int8_scale;
        for e in self.hot.iter_mut().take(self.hot_len) {
            e.acc.make_float(old);
        }
        self.int8_scale = if scale_ok { scale } else { 0.0 };
        self.int8_fix = if scale_ok && Cooling::Fixed.is_built() {
            Int8Fix::new(scale)
        } else {
            Int8Fix::NONE
        };
        if scale_ok {
            Ok(())
        } else {
            Err(ConfigError::Int8Scale)
        }
    }

    /// Cool int8 sums by `cooling` from now on (default [`Cooling::NATIVE`]; [`Self::configure`] keeps it).
    /// A bare-metal build links only its native method and refuses the other ([`ConfigError::Cooling`]);
    /// a hosted one takes either, so a host twin computes exactly what a given board does.
    pub fn set_cooling(&mut self, cooling: Cooling) -> Result<(), ConfigError> {
        if !cooling.is_built() {
            return Err(ConfigError::Cooling);
        }
        if cooling == Cooling::Fixed && self.mean_weights.has_shifts() {
            return Err(ConfigError::MeanWeightsFixedCooling);
        }
        #[cfg(not(target_os = "none"))]
        {
            self.cooling = cooling;
        }
        Ok(())
    }

    /// How int8 sums cool: a constant on bare metal, so the other method is not linked.
    #[inline]
    pub fn cooling(&self) -> Cooling {
        #[cfg(not(target_os = "none"))]
        return self.cooling;
        #[cfg(target_os = "none")]
        return Cooling::NATIVE;
    }

    /// The int8 feature scale (0 when none is set).
    pub fn int8_scale(&self) -> f32 {
        self.int8_scale
    }

    /// Add one map-frame point with an int8 feature (y = [`Self::int8_scale`] · code): `Ok` means its voxel
    /// took it. The voxel keeps exact integer sums of the codes while it is observed (two integer additions
    /// and a multiply per dimension, no float); refusals are counted as for [`Self::add_point`], plus
    /// [`Rejection::CodeOutOfRange`] (a code of −128) and [`Rejection::FeatureScale`] (no valid scale).
    pub fn add_point_i8<S: EvictionSink<D>>(
        &mut self,
        position: [f32; 3],
        codes: &[i8; D],
        sink: &mut S,
    ) -> Result<(), Rejection> {
        self.counted(|m| m.take_point_i8(position, codes, sink))
    }

    /// [`Self::add_points`] for int8 features.
    pub fn add_points_i8<S: EvictionSink<D>>(
        &mut self,
        pose: &Isometry3<f32>,
        points: &[[f32; 3]],
        codes: &[[i8; D]],
        sink: &mut S,
    ) -> usize {
        self.add_paired(pose, points, codes, |m, p, c| m.add_point_i8(p, c, sink))
    }

    /// Add one point with an int8 feature whose voxel the caller found (e.g. an integer sensor point
    /// through [`crate::fixed_pose::FixedPose`]): as [`Self::add_point_i8`], without any float operation.
    pub fn add_point_i8_in<S: EvictionSink<D>>(
        &mut self,
        key: VoxelKey,
        codes: &[i8; D],
        sink: &mut S,
    ) -> Result<(), Rejection> {
        self.counted(|m| m.take_key_i8(key, codes, sink))
    }

    /// Count a point refused before it reached the map (e.g. a position no key can be found for).
    pub fn refuse(&mut self, r: Rejection) {
        self.rejections.count(r);
    }

    fn take_point_i8<S: EvictionSink<D>>(
        &mut self,
        position: [f32; 3],
        codes: &[i8; D],
        sink: &mut S,
    ) -> Result<(), Rejection> {
        let key = locate_key(&self.lut, position)?;
        self.take_key_i8(key, codes, sink)
    }

    fn take_key_i8<S: EvictionSink<D>>(
        &mut self,
        key: VoxelKey,
        codes: &[i8; D],
        sink: &mut S,
    ) -> Result<(), Rejection> {
        // A set scale is > 0 and anything else is stored as +0.0: a bit test, no float compare (which
        // is a library call on an MCU without an FPU).
        if self.int8_scale.to_bits() == 0 {
            return Err(Rejection::FeatureScale);
        }
        #[cfg(latentbki_dsp)]
        if let Some(taken) = self.add_codes_at_hand(key, codes) {
            return taken;
        }
        if !code_in_range(codes) {
            return Err(Rejection::CodeOutOfRange);
        }
        let h = self.hot_entry(key, sink, true)?;
        self.hot_to_now(h);
        if self.hot_is_full(h) {
            self.restart_hot(h);
        }
        let scale = self.int8_scale;
        let e = self.hot.get_mut(h).ok_or(Rejection::NoRoom)?;
        e.acc.add_codes(codes, scale);
        e.referenced = true;
        Ok(())
    }

    /// The common case on a Cortex-M4/M7: the point's voxel is the previous point's hot entry (or the
    /// hint's), up to date, holding int8 sums with room. The codes are checked as they are added
    /// ([`crate::obs::CodeSums::add_checked`]: the check rides on the additions' loads) and a refused
    /// point is taken out again, so nothing changes for it but the cache of the previous point's entry.
    /// `None`: the general path (checked first) takes the point.
    #[cfg(latentbki_dsp)]
    #[inline(always)]
    fn add_codes_at_hand(
        &mut self,
        key: VoxelKey,
        codes: &[i8; D],
    ) -> Option<Result<(), Rejection>> {
        let h = self.hot_at_hand(key)?;
        if !self.hot_is_now(h) {
            return None;
        }
        let e = self.hot.get_mut(h)?;
        let super::hot::Acc::Codes(c) = &mut e.acc else {
            return None;
        };
        // Full, or empty (never at hand in practice: a voxel's first point takes the general path): the
        // general path, which starts or restarts the sums.
        if c.is_full() || c.count == 0 {
            return None;
        }
        if !c.add_checked(codes) {
            return Some(Err(Rejection::CodeOutOfRange));
        }
        e.referenced = true;
        Some(Ok(()))
    }
}
