//! The robot's side of the link as a firmware runs it: taps, live updates, acknowledgements.

use crate::config::MapConfig;
use crate::frame::{EncoderSettings, Resend};
use crate::mapper::*;
use crate::quant::packed_len;
use crate::receiver::{Receipt, Receiver, Sessions};
use crate::wire::Message;
use nalgebra::{Translation3, UnitQuaternion};

extern crate std;
use std::boxed::Box;
use std::vec::Vec;

const D: usize = 8;
type Robot = Mapper<D, 256, { packed_len(D) }, 4096, 256>;

/// The back channel: bytes written by the base station, read by the robot a few at a time.
#[derive(Default)]
struct BackChannel {
    bytes: Vec<u8>,
    at: usize,
}
impl embedded_io::ErrorType for BackChannel {
    type Error = core::convert::Infallible;
}
impl embedded_io::Read for BackChannel {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let n = buf.len().min(self.bytes.len() - self.at).min(7);
        buf[..n].copy_from_slice(&self.bytes[self.at..self.at + n]);
        self.at += n;
        Ok(n)
    }
}
impl embedded_io::ReadReady for BackChannel {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(self.at < self.bytes.len())
    }
}

fn setup(resend: Resend) -> Setup {
    Setup::new(
        MapConfig::DEFAULT,
        1.0,
        EncoderSettings::new(2, 3).with_resend(resend),
    )
}

/// 100 points on a strip beside `x`.
fn sensor_frame(x: f32) -> (Isometry3<f32>, Vec<[f32; 3]>, Vec<[f32; D]>) {
    let pose = Isometry3::from_parts(Translation3::new(x, 0.0, 0.0), UnitQuaternion::identity());
    let points = (0..100)
        .map(|i| [0.01 * i as f32 - 0.5, 0.3, 0.02])
        .collect();
    let features = (0..100).map(|i| [i as f32 * 0.01; D]).collect();
    (pose, points, features)
}

/// A base station in miniature: the core receiver, points of final and live summaries applied, and
/// acknowledgements written to the back channel.
struct Station {
    rx: Receiver<D, 512>,
    sessions: Sessions<2>,
    final_points: f32,
    live_summaries: u32,
    /// The latest live copy of each voxel.
    live: Vec<(crate::key::VoxelKey, crate::obs::ObsStats<D>)>,
}

impl Station {
    fn new() -> Self {
        Self {
            rx: Receiver::new(None),
            sessions: Sessions::new(),
            final_points: 0.0,
            live_summaries: 0,
            live: Vec::new(),
        }
    }
    fn receive(&mut self, mut input: &[u8], back: &mut BackChannel) {
        loop {
            let (ack, rest) = match self.rx.feed(input, &mut self.sessions) {
                Receipt::NeedMore => return,
                Receipt::Refused { ack, rest, .. } => (ack, rest),
                Receipt::Accepted { frame, rest } => {
                    if let Message::Voxels(batch) = frame.message {
                        let codec = frame.config.codec;
                        for s in batch.iter::<D>(codec) {
                            let s = s.unwrap();
                            if s.is_final {
                                self.final_points += s.obs.count;
                            } else {
                                self.live_summaries += 1;
                                match self.live.iter_mut().find(|(k, _)| *k == s.key) {
                                    Some((_, obs)) => *obs = s.obs,
                                    None => self.live.push((s.key, s.obs)),
                                }
                            }
                        }
                    }
                    (frame.ack, rest)
                }
            };
            if let Some(a) = ack {
                let mut wire = [0u8; 64];
                let n = a.encode(&mut wire).unwrap();
                back.bytes.extend_from_slice(&wire[..n]);
            }
            input = rest;
        }
    }
}

#[test]
fn the_tap_sees_every_voxel_handed_to_the_link() {
    let mut robot = Box::new(Robot::EMPTY);
    robot.configure(&setup(Resend::OFF)).unwrap();
    let (mut tapped, mut voxels) = (0.0f32, 0u32);
    let mut tap = |v: &Evicted<'_, D>| {
        tapped += v.obs.count;
        voxels += 1;
    };
    let mut out = Vec::new();
    for f in 0..8 {
        let (pose, points, features) = sensor_frame(f as f32 * 0.5);
        robot.integrate_tapped(&pose, &points, &features, &mut tap);
        robot.tick(&mut out, 2000).unwrap();
    }
    robot.drain_tapped(&mut out, &mut tap).unwrap();
    assert_eq!(tapped, 800.0);
    assert_eq!(voxels, robot.map().counters().evicted);
    assert!(robot.is_drained());
}

