//! Running a scenario: frames of generated points through the core's `Mapper`, the probe around the map's
//! work, the self-test's scenarios and sizes, and the report both the firmware and the host twin print.

#[allow(unused_imports)]
use crate::*;
use latentbki::batch::RejectionCounts;
use latentbki::config::{ConfigError, KernelMode, MapConfig, Prior};
use latentbki::forget::MapClock;
use latentbki::frame::{EncoderSettings, Resend};
use latentbki::local_map::{Counters, LocalMap};
use latentbki::mapper::{DrainError, Mapper, Setup, SetupError};
use latentbki::nalgebra::Isometry3;
use latentbki::quant::Cooling;
use latentbki::wire::LinkStats;

/// Brackets the map's work inside [`integrate_frame`] (the firmware counts instructions between the two
/// calls; the host does nothing), and — for a host tool that must know which points the map took (the
/// f32 reference of the points a firmware integrated) — sees every point.
pub trait Probe {
    /// The map's work begins.
    fn start(&mut self) {}
    /// The map's work ends.
    fn stop(&mut self) {}
    /// Whether [`Self::point`] is called: then [`integrate_frame`] adds the points one by one (the same
    /// map operations as the batch calls a firmware makes, so the same results).
    const SEES_POINTS: bool = false;
    /// One point of frame `pose` and whether the map took it: its sensor-frame position (and, with int8
    /// features, the millimetres the map was given) and its f32 feature (before int8 quantization).
    fn point(
        &mut self,
        _pose: &Isometry3<f32>,
        _point: [f32; 3],
        _point_mm: Option<[i32; 3]>,
        _feature: &[f32],
        _taken: bool,
    ) {
    }
}

/// A probe that does nothing.
impl Probe for () {}

/// Generation scratch for `K` points at a time (sensor-frame points and their features).
pub struct Chunk<const D: usize, const K: usize> {
    /// Map-frame points.
    pub points: [[f32; 3]; K],
    /// Their features.
    pub features: [[f32; D]; K],
    /// Their features as int8 codes (scenarios with int8 features).
    pub codes: [[i8; D]; K],
    /// The points in integer millimetres, as a range sensor reports them (scenarios with int8 features).
    pub points_mm: [[i32; 3]; K],
}

impl<const D: usize, const K: usize> Chunk<D, K> {
    /// All zero (a `static` initialiser that lands in `.bss`).
    pub const ZERO: Self = Self {
        points: [[0.0; 3]; K],
        features: [[0.0; D]; K],
        codes: [[0; D]; K],
        points_mm: [[0; 3]; K],
    };
}

/// int8 codes of a feature at `scale` (what an accelerator with that output scale hands the map): each
/// component rounded to the nearest code, clamped to ±127.
pub fn quantize<const D: usize>(feature: &[f32; D], scale: f32, codes: &mut [i8; D]) {
    let inv = 1.0 / scale;
    for (c, &v) in codes.iter_mut().zip(feature) {
        *c = libm::roundf(v * inv).clamp(-127.0, 127.0) as i8;
    }
}

/// What [`integrate_frame`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FrameReport {
    /// Sensor returns generated (zones in range).
    pub points: u32,
    /// Points the map integrated (its `counters().points` went up by this much).
    pub integrated: u32,
}

/// Generate frame `frame` of `scene` in chunks of `K` points and integrate it into `mapper` as one sensor
/// frame, as f32 features or (`int8_scale` > 0) as int8 codes of that scale with the points in integer
/// millimetres (the all-integer path, [`latentbki::mapper::SensorFrame::add_points_mm_i8`]) ([`Mapper::begin_frame`], then each chunk). The map's work — and only it — runs between
/// `probe.start()` and `probe.stop()` (once for the window move, once per chunk).
pub fn integrate_frame<
    const D: usize,
    const CAP: usize,
    const P: usize,
    const QB: usize,
    const N: usize,
    const H: usize,
    const K: usize,
    M: Probe,
    C: MapClock,
