//! The robot's `Mapper` over a faulty two-way link to a base station: with acknowledgements nothing is
//! lost — through byte errors, dropped, truncated, duplicated and delayed frames, and an outage of seconds
//! mid-run, after which the robot's queue recovers; without a back channel the run goes on as before and
//! the loss is counted.

mod stream_common;

use host_sim::base_station::BaseStation;
use host_sim::link::{ByteLog, Faults, FaultyWriter, Pipe, SplitMix};
use latentbki::frame::{EncoderSettings, Resend};
use latentbki::{sink::Evicted, Setup};
use stream_common::*;

/// Link time per tick (ms) and bytes per tick.
const TICK_MS: u64 = 100;
const BUDGET: usize = 6000;

struct Outcome {
    /// Points the robot handed to the link (tapped).
    sent: f64,
    /// Points in final contributions at the base station.
    settled: f64,
    /// Frames the base station never received.
    lost_frames: u32,
    /// Most frames unacknowledged at once, and at the end.
    peak_unacked: usize,
    unacked_at_end: usize,
    /// Ticks during which the robot's queue was full (voxels held in the map).
    refused: u32,
    resent: u32,
}

fn run(faults: Faults, back_channel: bool) -> Outcome {
    run_with(faults, back_channel, latentbki::wire::SummaryCodec::DEFAULT)
}

fn run_with(faults: Faults, back_channel: bool, codec: latentbki::wire::SummaryCodec) -> Outcome {
    let world = World::new(codec);
    let resend = if back_channel {
        Resend::new(8 * 1024, 5)
    } else {
        Resend::OFF
    };
    let setup = Setup {
        codec: world.config.codec,
        feature_space: world.config.feature_space,
        ..Setup::new(
            world.config.map_config().unwrap(),
            2.5,
            EncoderSettings::new(1, 77).with_resend(resend),
        )
    };
    let mut robot = Box::new(Robot::EMPTY);
    robot.configure(&setup).unwrap();
    let mut base = BaseStation::<D>::new(world.config).unwrap();
    let mut up = FaultyWriter::new(ByteLog::default(), faults, 11);
    let mut down = FaultyWriter::new(Pipe::default(), faults, 12);
    let mut rng = SplitMix::new(5);
    let mut sent = 0.0f64;
    let mut peak_unacked = 0;
    let mut carry =
        |robot: &mut Robot, base: &mut BaseStation<D>, up: &mut FaultyWriter<ByteLog>| {
            up.advance(TICK_MS).unwrap();
            base.receive(&std::mem::take(&mut up.inner().0));
            if back_channel {
                use embedded_io::Write;
                down.write_all(&base.take_acks()).unwrap();
                down.advance(TICK_MS).unwrap();
                robot.poll_acks(down.inner()).unwrap();
            }
        };
    // Out along a road and back: 90 scans, 9 s of link time.
    let xs: Vec<f32> = (0..60)
        .map(|i| 0.5 + 0.2 * i as f32)
        .chain((0..30).map(|i| 12.3 - 0.2 * i as f32))
        .collect();
    for x in xs {
        let (pose, pts, feats) = scan(&world, &mut rng, x, 0.0, 400, 1.6);
        robot.integrate_tapped(&pose, &pts, &feats, |v: &Evicted<'_, D>| {
            sent += f64::from(v.obs.count)
        });
        robot.tick_live(&mut up, BUDGET, 1500).unwrap();
        peak_unacked = peak_unacked.max(robot.encoder().unacknowledged());
        carry(&mut robot, &mut base, &mut up);
    }
    // Drain, then keep the link going until everything is acknowledged (or 60 s passed).
    let mut drained = false;
    for _ in 0..600 {
        if !drained {
            drained = robot
                .drain_tapped(&mut up, |v: &Evicted<'_, D>| sent += f64::from(v.obs.count))
                .is_ok();
        } else {
            robot.tick(&mut up, BUDGET).unwrap();
        }
        carry(&mut robot, &mut base, &mut up);
        if drained && (!back_channel || robot.is_drained()) {
            break;
        }
    }
    assert_eq!(robot.map().rejections().total(), 0, "no point refused");
    let map = base.map().unwrap();
    Outcome {
        sent,
        settled: map.voxels().map(|(_, v)| f64::from(v.settled.count)).sum(),
        lost_frames: base.stats().lost,
        peak_unacked,
        unacked_at_end: robot.encoder().unacknowledged(),
        refused: robot.map().counters().refused,
        resent: robot.encoder().stats().resent,
    }
}

#[test]
fn an_outage_of_seconds_mid_run_loses_nothing_and_the_queue_recovers() {
    // The link is down for 3 s of every 10 s: from 7 s to 10 s, while the robot maps.
    let faults = Faults::with_drops_and_delays(1e-4, 0.02, 300).with_outages(10_000, 3_000);
    let o = run(faults, true);
    assert!(o.sent > 30_000.0);
    assert_eq!(o.settled, o.sent, "every point arrives exactly once");
    assert_eq!(o.unacked_at_end, 0, "the re-send buffer drained");
    assert!(
        o.peak_unacked > 10,
        "frames waited through the outage: {}",
        o.peak_unacked
    );
    assert!(o.resent > 0);
    println!(
        "outage: {} points, {} re-sent frames, {} evictions held back, peak {} unacknowledged frames",
        o.sent, o.resent, o.refused, o.peak_unacked
    );
}

#[test]
fn a_harsh_link_loses_nothing_with_acknowledgements() {
    // Byte errors 1e-3 (and the drops and bursts they bring), 10 % of frames dropped, delays; the demo's
    // codec (protocol 4's lead band, counts growing the bits).
    let o = run_with(
        Faults::with_drops_and_delays(1e-3, 0.10, 300),
        true,
        host_sim::demo_radio::CODEC,
    );
    assert_eq!(o.settled, o.sent);
    assert_eq!(o.unacked_at_end, 0);
    assert!(o.resent > 20, "{}", o.resent);
}

#[test]
fn without_a_back_channel_the_loss_is_counted() {
    let o = run(Faults::with_drops_and_delays(1e-3, 0.10, 300), false);
    assert!(
        o.settled < o.sent,
        "a lossy link without re-sends loses points"
    );
    assert!(o.lost_frames > 10, "and the base station counts the frames");
    assert_eq!(o.resent, 0);
    assert_eq!(
        o.unacked_at_end, 0,
        "nothing is kept without a back channel"
    );
}