#[test]
fn live_updates_show_held_voxels_and_finals_carry_every_point() {
    let mut robot = Box::new(Robot::EMPTY);
    robot.configure(&setup(Resend::OFF)).unwrap();
    let mut station = Station::new();
    let mut back = BackChannel::default();
    // The robot stays put: nothing is evicted, so only live updates can show the map.
    for _ in 0..4 {
        let (pose, points, features) = sensor_frame(0.0);
        robot.integrate(&pose, &points, &features);
        let mut out = Vec::new();
        let r = robot.tick_live(&mut out, 2000, 400).unwrap();
        assert!(r.live_bytes <= 400, "{r:?}");
        station.receive(&out, &mut back);
    }
    assert_eq!(robot.encoder().stats().evicted_sent, 0);
    let held = robot.map().len() as u32;
    assert!(
        station.live_summaries >= held,
        "{} live summaries for {held} held voxels",
        station.live_summaries
    );
    // Nothing changed since: a quiet tick streams nothing.
    let mut out = Vec::new();
    while robot.map().changed_voxels(0).next().is_some() {
        robot.tick_live(&mut out, 2000, 400).unwrap();
    }
    let mut quiet = Vec::new();
    assert_eq!(robot.tick_live(&mut quiet, 2000, 400).unwrap().live_sent, 0);
    let mut out = Vec::new();
    robot.drain(&mut out).unwrap();
    station.receive(&out, &mut back);
    assert_eq!(station.final_points, 400.0);
}

/// A link of stored codes streams live updates too: each changed cold voxel's codes as the map holds
/// them (the base station's copy is the robot's voxel bit for bit), a hot voxel's new points once it has
/// cooled; statistics handed to such a session are skipped; the finals still carry every point once.
#[cfg(feature = "stored-codes")]
#[test]
fn a_stored_code_link_streams_cold_voxels_live_as_the_map_holds_them() {
    let mut robot = Box::new(Robot::EMPTY);
    let mut s = setup(Resend::OFF);
    s.codec = crate::wire::SummaryCodec::STORED;
    robot.configure(&s).unwrap();
    let mut station = Station::new();
    let mut back = BackChannel::default();
    let mut live_sent = 0;
    // 100 voxels in view (more than the hot tier holds), the robot standing still: four looks.
    let pose = Isometry3::identity();
    let points: Vec<[f32; 3]> = (0..100)
        .map(|i| {
            [
                0.1 * (i % 10) as f32 - 0.45,
                0.1 * (i / 10) as f32 - 0.45,
                0.05,
            ]
        })
        .collect();
    for f in 0..4 {
        let features: Vec<[f32; D]> = (0..100).map(|i| [(i + f) as f32 * 0.01 - 0.3; D]).collect();
        robot.integrate(&pose, &points, &features);
        let mut out = Vec::new();
        let r = robot.tick_live(&mut out, 2000, 600).unwrap();
        assert!(r.live_bytes <= 600, "{r:?}");
        live_sent += r.live_sent;
        station.receive(&out, &mut back);
    }
    assert!(live_sent > 0 && station.live_summaries > 0);
    for _ in 0..100 {
        if robot.map().changed_stored(0).next().is_none() {
            break;
        }
        let mut out = Vec::new();
        robot.tick_live(&mut out, 2000, 600).unwrap();
        station.receive(&out, &mut back);
    }
    assert!(robot.map().changed_stored(0).next().is_none());
    let mut quiet = Vec::new();
    assert_eq!(robot.tick_live(&mut quiet, 2000, 600).unwrap().live_sent, 0);
    let hot: Vec<_> = robot.map().hot_voxels().map(|v| v.key).collect();
    assert!(!hot.is_empty());
    let mut cold = 0;
    for v in robot.map().iter().filter(|v| !hot.contains(&v.key)) {
        let copy = station
            .live
            .iter()
            .find(|(k, _)| *k == v.key)
            .map(|(_, o)| o);
        assert_eq!(
            copy,
            Some(&v.obs),
            "cold voxel {:?}: the station's copy",
            v.key
        );
        cold += 1;
    }
    assert!(cold >= 50, "{cold} cold voxels held");
    // A statistics-only item cannot go in a session of stored codes: skipped, nothing written.
    let obs = crate::obs::ObsStats::<D> {
        count: 3.0,
        ..crate::obs::ObsStats::EMPTY
    };
    let item = crate::frame::live(crate::key::VoxelKey::new(1, 2, 3), &obs, 1);
    let mut out = Vec::new();
    let r = robot
        .encoder
        .tick_live(&mut out, 2000, 600, [item])
        .unwrap();
    assert_eq!((r.live_sent, r.live_bytes, out.len()), (1, 0, 0), "{r:?}");
    let mut out = Vec::new();
    robot.drain(&mut out).unwrap();
    station.receive(&out, &mut back);
    assert_eq!(station.final_points, 400.0);
}

