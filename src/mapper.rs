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

use crate::forget::{MapClock, Timeless};
use crate::frame::{AckReader, FrameEncoder, TickError, TickReport};
use crate::local_map::{LocalMap, HOT_VOXELS};
use crate::sink::Evicted;
use nalgebra::Isometry3;

mod live;
mod robot_type;
mod sensor_frame;
mod setup;
mod tap;
pub use sensor_frame::SensorFrame;
pub use setup::{Setup, SetupError};
use tap::Tapped;
pub use tap::{EvictionTap, NoTap};

/// Why [`Mapper::drain`] stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum DrainError<E> {
    /// The writer failed; what was not sent stays in the map or the encoder's queue.
    Write(E),
    /// A queued voxel could not be sent (the frame size `N` is too small for one summary, or no session),
    /// or, with a back channel, the re-send buffer is full of unacknowledged frames: read acknowledgements
    /// ([`Mapper::poll_acks`]) and drain again.
    Stuck,
}

impl<E: core::fmt::Debug> core::fmt::Display for DrainError<E> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Write(e) => write!(f, "drain: writing to the link failed ({e:?}); what was not sent is kept"),
            Self::Stuck => f.write_str(
                "drain: a voxel cannot be sent (frame too small for a summary, no session, or the re-send buffer full of unacknowledged frames)",
            ),
        }
    }
}

impl<E: core::fmt::Debug> core::error::Error for DrainError<E> {}

/// What one [`Mapper::drain_within`] call did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DrainReport {
    /// Voxels evicted from the map into the encoder's queue.
    pub evicted: u32,
    /// Bytes written (≤ the budget).
    pub bytes: usize,
    /// Everything was sent: the map and the queue are empty, no frame waits for its write, and the last
    /// frame written is the closing link statistics. (With a back channel, frames may still wait for their
    /// acknowledgement: [`Mapper::is_drained`].)
    pub done: bool,
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
    C: MapClock = Timeless,
