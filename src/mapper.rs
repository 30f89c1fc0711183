//! The firmware's entry point: a local map and the frame encoder that streams what it evicts, as one value.
//!
//! A robot's loop is always the same — configure once, then per sensor frame: pose, points and features in,
//! a byte-budgeted send; at the end, everything out. [`Mapper`] owns the two pieces that loop needs
//! ([`LocalMap`] and [`FrameEncoder`], the encoder being the map's eviction sink) so that a firmware writes
//! that loop in a handful of lines and never wires the map to the link itself. It holds no pointer and
//! nothing on the heap; [`Mapper::EMPTY`] is all zero, so a `static` of it lives in `.bss`, and
//! [`Mapper::configure`] sets it up in place from a [`Setup`] that can itself be a `const`.
//!
//! Nothing on its path panics (the QEMU firmware's `panic-never` build proves it at link time) and nothing
//! is lost silently: refused points are counted by the map ([`LocalMap::rejections`]), voxels the link
//! cannot take yet stay in the map (back-pressure), and [`Mapper::drain`] sends every voxel before it
//! returns.
//!
//! With a back channel ([`crate::frame::Resend`]) the robot keeps what it sent until the base station
//! acknowledges it; [`Mapper::poll_acks`] reads acknowledgements without blocking. With live updates
//! ([`Mapper::tick_live`]) each tick also streams the held voxels that changed since they were last streamed, so
//! the base station's map follows the robot while it works. A program that needs every eviction's exact
//! statistics (an evaluation, a log) taps them ([`EvictionTap`]) instead of assembling a second robot.

use crate::batch::Rejection;
use crate::config::{ConfigError, MapConfig};
use crate::fixed_pose::FixedPose;
use crate::frame::{AckReader, EncoderSettings, FrameEncoder, TickError, TickReport};
use crate::key::to_map_frame;
use crate::local_map::{LocalMap, HOT_VOXELS};
use crate::sink::Evicted;
use crate::wire::{SessionConfig, SummaryCodec, WireError, NO_FEATURE_SPACE};
use nalgebra::Isometry3;

mod tap;
use tap::Tapped;
pub use tap::{EvictionTap, NoTap};

/// Everything a [`Mapper`] is configured with; `const`-constructible, so a firmware keeps it in a `static`.
///
/// ```
/// use latentbki::{EncoderSettings, MapConfig, Setup};
///
/// // Robot 3, session 12 (a boot counter); voxels within 2 m of the sensor stay on the device.
/// static SETUP: Setup = Setup::new(MapConfig::DEFAULT, 2.0, EncoderSettings::new(3, 12));
/// assert_eq!((SETUP.link.robot, SETUP.window_radius), (3, 2.0));
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Setup {
    /// Voxel size, kernel, prior.
    pub map: MapConfig,
    /// Radius of the window around the robot (m): voxels farther away are evicted and streamed.
    pub window_radius: f32,
    /// Robot id, session id, how often the session header and link statistics repeat.
    pub link: EncoderSettings,
    /// How summaries are quantized on the wire.
    pub codec: SummaryCodec,
    /// Id of the PCA the features were compressed with ([`crate::wire::feature_space_id`]), or
    /// [`NO_FEATURE_SPACE`].
    pub feature_space: u32,
    /// Scale of int8 features (a code c is the feature value `int8_scale` · c); 0 = the robot gives f32
    /// features only. Sent in the session header.
    pub int8_scale: f32,
}

impl Setup {
    /// A setup with the default summary codec and features that are not tied to a PCA.
    pub const fn new(map: MapConfig, window_radius: f32, link: EncoderSettings) -> Self {
        Self {
            map,
            window_radius,
            link,
            codec: SummaryCodec::DEFAULT,
            feature_space: NO_FEATURE_SPACE,
            int8_scale: 0.0,
        }
    }

    /// The same setup for a robot whose features are int8 codes: c stands for `scale` · c (e.g. an NPU's
    /// output quantization scale). f32 features stay accepted too.
    pub const fn with_int8_features(self, scale: f32) -> Self {
        Self {
            int8_scale: scale,
            ..self
        }
    }

    /// The session configuration a `dim`-dimensional map sends in its header.
    pub fn session(&self, dim: usize) -> SessionConfig {
        SessionConfig::new(&self.map, dim, self.codec, self.feature_space)
            .with_int8_scale(self.int8_scale)
    }
}