>(
    scene: &Scene,
    frame: u32,
    int8_scale: f32,
    mapper: &mut Mapper<D, CAP, P, QB, N, H, C>,
    chunk: &mut Chunk<D, K>,
    probe: &mut M,
) -> FrameReport {
    let view = scene.view(frame);
    let pose = view.pose();
    let mut report = FrameReport::default();
    let before = mapper.map().counters().points;
    probe.start();
    let mut batch = mapper.begin_frame(&pose);
    probe.stop();
    let zones = scene.sensor.zones();
    let mut zone = 0;
    while zone < zones {
        let mut n = 0;
        while n < K && zone < zones {
            if let Some(o) = scene.observe(&view, frame, zone, &mut chunk.features[n]) {
                chunk.points[n] = o.point;
                if int8_scale > 0.0 {
                    quantize(&chunk.features[n], int8_scale, &mut chunk.codes[n]);
                    chunk.points_mm[n] = o.point.map(|v| libm::roundf(v * 1000.0) as i32);
                }
                n += 1;
            }
            zone += 1;
        }
        report.points += n as u32;
        probe.start();
        // Refusals are counted by the map (`rejections`).
        if M::SEES_POINTS {
            for i in 0..n {
                let (p, y) = (chunk.points[i], &chunk.features[i]);
                let (mm, taken) = if int8_scale > 0.0 {
                    let mm = chunk.points_mm[i];
                    (Some(mm), batch.add_point_mm_i8(mm, &chunk.codes[i]).is_ok())
                } else {
                    (None, batch.add_point(p, y).is_ok())
                };
                probe.point(&pose, p, mm, y, taken);
            }
        } else if int8_scale > 0.0 {
            // An integer sensor and an int8 accelerator: no float operation per point.
            batch.add_points_mm_i8(&chunk.points_mm[..n], &chunk.codes[..n]);
        } else {
            batch.add_points(&chunk.points[..n], &chunk.features[..n]);
        }
        probe.stop();
    }
    report.integrated = batch.map().counters().points.wrapping_sub(before);
    report
}

/// One self-test run: a scene, how many frames, the map and the link.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scenario {
    /// What it measures, for reports (one word, no spaces).
    pub name: &'static str,
    /// What the sensor sees (a `static`: scenarios that differ only in the map or the features share one,
    /// so the firmware stores each scene once).
    pub scene: &'static Scene,
    /// Frames integrated.
    pub frames: u32,
    /// Filter size f of the map (0.1 m voxels, ℓ = 0.5 m, default prior, voxel-offset kernel).
    pub filter_size: u8,
    /// Window radius around the sensor (m).
    pub window_radius: f32,
    /// Session id on the wire (robot [`SELF_TEST_ROBOT`]).
    pub session: u32,
    /// Link bytes per frame (e.g. 2,048 B: 460,800 Bd at 20 frames/s).
    pub tick_budget: usize,
    /// Scale of int8 features ([`Setup::with_int8_features`]); 0 = f32 features.
    pub int8_scale: f32,
}

/// Robot id the self-test streams as.
pub const SELF_TEST_ROBOT: u16 = 6;
/// RAM the self-test gives the map's voxels (slots and index): 192 KiB less 16 KiB of stack and 32 KiB
/// for the rest (the map's batch scratch and kernel table, the encoder, the point chunk).
pub const SELF_TEST_MAP_BUDGET: usize = 144 * 1024;
/// Voxels the self-test map holds at D = 64: what [`SELF_TEST_MAP_BUDGET`] buys at the current bytes per
/// voxel.
pub const SELF_TEST_CAPACITY: usize =
    SELF_TEST_MAP_BUDGET / LocalMap::<64, 1, { latentbki::quant::packed_len(64) }>::BYTES_PER_VOXEL;