> {
    map: LocalMap<D, CAP, P, H, C>,
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
        C: MapClock,
    > Mapper<D, CAP, P, QB, N, H, C>
{
    /// The mapper's RAM (its `static`): the map's (voxels, hot tier, kernel table: [`LocalMap::RAM_BYTES`],
    /// exactly its size on a 32-bit MCU) plus the encoder (queue `QB`, two frame buffers of `N`, state), the
    /// acknowledgement reader and the live-update hand, rounded to the alignment. Equals `size_of::<Self>()`
    /// on every target (tested), so a firmware checks its budget at compile time:
    /// `const _: () = assert!(Robot::RAM_BYTES <= 150 * 1024);`.
    pub const RAM_BYTES: usize = (core::mem::size_of::<LocalMap<D, CAP, P, H, C>>()
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
        self.map
            .set_cooling(setup.cooling)
            .map_err(SetupError::Map)?;
        // Only with the `forgetting` feature: the link must carry stamps for a map that forgets (without
        // it a mapper never forgets, and none of this is linked).
        #[cfg(feature = "forgetting")]
        self.map
            .set_forgetting(setup.forgetting)
            .map_err(SetupError::Map)?;
        // Without the feature only all-ones weights exist: one byte compared, no weighing code linked.
        #[cfg(feature = "mean-weights")]
        self.map
            .set_mean_weights(setup.mean_weights)
            .map_err(SetupError::Map)?;
        #[cfg(not(feature = "mean-weights"))]
        if !setup.mean_weights.is_ones() {
            return Err(SetupError::Map(crate::config::ConfigError::MeanWeights));
        }
        // Stored codes carry no weights: a weighed mean only its own map can weigh back.
        #[cfg(feature = "stored-codes")]
        if setup.codec.is_stored() && setup.mean_weights.has_shifts() {
            return Err(SetupError::Link(crate::wire::WireError::BadConfig));
        }
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
    pub fn begin_frame(
        &mut self,
        pose: &Isometry3<f32>,
    ) -> SensorFrame<'_, D, CAP, P, QB, N, H, NoTap, C> {
        self.begin_frame_tapped(pose, NoTap)
    }

    /// [`Self::begin_frame`] with a tap that sees every voxel the frame hands to the link.
    pub fn begin_frame_tapped<T: EvictionTap<D>>(
        &mut self,
        pose: &Isometry3<f32>,
        mut tap: T,
    ) -> SensorFrame<'_, D, CAP, P, QB, N, H, T, C> {
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

    /// Apply the acknowledgements in bytes read from the back channel by any means (an interrupt's buffer,
    /// an async read, a test): what [`Self::poll_acks`] does with the bytes it reads. Partial
    /// acknowledgements wait for their rest.
    pub fn feed_acks(&mut self, bytes: &[u8]) {
        let settings = *self.encoder.settings();
        let before = self.acks.stats().refused();
        let encoder = &mut self.encoder;
        self.acks
            .feed(bytes, settings.robot, settings.session, |ack| {
                encoder.acknowledge(&ack);
            });
        self.encoder
            .count_bad_acks(self.acks.stats().refused().saturating_sub(before));
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
    /// acknowledgements and drain again. A firmware that must not write everything at once calls
    /// [`Self::drain_within`] with a byte budget per call instead.
    pub fn drain<W: embedded_io::Write>(&mut self, w: &mut W) -> Result<u32, DrainError<W::Error>> {
        self.drain_tapped(w, NoTap)
    }

    /// [`Self::drain`] with a tap that sees every voxel handed to the link.
    pub fn drain_tapped<W: embedded_io::Write, T: EvictionTap<D>>(
        &mut self,
        w: &mut W,
        mut tap: T,
    ) -> Result<u32, DrainError<W::Error>> {
        let r = self.drain_within_tapped(w, usize::MAX, &mut tap)?;
        if r.done {
            Ok(r.evicted)
        } else {
            Err(DrainError::Stuck)
        }
    }

    /// One step of the end of the run, within `budget` bytes: evict voxels from the map into the queue and
    /// send whole frames — re-sends due, queued voxels, then the closing link statistics — until the budget
    /// or the work runs out. Call it again (reading acknowledgements in between, with a back channel) until
    /// [`DrainReport::done`]. It returns [`DrainError::Stuck`] only when nothing at all could be sent with
    /// at least a whole frame (`N` bytes) of budget: a frame size too small for one summary, no session, or
    /// a re-send buffer full of unacknowledged frames (read acknowledgements, then drain again).
    pub fn drain_within<W: embedded_io::Write>(
        &mut self,
        w: &mut W,
        budget: usize,
    ) -> Result<DrainReport, DrainError<W::Error>> {
        self.drain_within_tapped(w, budget, &mut NoTap)
    }

    fn drain_within_tapped<W: embedded_io::Write, T: EvictionTap<D>>(
        &mut self,
        w: &mut W,
        budget: usize,
        tap: &mut T,
    ) -> Result<DrainReport, DrainError<W::Error>> {
        let mut report = DrainReport::default();
        // The queue refuses when full: alternate flushing the map and sending until both are empty.
        loop {
            let mut sink = Tapped {
                sink: &mut self.encoder,
                tap: &mut *tap,
            };
            let flushed = self.map.flush(&mut sink);
            let (Ok(n) | Err(n)) = flushed;
            report.evicted = report.evicted.saturating_add(n as u32);
            let left = budget.saturating_sub(report.bytes);
            if flushed.is_ok() && self.drained_but_stats() {
                if self.stats_closed() {
                    report.done = true; // the closing statistics are the last frame written
                    return Ok(report);
                }
                return match self.encoder.send_stats_within(w, left) {
                    Ok(Some(sent)) => {
                        report.bytes += sent;
                        report.done = true;
                        Ok(report)
                    }
                    Ok(None) if left >= N && report.bytes == 0 => Err(DrainError::Stuck),
                    Ok(None) => Ok(report),
                    Err(e) => Err(DrainError::Write(e)),
                };
            }
            let sent = self
                .encoder
                .tick(w, left, core::iter::empty::<Evicted<'_, D>>())?;
            report.bytes += sent.bytes;
            if sent.frames == sent.resent && n == 0 {
                // No progress: out of budget, or (nothing written with a whole frame's budget) stuck.
                return if report.bytes == 0 && budget >= N {
                    Err(DrainError::Stuck)
                } else {
                    Ok(report)
                };
            }
        }
    }

    /// The queue is empty and no frame waits for its write (after a flush that emptied the map): only the
    /// closing statistics may be left to send.
    fn drained_but_stats(&self) -> bool {
        self.encoder.queued() == 0 && !self.encoder.has_pending()
    }

    /// The last frame written is link statistics (a drain's closing frame).
    fn stats_closed(&self) -> bool {
        self.encoder.frames_since_stats() == 0 && self.encoder.next_seq() != 0
    }

    /// How many evicted voxels (summaries) the encoder's queue holds with this session's codec: `QB` / the
    /// bytes one queued summary takes (0 before [`Self::configure`]). Voxels beyond it stay in the map until
    /// a tick sends some (back-pressure).
    pub fn queue_capacity(&self) -> usize {
        self.encoder.capacity()
    }

    /// Set the mission clock ([`crate::forget`]'s clock rule; a map that never forgets ignores it): the
    /// points of frames from now on are stamped `now`, reads decay to it. Call it once per sensor frame
    /// (or whenever the clock advances), before the frame's points.
    pub fn set_time(&mut self, now: u32) {
        self.map.set_time(now);
    }

    /// The map (voxels, posteriors, counters, rejections).
    pub fn map(&self) -> &LocalMap<D, CAP, P, H, C> {
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

#[cfg(feature = "async")]
mod asynch;

#[cfg(test)]
mod tests;