/// Why [`Mapper::configure`] refused a setup.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SetupError {
    /// The map refused its part (window radius, sub-voxel kernel, …).
    Map(ConfigError),
    /// The encoder refused its part (codec, or buffers too small for one summary).
    Link(WireError),
}

/// Why [`Mapper::drain`] stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DrainError<E> {
    /// The writer failed; what was not sent stays in the map or the encoder's queue.
    Write(E),
    /// A queued voxel could not be sent (the frame size `N` is too small for one summary, or no session),
    /// or, with a back channel, the re-send buffer is full of unacknowledged frames: read acknowledgements
    /// ([`Mapper::poll_acks`]) and drain again.
    Stuck,
}

impl<E> From<TickError<E>> for DrainError<E> {
    fn from(e: TickError<E>) -> Self {
        match e {
            TickError::Write(e, _) => Self::Write(e),
        }
    }
}

/// A local map of `CAP` voxels of dimension `D` streaming through a frame encoder with `QB` bytes of queue
/// and frames of at most `N` bytes. `P` is [`crate::quant::packed_len`]`(D)` (checked at compile time).
///
/// Large (≈ `CAP` × [`LocalMap::BYTES_PER_VOXEL`] + `QB` + 2 `N` bytes): place it in a `static`.
///
/// ```
/// use latentbki::nalgebra::Isometry3;
/// use latentbki::{packed_len, EncoderSettings, MapConfig, Mapper, Setup};
/// use static_cell::ConstStaticCell;
///
/// // D = 16 features, 256 voxels, a 1 KiB queue of evicted voxels, frames of at most 256 bytes.
/// type Robot = Mapper<16, 256, { packed_len(16) }, 1024, 256>;
/// static MAPPER: ConstStaticCell<Robot> = ConstStaticCell::new(Robot::EMPTY);
///
/// let mapper = MAPPER.take();
/// mapper.configure(&Setup::new(MapConfig::DEFAULT, 1.0, EncoderSettings::new(1, 1))).unwrap();
/// let taken = mapper.integrate(&Isometry3::identity(), &[[0.5, 0.0, 0.0]], &[[0.25; 16]]);
/// assert_eq!((taken, mapper.map().len()), (1, 1));
///
/// let mut link = [0u8; 2048];
/// let mut uart: &mut [u8] = &mut link; // any embedded_io::Write
/// mapper.drain(&mut uart).unwrap(); // the session header, the voxel, link statistics
/// assert_eq!(mapper.map().len(), 0);
/// ```
pub struct Mapper<
    const D: usize,
    const CAP: usize,
    const P: usize,
    const QB: usize,
    const N: usize,
    const H: usize = HOT_VOXELS,
> {
    map: LocalMap<D, CAP, P, H>,
    encoder: FrameEncoder<D, QB, N>,
    acks: AckReader,
    /// Where the next live round starts (a slot of the map).
    live_hand: usize,
}