/// Bytes of the encoder's queue of evicted voxels.
pub const SELF_TEST_QUEUE_BYTES: usize = 4096;
/// Of the queue budget: bytes that keep frames until the loopback acknowledges them.
pub const SELF_TEST_RESEND_BYTES: usize = 2048;
/// Largest frame on the wire.
pub const SELF_TEST_FRAME_BYTES: usize = 512;

/// The 8×8 ToF circling the room.
pub static TOF_ROOM: Scene = Scene::new(DepthSensor::TOF_8X8, 0x70F);
/// 4,096-point depth frames circling the room (three seeds: f = 1, f = 3, the full map).
pub static DEPTH_D1: Scene = Scene::new(DepthSensor::DEPTH_64X64, 0xD1);
/// See [`DEPTH_D1`].
pub static DEPTH_D3: Scene = Scene::new(DepthSensor::DEPTH_64X64, 0xD3);
/// See [`DEPTH_D1`].
pub static DEPTH_D4: Scene = Scene::new(DepthSensor::DEPTH_64X64, 0xD4);
/// A 2D scanning LiDAR driving through a room and down a corridor, 240 revolutions.
pub static LIDAR_CORRIDOR: Scene = Scene::room_and_corridor(DepthSensor::LIDAR_360, 0x11DA, 240);

/// The firmware self-test: the 8×8 ToF for three turns (f = 1), then 4,096-point depth frames at f = 1
/// and f = 3 (the instruction-count benchmark), then half a turn of depth frames with a window that holds
/// the whole room (f = 3): the map fills, so the run measures how many voxels a full map answers; then the
/// sensor patterns at f = 3 for the instruction counts: the depth frames with int8 features, the 8×8 ToF,
/// and a 2D scanning LiDAR (360 beams per revolution, 240 revolutions: 24 s at 10 Hz) driving through a room
/// and down a corridor; then the two sparse patterns again with int8 features (the all-integer path an MCU
/// without an FPU runs: points in millimetres, codes of [`SELF_TEST_INT8_SCALE`]).
pub const SELF_TEST: [Scenario; 9] = [
    Scenario {
        name: "tof_f1",
        scene: &TOF_ROOM,
        frames: 144,
        filter_size: 1,
        window_radius: 2.0,
        session: 1,
        tick_budget: 2048,
        int8_scale: 0.0,
    },
    Scenario {
        name: "depth_f1",
        scene: &DEPTH_D1,
        frames: 8,
        filter_size: 1,
        window_radius: 2.5,
        session: 2,
        tick_budget: 8192,
        int8_scale: 0.0,
    },
    Scenario {
        name: "depth_f3",
        scene: &DEPTH_D3,
        frames: 8,
        filter_size: 3,
        window_radius: 2.5,
        session: 3,
        tick_budget: 8192,
        int8_scale: 0.0,
    },
    Scenario {
        name: "full_map",
        scene: &DEPTH_D4,
        frames: 24,
        filter_size: 3,
        window_radius: 4.0,
        session: 4,
        tick_budget: 8192,
        int8_scale: 0.0,
    },
    Scenario {
        name: "depth_f3_i8",
        scene: &DEPTH_D3,
        frames: 8,
        filter_size: 3,
        window_radius: 2.5,
        session: 5,
        tick_budget: 8192,
        int8_scale: SELF_TEST_INT8_SCALE,
    },
    Scenario {
        name: "tof_f3",
        scene: &TOF_ROOM,
        frames: 144,
        filter_size: 3,
        window_radius: 2.0,
        session: 6,
        tick_budget: 2048,
        int8_scale: 0.0,
    },
    Scenario {
        name: "lidar_f3",
        scene: &LIDAR_CORRIDOR,
        frames: 240,
        filter_size: 3,
        window_radius: 4.0,
        session: 7,
        tick_budget: 2048,
        int8_scale: 0.0,
    },
    Scenario {
        name: "tof_f3_i8",
        scene: &TOF_ROOM,
        frames: 144,
        filter_size: 3,
        window_radius: 2.0,
        session: 8,
        tick_budget: 2048,
        int8_scale: SELF_TEST_INT8_SCALE,
    },
    Scenario {
        name: "lidar_f3_i8",
        scene: &LIDAR_CORRIDOR,
        frames: 240,
        filter_size: 3,
        window_radius: 4.0,
        session: 9,
        tick_budget: 2048,
        int8_scale: SELF_TEST_INT8_SCALE,
    },
];