#[test]
fn with_acknowledgements_nothing_is_lost_on_a_lossy_link() {
    let mut robot = Box::new(Robot::EMPTY);
    robot.configure(&setup(Resend::new(2048, 3))).unwrap();
    let mut station = Station::new();
    let mut back = BackChannel::default();
    let mut frames = 0u32;
    let mut deliver = |out: &[u8], station: &mut Station, back: &mut BackChannel| {
        // Every 4th frame is lost; garbage on the back channel is refused.
        for f in out.split(|&b| b == 0).filter(|f| !f.is_empty()) {
            frames += 1;
            if !frames.is_multiple_of(4) {
                station.receive(&[&[0], f, &[0]].concat(), back);
            }
        }
        back.bytes.extend_from_slice(&[0, 1, 2, 3, 0]);
    };
    for f in 0..12 {
        let (pose, points, features) = sensor_frame(f as f32 * 0.4);
        robot.integrate(&pose, &points, &features);
        let mut out = Vec::new();
        robot.tick_live(&mut out, 1500, 300).unwrap();
        deliver(&out, &mut station, &mut back);
        robot.poll_acks(&mut back).unwrap();
    }
    for _ in 0..200 {
        let mut out = Vec::new();
        let _ = robot.drain(&mut out); // Stuck while the re-send buffer waits for acknowledgements
        robot.tick(&mut out, 1500).unwrap();
        deliver(&out, &mut station, &mut back);
        robot.poll_acks(&mut back).unwrap();
        if robot.is_drained() {
            break;
        }
    }
    assert!(robot.is_drained(), "{:?}", robot.encoder().stats());
    assert_eq!(station.final_points, 1200.0, "every point exactly once");
    let s = robot.encoder().stats();
    assert!(s.resent > 0 && s.acked > 0, "{s:?}");
    assert!(s.bad_acks > 0 && robot.ack_stats().accepted > 0);
}