impl<
        const D: usize,
        const CAP: usize,
        const P: usize,
        const QB: usize,
        const N: usize,
        const H: usize,
    > Mapper<D, CAP, P, QB, N, H>
{
    /// The mapper's RAM (its `static`): the map's [`LocalMap::RAM_BYTES`] (voxels, hot tier, kernel table)
    /// plus the encoder (queue `QB`, two frame buffers of `N`, state), the acknowledgement reader and the
    /// live-update hand, rounded to the alignment. Equals `size_of::<Self>()` (tested), so a firmware
    /// checks its budget at compile time: `const _: () = assert!(Robot::RAM_BYTES <= 150 * 1024);`.
    pub const RAM_BYTES: usize = (LocalMap::<D, CAP, P, H>::RAM_BYTES
        + core::mem::size_of::<FrameEncoder<D, QB, N>>()
        + core::mem::size_of::<AckReader>()
        + core::mem::size_of::<usize>())
    .next_multiple_of(core::mem::align_of::<Self>());

    /// Unconfigured and all zero (a `static` of it lives in `.bss`): it takes no point and sends nothing
    /// until [`Self::configure`].
    #[allow(clippy::declare_interior_mutable_const)]
    pub const EMPTY: Self = Self {
        map: LocalMap::EMPTY,
        encoder: FrameEncoder::EMPTY,
        acks: AckReader::new(),
        live_hand: 0,
    };

    /// (Re)configure in place: clears the map and starts a new session on the link (the next tick begins
    /// with its header). On error nothing is sent until a later `configure` succeeds.
    pub fn configure(&mut self, setup: &Setup) -> Result<(), SetupError> {
        self.encoder.close();
        self.acks.reset();
        self.live_hand = 0;
        self.map
            .configure(setup.map, setup.window_radius)
            .map_err(SetupError::Map)?;
        if setup.int8_scale != 0.0 {
            self.map
                .set_int8_scale(setup.int8_scale)
                .map_err(SetupError::Map)?;
        }
        self.encoder
            .configure(setup.session(D), setup.link)
            .map_err(SetupError::Link)
    }

    /// Start a sensor frame seen from `pose` (sensor → map): the window follows the sensor (voxels left
    /// behind are queued for the link). Add the frame's points through the returned [`SensorFrame`].
    pub fn begin_frame(&mut self, pose: &Isometry3<f32>) -> SensorFrame<'_, D, CAP, P, QB, N, H> {
        self.begin_frame_tapped(pose, NoTap)
    }

    /// [`Self::begin_frame`] with a tap that sees every voxel the frame hands to the link.
    pub fn begin_frame_tapped<T: EvictionTap<D>>(
        &mut self,
        pose: &Isometry3<f32>,
        mut tap: T,
    ) -> SensorFrame<'_, D, CAP, P, QB, N, H, T> {
        let t = pose.translation.vector;
        let mut sink = Tapped {
            sink: &mut self.encoder,
            tap: &mut tap,
        };
        self.map.move_window([t.x, t.y, t.z], &mut sink);
        SensorFrame {
            mapper: self,
            pose: *pose,
            fixed: None,
            tap,
        }
    }

    /// One whole frame: [`Self::begin_frame`] and [`SensorFrame::add_points`]. Returns the points integrated.
    pub fn integrate(
        &mut self,
        pose: &Isometry3<f32>,
        points: &[[f32; 3]],
        features: &[[f32; D]],
    ) -> usize {
        self.begin_frame(pose).add_points(points, features)
    }

    /// [`Self::integrate`] with a tap that sees every voxel the frame hands to the link.
    pub fn integrate_tapped<T: EvictionTap<D>>(
        &mut self,
        pose: &Isometry3<f32>,
        points: &[[f32; 3]],
        features: &[[f32; D]],
        tap: T,
    ) -> usize {
        self.begin_frame_tapped(pose, tap)
            .add_points(points, features)
    }

    /// [`Self::integrate`] for int8 features (see [`Setup::with_int8_features`]).
    pub fn integrate_i8(
        &mut self,
        pose: &Isometry3<f32>,
        points: &[[f32; 3]],
        codes: &[[i8; D]],
    ) -> usize {
        self.begin_frame(pose).add_points_i8(points, codes)
    }

    /// Spend up to `budget` bytes on the link: overdue re-sends (with a back channel), the session header
    /// when due, then the evicted voxels (oldest first). Only whole frames are written.
    pub fn tick<W: embedded_io::Write>(
        &mut self,
        w: &mut W,
        budget: usize,
    ) -> Result<TickReport, TickError<W::Error>> {
        self.encoder
            .tick(w, budget, core::iter::empty::<Evicted<'_, D>>())
    }

    /// [`Self::tick`], then live updates: up to `live_budget` of the `budget` bytes stream the held voxels
    /// that changed since they were last streamed, in ring order over the map's slots (each gets its
    /// turn), so a base station's map follows the robot while it works. The base station replaces a live
    /// copy by the next one and by the final one. (A firmware that wants only final voxels calls
    /// [`Self::tick`], and links none of this.)
    pub fn tick_live<W: embedded_io::Write>(
        &mut self,
        w: &mut W,
        budget: usize,
        live_budget: usize,
    ) -> Result<TickReport, TickError<W::Error>> {
        if live_budget == 0 || self.map.is_empty() {
            return self.tick(w, budget);
        }
        let hand = self.live_hand;
        let report = self
            .encoder
            .tick_live(w, budget, live_budget, self.map.changed_voxels(hand));
        // The leading `live_sent` changed voxels from the hand were consumed: mark them streamed.
        let consumed = match &report {
            Ok(r) => r.live_sent,
            Err(TickError::Write(_, r)) => r.live_sent,
        };
        let mut at = hand;
        for _ in 0..consumed {
            let Some(s) = self.map.next_changed(at) else {
                break;
            };
            self.map.mark_streamed(s);
            at = if s + 1 >= CAP { 0 } else { s + 1 };
        }
        self.live_hand = at;
        report
    }

    /// Read the acknowledgements the back channel has ready (never blocking): acknowledged frames are
    /// freed, frames shown missing are re-sent once half the timeout passed. Bad bytes are refused and counted
    /// ([`crate::wire::LinkStats::bad_acks`], [`Self::ack_stats`]). Returns the bytes read.
    pub fn poll_acks<R: embedded_io::Read + embedded_io::ReadReady>(
        &mut self,
        r: &mut R,
    ) -> Result<usize, R::Error> {
        let settings = *self.encoder.settings();
        let before = self.acks.stats().refused();
        let encoder = &mut self.encoder;
        let n = self.acks.poll(r, settings.robot, settings.session, |ack| {
            encoder.acknowledge(&ack);
        })?;
        self.encoder
            .count_bad_acks(self.acks.stats().refused().saturating_sub(before));
        Ok(n)
    }

    /// What the acknowledgement reader saw.
    pub fn ack_stats(&self) -> crate::frame::AckStats {
        self.acks.stats()
    }

    /// Whether everything reached the base station: nothing held, nothing queued, nothing unacknowledged
    /// (without a back channel: nothing held or queued).
    pub fn is_drained(&self) -> bool {
        self.map.is_empty() && self.encoder.queued() == 0 && self.encoder.unacknowledged() == 0
    }

    /// End of the run: evict every voxel and send everything, then a link-statistics frame. Returns the
    /// number of voxels evicted from the map. With a back channel, frames may still await their
    /// acknowledgement after it returns (read them with [`Self::poll_acks`], tick until
    /// [`Self::is_drained`]); when the re-send buffer is full it returns [`DrainError::Stuck`]: read
    /// acknowledgements and drain again.
    pub fn drain<W: embedded_io::Write>(&mut self, w: &mut W) -> Result<u32, DrainError<W::Error>> {
        self.drain_tapped(w, NoTap)
    }

    /// [`Self::drain`] with a tap that sees every voxel handed to the link.
    pub fn drain_tapped<W: embedded_io::Write, T: EvictionTap<D>>(
        &mut self,
        w: &mut W,
        mut tap: T,
    ) -> Result<u32, DrainError<W::Error>> {
        let mut evicted = 0u32;
        // The queue refuses when full: alternate flushing the map and sending until both are empty.
        loop {
            let mut sink = Tapped {
                sink: &mut self.encoder,
                tap: &mut tap,
            };
            let flushed = self.map.flush(&mut sink);
            let (Ok(n) | Err(n)) = flushed;
            evicted = evicted.saturating_add(n as u32);
            if flushed.is_ok() && self.encoder.queued() == 0 {
                break;
            }
            let sent = self
                .encoder
                .tick(w, usize::MAX, core::iter::empty::<Evicted<'_, D>>())?;
            if sent.evicted_sent == 0 && n == 0 {
                return Err(DrainError::Stuck);
            }
        }
        self.encoder.send_stats(w).map_err(DrainError::Write)?;
        Ok(evicted)
    }

    /// How many evicted voxels (summaries) the encoder's queue holds with this session's codec: `QB` / the
    /// bytes one queued summary takes (0 before [`Self::configure`]). Voxels beyond it stay in the map until
    /// a tick sends some (back-pressure).
    pub fn queue_capacity(&self) -> usize {
        self.encoder.capacity()
    }

    /// The map (voxels, posteriors, counters, rejections).
    pub fn map(&self) -> &LocalMap<D, CAP, P, H> {
        &self.map
    }
    /// The encoder (queue, link statistics).
    pub fn encoder(&self) -> &FrameEncoder<D, QB, N> {
        &self.encoder
    }
    /// The information-gain score of a candidate view against the voxels held now
    /// ([`crate::info_gain::view_score`]: `hits` sorted by key, each with its expected point count).
    pub fn view_score(
        &self,
        hits: &[(crate::key::VoxelKey, f32)],
    ) -> Result<f32, crate::info_gain::ScoreError> {
        let (lut, prior) = (self.map.kernel(), self.map.prior());
        crate::info_gain::view_score(lut, &self.map, prior.lambda, hits)
    }
}

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
> {
    mapper: &'m mut Mapper<D, CAP, P, QB, N, H>,
    pose: Isometry3<f32>,
    /// The pose in fixed point, made at the first integer point (`Some(None)`: not representable).
    fixed: Option<Option<FixedPose>>,
    tap: T,
}

impl<
        const D: usize,
        const CAP: usize,
        const P: usize,
        const QB: usize,
        const N: usize,
        const H: usize,
        T: EvictionTap<D>,
    > SensorFrame<'_, D, CAP, P, QB, N, H, T>
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
    /// [`Setup::int8_scale`] · c. The map keeps exact integer sums while a voxel is observed, so a
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
    pub fn map(&self) -> &LocalMap<D, CAP, P, H> {
        &self.mapper.map
    }
}