/// Scale of the self-test's int8 features: codes of ±127 reach ±0.635, beyond the codebook's ±1/8 plus
/// five standard deviations of its 0.1 noise.
pub const SELF_TEST_INT8_SCALE: f32 = 0.005;

impl Scenario {
    /// The map configuration.
    pub fn map_config(&self) -> Result<MapConfig, ConfigError> {
        MapConfig::new(
            0.1,
            0.5,
            self.filter_size,
            Prior::default(),
            KernelMode::VoxelOffset,
        )
    }

    /// The mapper's setup: this map, robot [`SELF_TEST_ROBOT`] with the scenario's session,
    /// [`SELF_TEST_CODEC`], [`SELF_TEST_MEAN_WEIGHTS`], no PCA, the int8 scale if any, and a back channel
    /// (half the queue budget keeps unacknowledged frames; [`run`] loops the acknowledgements back).
    pub fn setup(&self) -> Result<Setup, ConfigError> {
        let setup = Setup {
            codec: SELF_TEST_CODEC,
            ..Setup::new(
                self.map_config()?,
                self.window_radius,
                EncoderSettings::new(SELF_TEST_ROBOT, self.session)
                    .with_resend(Resend::new(SELF_TEST_RESEND_BYTES as u32, 4)),
            )
        }
        .with_mean_weights(SELF_TEST_MEAN_WEIGHTS);
        Ok(if self.int8_scale > 0.0 {
            setup.with_int8_features(self.int8_scale)
        } else {
            setup
        })
    }

    /// Clear `mapper` and configure it for this scenario (in place), cooling int8 sums by this build's
    /// method ([`Cooling::NATIVE`]: what a firmware does).
    pub fn configure<
        const D: usize,
        const CAP: usize,
        const P: usize,
        const QB: usize,
        const N: usize,
        const H: usize,
        C: MapClock,
    >(
        &self,
        mapper: &mut Mapper<D, CAP, P, QB, N, H, C>,
    ) -> Result<(), SetupError> {
        self.configure_cooling(mapper, Cooling::NATIVE)
    }

    /// [`Self::configure`] cooling int8 sums by `cooling`: a host twin passes its board's method.
    pub fn configure_cooling<
        const D: usize,
        const CAP: usize,
        const P: usize,
        const QB: usize,
        const N: usize,
        const H: usize,
        C: MapClock,
    >(
        &self,
        mapper: &mut Mapper<D, CAP, P, QB, N, H, C>,
        cooling: Cooling,
    ) -> Result<(), SetupError> {
        let setup = self.setup().map_err(SetupError::Map)?;
        mapper.configure(&setup.with_cooling(cooling))
    }

    /// [`Self::configure`] forgetting with `forgetting` (a mapper with the
    /// [`latentbki::forget::Fading`] clock; [`run`] ticks once per frame).
    #[cfg(feature = "forgetting")]
    pub fn configure_forgetting<
        const D: usize,
        const CAP: usize,
        const P: usize,
        const QB: usize,
        const N: usize,
        const H: usize,
        C: MapClock,
    >(
        &self,
        mapper: &mut Mapper<D, CAP, P, QB, N, H, C>,
        forgetting: Option<latentbki::forget::Forgetting>,
    ) -> Result<(), SetupError> {
        let setup = self.setup().map_err(SetupError::Map)?;
        mapper.configure(&setup.with_forgetting(forgetting))
    }
}

