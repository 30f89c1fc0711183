//! One sensor frame being added to a [`Mapper`]: every point goes through the frame's pose, in float or
//! (for integer millimetres and int8 features) in fixed point.

use super::tap::{EvictionTap, NoTap, Tapped};
use super::Mapper;
use crate::batch::Rejection;
use crate::fixed_pose::FixedPose;
use crate::forget::{MapClock, Timeless};
use crate::key::to_map_frame;
use crate::local_map::LocalMap;
use nalgebra::Isometry3;

/// A sensor frame being added to a [`Mapper`]: every point goes through the frame's pose (and every
/// voxel it hands to the link through the tap `T`, if any).
///
/// ```
/// # use latentbki::{packed_len, EncoderSettings, MapConfig, Mapper, Setup};
/// # use static_cell::ConstStaticCell;
/// # type Robot = Mapper<16, 256, { packed_len(16) }, 1024, 256>;
/// # static MAPPER: ConstStaticCell<Robot> = ConstStaticCell::new(Robot::EMPTY);
/// # let mapper = MAPPER.take();
/// # mapper.configure(&Setup::new(MapConfig::DEFAULT, 1.0, EncoderSettings::new(1, 1))).unwrap();
/// // A scanning sensor: one pose per revolution, the beams as they arrive.
/// let mut frame = mapper.begin_frame(&latentbki::nalgebra::Isometry3::identity());
/// for beam in 0..8 {
///     frame.add_point([0.6, 0.05 * beam as f32, 0.0], &[0.5; 16]).unwrap();
/// }
/// drop(frame);
/// assert_eq!(mapper.map().rejections().total(), 0);
/// ```
pub struct SensorFrame<
    'm,
    const D: usize,
    const CAP: usize,
    const P: usize,
    const QB: usize,
    const N: usize,
    const H: usize,
    T = NoTap,
    C: MapClock = Timeless,
> {
    pub(super) mapper: &'m mut Mapper<D, CAP, P, QB, N, H, C>,
    pub(super) pose: Isometry3<f32>,
    /// The pose in fixed point, made at the first integer point (`Some(None)`: not representable).
    pub(super) fixed: Option<Option<FixedPose>>,
    pub(super) tap: T,
}

impl<
        const D: usize,
        const CAP: usize,
        const P: usize,
        const QB: usize,
        const N: usize,
        const H: usize,
        T: EvictionTap<D>,
        C: MapClock,
    > SensorFrame<'_, D, CAP, P, QB, N, H, T, C>
{
    /// Add sensor-frame points with their features (pairs; an unpaired tail is counted as
    /// [`Rejection::Unpaired`]). Returns how many the map took; the others are counted in
    /// [`LocalMap::rejections`].
    pub fn add_points(&mut self, points: &[[f32; 3]], features: &[[f32; D]]) -> usize {
        let m = &mut self.mapper;
        let mut sink = Tapped {
            sink: &mut m.encoder,
            tap: &mut self.tap,
        };
        m.map.add_points(&self.pose, points, features, &mut sink)
    }

    /// Add one sensor-frame point (for sensors that deliver a point at a time).
    pub fn add_point(&mut self, point: [f32; 3], feature: &[f32; D]) -> Result<(), Rejection> {
        let m = &mut self.mapper;
        let mut sink = Tapped {
            sink: &mut m.encoder,
            tap: &mut self.tap,
        };
        m.map
            .add_point(to_map_frame(&self.pose, point), feature, &mut sink)
    }

    /// [`Self::add_points`] for int8 features: each code c stands for the setup's
    /// [`Setup::int8_scale`](super::Setup::int8_scale) · c. The map keeps exact integer sums while a voxel is observed, so a
    /// microcontroller without an FPU adds a point without float arithmetic on the features.
    pub fn add_points_i8(&mut self, points: &[[f32; 3]], codes: &[[i8; D]]) -> usize {
        let m = &mut self.mapper;
        m.map.add_points_i8(
            &self.pose,
            points,
            codes,
            &mut Tapped {
                sink: &mut m.encoder,
                tap: &mut self.tap,
            },
        )
    }

    /// [`Self::add_point`] for an int8 feature (a beam at a time).
    pub fn add_point_i8(&mut self, point: [f32; 3], codes: &[i8; D]) -> Result<(), Rejection> {
        let m = &mut self.mapper;
        m.map.add_point_i8(
            to_map_frame(&self.pose, point),
            codes,
            &mut Tapped {
                sink: &mut m.encoder,
                tap: &mut self.tap,
            },
        )
    }

    /// [`Self::add_point_i8`] for a point in integer millimetres (what a ToF or a LiDAR reports): the
    /// frame's pose is turned into fixed point once ([`FixedPose`]), so the point reaches its voxel with
    /// 32-bit integer arithmetic only — no float operation on the whole per-point path, for an MCU without
    /// an FPU. Coordinates beyond ±[`crate::fixed_pose::MAX_POINT_MM`] are refused as
    /// [`Rejection::KeyOutOfRange`]; a pose fixed point cannot hold (non-finite, or beyond 2²² voxels
    /// from the origin) refuses every point as [`Rejection::NonFinitePosition`].
    pub fn add_point_mm_i8(
        &mut self,
        point_mm: [i32; 3],
        codes: &[i8; D],
    ) -> Result<(), Rejection> {
        let voxel = self.mapper.map.config().voxel_size();
        let pose = &self.pose;
        let fixed = *self
            .fixed
            .get_or_insert_with(|| FixedPose::new(pose, voxel));
        let m = &mut self.mapper;
        let Some(fixed) = fixed else {
            m.map.refuse(Rejection::NonFinitePosition);
            return Err(Rejection::NonFinitePosition);
        };
        let Some(key) = fixed.key_of(point_mm) else {
            m.map.refuse(Rejection::KeyOutOfRange);
            return Err(Rejection::KeyOutOfRange);
        };
        m.map.add_point_i8_in(
            key,
            codes,
            &mut Tapped {
                sink: &mut m.encoder,
                tap: &mut self.tap,
            },
        )
    }

    /// [`Self::add_point_mm_i8`] for a batch (pairs; an unpaired tail is counted as
    /// [`Rejection::Unpaired`]). Returns how many the map took.
    pub fn add_points_mm_i8(&mut self, points_mm: &[[i32; 3]], codes: &[[i8; D]]) -> usize {
        let mut taken = 0;
        for (p, c) in points_mm.iter().zip(codes) {
            if self.add_point_mm_i8(*p, c).is_ok() {
                taken += 1;
            }
        }
        for _ in 0..points_mm.len().abs_diff(codes.len()) {
            self.mapper.map.refuse(Rejection::Unpaired);
        }
        taken
    }

    /// The map, read-only (e.g. for a report between chunks).
    pub fn map(&self) -> &LocalMap<D, CAP, P, H, C> {
        &self.mapper.map
    }
}