#[cfg(test)]
mod link_tests;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::{Feed, FrameDecoder};
    use crate::quant::packed_len;
    use crate::wire::{parse_body, Message};
    use nalgebra::{Translation3, UnitQuaternion};

    extern crate std;
    use std::boxed::Box;
    use std::vec::Vec;

    const D: usize = 8;
    /// A small queue (6 evicted voxels) so that draining needs several rounds of flush and send.
    type Small = Mapper<D, 256, { packed_len(D) }, 160, 256>;

    /// A link that collects bytes, or fails every write while `broken`.
    struct Link {
        bytes: Vec<u8>,
        broken: bool,
    }
    impl embedded_io::ErrorType for Link {
        type Error = embedded_io::ErrorKind;
    }
    impl embedded_io::Write for Link {
        fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
            if self.broken {
                return Err(embedded_io::ErrorKind::BrokenPipe);
            }
            self.bytes.extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> Result<(), Self::Error> {
            Ok(())
        }
    }

    fn setup() -> Setup {
        Setup::new(MapConfig::DEFAULT, 1.0, EncoderSettings::new(2, 3))
    }

    /// 100 points on a 1 m strip beside `x` (within the 1 m window).
    fn frame(mapper: &mut Small, x: f32) -> usize {
        let pose =
            Isometry3::from_parts(Translation3::new(x, 0.0, 0.0), UnitQuaternion::identity());
        let points: Vec<[f32; 3]> = (0..100)
            .map(|i| [0.01 * i as f32 - 0.5, 0.3, 0.02])
            .collect();
        let features: Vec<[f32; D]> = (0..100).map(|i| [i as f32 * 0.01; D]).collect();
        mapper.integrate(&pose, &points, &features)
    }

    /// (summaries, Σ point counts) in a byte stream.
    fn decode(bytes: &[u8]) -> (usize, f32) {
        let mut decoder = FrameDecoder::<512>::default();
        let (mut summaries, mut points) = (0, 0.0);
        let mut rest = bytes;
        loop {
            match decoder.feed(rest) {
                Feed::NeedMore => break,
                Feed::Error { error, .. } => panic!("frame error {error:?}"),
                Feed::Frame { body, rest: r } => {
                    if let Ok((_, Message::Voxels(batch))) = parse_body(body) {
                        for s in batch.iter::<D>(setup().codec) {
                            summaries += 1;
                            points += s.unwrap().obs.count;
                        }
                    }
                    rest = r;
                }
            }
        }
        (summaries, points)
    }

    #[test]
    fn every_point_reaches_the_link_through_a_small_queue() {
        let mut mapper = Box::new(Small::EMPTY);
        mapper.configure(&setup()).unwrap();
        let mut link = Link {
            bytes: Vec::new(),
            broken: false,
        };
        let mut taken = 0;
        for f in 0..10 {
            taken += frame(&mut mapper, f as f32 * 0.5);
            mapper.tick(&mut link, 300).unwrap();
        }
        assert_eq!(taken, 1000);
        let held = mapper.map().len();
        assert!(held > 6, "more voxels than the queue holds: {held}");
        mapper.drain(&mut link).unwrap();
        assert!(mapper.map().is_empty());
        assert_eq!(mapper.encoder().queued(), 0);
        let (summaries, points) = decode(&link.bytes);
        assert_eq!(summaries as u32, mapper.map().counters().evicted);
        assert_eq!(points, 1000.0, "every point arrives exactly once");
    }

    #[test]
    fn a_failing_link_loses_nothing() {
        let mut mapper = Box::new(Small::EMPTY);
        mapper.configure(&setup()).unwrap();
        let mut link = Link {
            bytes: Vec::new(),
            broken: true,
        };
        for f in 0..4 {
            frame(&mut mapper, f as f32 * 0.5);
            assert!(mapper.tick(&mut link, 300).is_err());
        }
        assert!(matches!(mapper.drain(&mut link), Err(DrainError::Write(_))));
        link.broken = false;
        mapper.drain(&mut link).unwrap();
        // Frames written while the link was broken are lost on the wire (the receiver counts them by
        // sequence number); every voxel the encoder did not get to write arrives.
        let (_, points) = decode(&link.bytes);
        assert!(points > 0.0 && points <= 400.0, "{points}");
        assert!(mapper.map().is_empty());
    }

    #[test]
    fn a_refused_setup_sends_nothing() {
        let mut mapper = Box::new(Small::EMPTY);
        mapper.configure(&setup()).unwrap();
        let bad = Setup {
            window_radius: 0.0,
            ..setup()
        };
        assert_eq!(
            mapper.configure(&bad),
            Err(SetupError::Map(ConfigError::Window))
        );
        let mut link = Link {
            bytes: Vec::new(),
            broken: false,
        };
        frame(&mut mapper, 0.0);
        assert_eq!(mapper.tick(&mut link, 1000).unwrap().bytes, 0);
        assert_eq!(mapper.drain(&mut link), Err(DrainError::Stuck));
        assert!(link.bytes.is_empty());
        let no_codec = Setup {
            codec: SummaryCodec {
                mean_bits: 1,
                psi_blocks: 8,
                mean_bits_growth: 0,
                lead: 0,
                lead_bits: 0,
            },
            ..setup()
        };
        assert_eq!(
            mapper.configure(&no_codec),
            Err(SetupError::Link(WireError::BadConfig))
        );
    }

    #[test]
    fn ram_bytes_is_the_size_of_the_mapper() {
        use core::mem::size_of;
        assert_eq!(Small::RAM_BYTES, size_of::<Small>());
        type Big = Mapper<64, 1228, { packed_len(64) }, 4096, 512>;
        assert_eq!(Big::RAM_BYTES, size_of::<Big>());
        type Lidar = Mapper<64, 900, { packed_len(64) }, 2048, 256, 96>;
        assert_eq!(Lidar::RAM_BYTES, size_of::<Lidar>());
        type Odd = Mapper<13, 77, { packed_len(13) }, 333, 129, 5>;
        assert_eq!(Odd::RAM_BYTES, size_of::<Odd>());
        // The hot tier is in the formula: one more hot entry costs its bytes.
        type More = Mapper<64, 1228, { packed_len(64) }, 4096, 512, 33>;
        assert_eq!(
            More::RAM_BYTES,
            (Big::RAM_BYTES + LocalMap::<64, 1228, { packed_len(64) }>::BYTES_PER_HOT_VOXEL)
                .next_multiple_of(core::mem::align_of::<Big>())
        );
    }

    #[test]
    fn the_queue_capacity_is_in_summaries() {
        let mut mapper = Box::new(Small::EMPTY);
        assert_eq!(mapper.queue_capacity(), 0);
        mapper.configure(&setup()).unwrap();
        let n = mapper.queue_capacity();
        assert!(n > 0);
        // Filling the map beyond the queue: exactly `n` evictions are queued before the queue refuses.
        for x in 0..40 {
            frame(&mut mapper, x as f32 * 3.0);
            if mapper.encoder().queued() == n {
                break;
            }
        }
        assert_eq!(mapper.encoder().queued(), n);
        assert!(mapper.encoder().stats().refused > 0);
    }

    #[test]
    fn the_window_covers_the_sensor_range() {
        const W: f32 = MapConfig::DEFAULT.window_for_range(4.0);
        static S: Setup = Setup::new(
            MapConfig::DEFAULT,
            MapConfig::DEFAULT.window_for_range(4.0),
            EncoderSettings::new(1, 1),
        );
        assert!((W - 4.3).abs() < 1e-6);
        let mut mapper = Box::new(Small::EMPTY);
        mapper.configure(&S).unwrap();
        // Returns at the full range in every direction, from a sensor anywhere in its voxel: all taken.
        let mut frame = mapper.begin_frame(&Isometry3::from_parts(
            Translation3::new(0.099, -0.001, 0.05),
            UnitQuaternion::identity(),
        ));
        for i in 0..64 {
            let a = i as f32 * core::f32::consts::TAU / 64.0;
            let p = [4.0 * libm::cosf(a), 4.0 * libm::sinf(a), 0.0];
            assert_eq!(frame.add_point(p, &[0.5; D]), Ok(()), "{p:?}");
        }
    }
}
