//! Running a scenario: frames of generated points through the core's `Mapper`, the probe around the map's
//! work, the self-test's scenarios and sizes, and the report both the firmware and the host twin print.

#[allow(unused_imports)]
use crate::*;
use latentbki::batch::RejectionCounts;
use latentbki::config::ConfigError;
use latentbki::forget::MapClock;
use latentbki::local_map::{Counters, LocalMap};
use latentbki::mapper::{DrainError, Mapper};
use latentbki::nalgebra::Isometry3;
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