/// What [`run`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RunReport {
    /// Sensor returns generated.
    pub points: u32,
    /// Points the map accepted.
    pub integrated: u32,
    /// Points refused, by reason.
    pub rejections: RejectionCounts,
    /// The map's counters.
    pub counters: Counters,
    /// Most voxels held at the end of a frame.
    pub peak_voxels: u32,
    /// Voxels flushed at the end.
    pub flushed: u32,
    /// The encoder's link statistics at the end.
    pub link: LinkStats,
}

/// Run a scenario on a mapper freshly configured for it ([`Scenario::configure`]): integrate every frame
/// (the map's work bracketed by `probe`), after each frame let the mapper spend the scenario's byte budget
/// on `w`, and at the end drain it ([`Mapper::drain`]: every voxel, then a link-statistics frame).
/// `on_frame` sees each frame's report (the firmware logs it and marks the end of the frame for the
/// instruction counter).
pub fn run<
    const D: usize,
    const CAP: usize,
    const P: usize,
    const QB: usize,
    const N: usize,
    const H: usize,
    const K: usize,
    W,
    M,
    C: MapClock,
>(
    scenario: &Scenario,
    mapper: &mut Mapper<D, CAP, P, QB, N, H, C>,
    chunk: &mut Chunk<D, K>,
    w: &mut W,
    probe: &mut M,
    mut on_frame: impl FnMut(u32, &FrameReport, &LocalMap<D, CAP, P, H, C>),
) -> Result<RunReport, RunError<W::Error>>
where
    W: embedded_io::Write,
    M: Probe,
{
    let config = scenario.map_config().map_err(RunError::Config)?;
    let map = mapper.map();
    let fresh = map.config() == &config && map.is_empty() && map.counters() == Counters::default();
    if !fresh || !mapper.encoder().is_configured() || mapper.encoder().next_seq() != 0 {
        return Err(RunError::NotConfigured);
    }
    let mut report = RunReport::default();
    // The frames go to the UART; the loopback acknowledges them as a base station on a perfect link would.
    let mut back = loopback::Loopback::new();
    let (robot, session) = (SELF_TEST_ROBOT, scenario.session);
    for frame in 0..scenario.frames {
        // One tick per frame (nothing in a mapper that never forgets).
        mapper.set_time(frame);
        let f = integrate_frame(
            scenario.scene,
            frame,
            scenario.int8_scale,
            mapper,
            chunk,
            probe,
        );
        report.points += f.points;
        report.integrated += f.integrated;
        report.peak_voxels = report.peak_voxels.max(mapper.map().len() as u32);
        on_frame(frame, &f, mapper.map());
        mapper
            .tick(w, scenario.tick_budget)
            .map_err(|latentbki::frame::TickError::Write(e, _)| RunError::Write(e))?;
        back.acknowledge_all(robot, session, mapper.encoder().next_seq());
        let Ok(_) = mapper.poll_acks(&mut back);
    }
    // Drain: a full re-send buffer waits for acknowledgements.
    let before = mapper.map().counters().evicted;
    loop {
        let done = match mapper.drain(w) {
            Ok(_) => true,
            Err(DrainError::Write(e)) => return Err(RunError::Write(e)),
            // Stuck (or a reason a later version adds): acknowledgements may free the re-send buffer.
            Err(_) => false,
        };
        back.acknowledge_all(robot, session, mapper.encoder().next_seq());
        let Ok(read) = mapper.poll_acks(&mut back);
        if done {
            break;
        }
        if read == 0 {
            return Err(RunError::Stuck);
        }
    }
    if !mapper.is_drained() {
        return Err(RunError::Stuck);
    }
    report.flushed = mapper.map().counters().evicted.wrapping_sub(before);
    report.rejections = mapper.map().rejections();
    report.counters = mapper.map().counters();
    report.link = mapper.encoder().stats();
    Ok(report)
}

/// Why [`run`] stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RunError<E> {
    /// The scenario's map configuration is invalid.
    Config(ConfigError),
    /// The mapper was not freshly configured for this scenario.
    NotConfigured,
    /// The writer failed.
    Write(E),
    /// The encoder could not send a queued voxel (its frame size is too small for one summary).
    Stuck,
}