/// A UART that fails: the first `fail` writes it is asked for fail, each after passing on `cut` bytes of
/// the frame (0: nothing reaches the link; a frame's length − 1: all of it but its closing delimiter).
struct FailingUart {
    out: Vec<u8>,
    fail: u32,
    cut: usize,
}
impl embedded_io::ErrorType for FailingUart {
    type Error = embedded_io::ErrorKind;
}
impl embedded_io::Write for FailingUart {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        if self.fail > 0 {
            self.fail -= 1;
            let n = self.cut.min(buf.len().saturating_sub(1));
            self.out.extend_from_slice(&buf[..n]);
            return Err(embedded_io::ErrorKind::Other);
        }
        self.out.extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// A failed write consumes no sequence number: whatever part of a frame reached the link before the UART
/// failed (none, some, all but the last delimiter), the frame is written again byte for byte, the base
/// station counts 0 frames lost and gets every point once — with a back channel and without.
#[test]
fn a_uart_that_fails_n_times_costs_no_frame_and_no_point() {
    for resend in [Resend::OFF, Resend::new(2048, 3)] {
        for cut in [0usize, 1, 9, 10_000] {
            let mut robot = Box::new(Robot::EMPTY);
            robot.configure(&setup(resend)).unwrap();
            let mut station = Station::new();
            let mut back = BackChannel::default();
            let mut uart = FailingUart {
                out: Vec::new(),
                fail: 0,
                cut,
            };
            let mut failures = 0;
            for f in 0..12 {
                let (pose, points, features) = sensor_frame(f as f32 * 0.4);
                robot.integrate(&pose, &points, &features);
                // Every third tick the UART fails twice.
                if f % 3 == 1 {
                    uart.fail = 2;
                }
                if robot.tick_live(&mut uart, 1500, 300).is_err() {
                    failures += 1;
                }
                station.receive(&core::mem::take(&mut uart.out), &mut back);
                robot.poll_acks(&mut back).unwrap();
            }
            uart.fail = 3;
            for _ in 0..200 {
                if robot.drain_within(&mut uart, 700).is_err() {
                    failures += 1;
                }
                let _ = robot.tick(&mut uart, 1500);
                station.receive(&core::mem::take(&mut uart.out), &mut back);
                robot.poll_acks(&mut back).unwrap();
                if robot.is_drained() && !robot.encoder().has_pending() {
                    break;
                }
            }
            let what = (resend.is_on(), cut);
            assert!(failures >= 5, "{what:?}: {failures} failed ticks");
            assert!(robot.is_drained(), "{what:?}");
            assert_eq!(robot.encoder().stats().write_errors, 4 * 2 + 3, "{what:?}");
            assert_eq!(station.final_points, 1200.0, "{what:?}: every point once");
            let (_, seq) = station.sessions.iter().next().unwrap();
            assert_eq!(seq.lost, 0, "{what:?}: no frame counted lost");
            assert_eq!(
                seq.highest(),
                Some(robot.encoder().next_seq() - 1),
                "{what:?}"
            );
        }
    }
}

/// `drain_within` spends at most its budget per call, makes progress with any budget of a whole frame,
/// and ends with the link statistics; it sends the voxels one `drain` sends.
#[test]
fn drain_within_a_budget_sends_what_drain_sends() {
    let fill = |robot: &mut Robot| {
        robot.configure(&setup(Resend::OFF)).unwrap();
        for f in 0..6 {
            let (pose, points, features) = sensor_frame(f as f32);
            robot.integrate(&pose, &points, &features);
        }
    };
    let mut whole = Box::new(Robot::EMPTY);
    fill(&mut whole);
    let mut once = Vec::new();
    let evicted = whole.drain(&mut once).unwrap();
    assert!(evicted > 0);
    let mut steps = Box::new(Robot::EMPTY);
    fill(&mut steps);
    let mut out = Vec::new();
    let (mut calls, mut total) = (0, 0u32);
    loop {
        let before = out.len();
        let r = steps.drain_within(&mut out, 300).unwrap();
        assert!(r.bytes <= 300 && out.len() - before == r.bytes, "{r:?}");
        total += r.evicted;
        calls += 1;
        if r.done {
            break;
        }
        assert!(
            r.bytes > 0,
            "{r:?}: a whole frame's budget always sends one"
        );
    }
    assert!(calls > 3, "{calls} calls");
    // The same voxels (the frames may cut them differently: a budget stops a frame the queue would fill).
    assert_eq!(total, evicted);
    let (mut a, mut b) = (Station::new(), Station::new());
    a.receive(&once, &mut BackChannel::default());
    b.receive(&out, &mut BackChannel::default());
    assert_eq!(a.final_points, 600.0);
    assert_eq!(b.final_points, a.final_points);
    assert_eq!(b.rx.refusals(), a.rx.refusals());
    assert!(steps.is_drained());
    // Done stays done: nothing more is written.
    let r = steps.drain_within(&mut out, 300).unwrap();
    assert_eq!((r.done, r.bytes), (true, 0));
    // Too small a budget for any frame: nothing written, not done, not an error.
    let mut small = Box::new(Robot::EMPTY);
    fill(&mut small);
    let r = small.drain_within(&mut out, 20).unwrap();
    assert_eq!((r.done, r.bytes), (false, 0));
}
