//! The lossless link on a real serial line, end to end: the robot (the QEMU firmware's host twin: the
//! self-test's ToF scenario on the firmware's own `Mapper`, its sizes and seeds) writes its frames into a
//! pty; a lossy shim in the middle flips bits, drops frames and cuts the line for an outage, both ways; on
//! the pty's other end `host-sim base-station --serial <pty> --map <db>` — the program a user deploys —
//! applies them and acknowledges on the same line what its database holds. Midway it is SIGKILLed and
//! restarted on the same database.
//!
//! Checked: at the kill, every frame the robot was told is safe is in the database; at the end every point
//! the robot integrated is in the database once, and the database's map is bit for bit the map a base
//! station builds from a clean copy of everything the robot wrote (the same frames, whatever order and
//! how many copies the line delivered).

use host_sim::base_station::store::{MapStore, SqliteStore};
use host_sim::base_station::BaseStation;
use host_sim::link::SplitMix;
use latentbki::frame::{Ack, AckReader, Resend};
use latentbki::quant::packed_len;
use latentbki::Mapper;
use latentbki_selftest::{
    integrate_frame, Chunk, SELF_TEST, SELF_TEST_CAPACITY, SELF_TEST_FRAME_BYTES,
    SELF_TEST_QUEUE_BYTES, SELF_TEST_ROBOT,
};
use serialport::{SerialPort, TTYPort};
use std::collections::BTreeSet;
use std::io::{Read, Write};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use host_sim::sim::vocab::D;
type Robot =
    Mapper<D, SELF_TEST_CAPACITY, { packed_len(D) }, SELF_TEST_QUEUE_BYTES, SELF_TEST_FRAME_BYTES>;

/// Wall-clock length of one robot tick.
const TICK: Duration = Duration::from_millis(15);

fn base_station(port: &str, db: &Path) -> Child {
    Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args([
            "base-station",
            "--serial",
            port,
            "--commit-ms",
            "20",
            "--map",
        ])
        .arg(db)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// The lossy line: bit errors, whole frames dropped, and an outage while `cut` is set.
struct Shim {
    rng: SplitMix,
    ber: f64,
    frame_drops: f64,
    cut: bool,
}

impl Shim {
    fn pass(&mut self, bytes: &[u8]) -> Vec<u8> {
        if self.cut {
            return Vec::new();
        }
        let mut out = Vec::with_capacity(bytes.len());
        // Frames are runs between 0x00 delimiters; drop some whole, damage others.
        for run in bytes.split_inclusive(|&b| b == 0) {
            if self.rng.unit() < self.frame_drops {
                out.push(0);
                continue;
            }
            for &b in run {
                let mut b = b;
                for bit in 0..8 {
                    if self.rng.unit() < self.ber {
                        b ^= 1 << bit;
                    }
                }
                out.push(b);
            }
        }
        out
    }
}

/// Bytes read from the line, handed to the robot a few at a time.
#[derive(Default)]
struct Inbox {
    bytes: Vec<u8>,
    at: usize,
}
impl embedded_io::ErrorType for Inbox {
    type Error = core::convert::Infallible;
}
impl embedded_io::Read for Inbox {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let n = buf.len().min(self.bytes.len() - self.at);
        buf[..n].copy_from_slice(&self.bytes[self.at..self.at + n]);
        self.at += n;
        Ok(n)
    }
}
impl embedded_io::ReadReady for Inbox {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(self.at < self.bytes.len())
    }
}

/// What the robot wrote in one tick (its UART), kept whole for the reference.
#[derive(Default)]
struct Uart(Vec<u8>);
impl embedded_io::ErrorType for Uart {
    type Error = core::convert::Infallible;
}
impl embedded_io::Write for Uart {
    fn write(&mut self, b: &[u8]) -> Result<usize, Self::Error> {
        self.0.extend_from_slice(b);
        Ok(b.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// The robot, the line and what passed over it.
struct Rig {
    robot: Box<Robot>,
    master: TTYPort,
    up: Shim,
    down: Shim,
    inbox: Inbox,
    /// Every byte the robot wrote, as written (the reference's input).
    sent: Vec<u8>,
    /// Sequence numbers the robot was told are safe (acknowledgements it accepted).
    acked: BTreeSet<u32>,
    session: u32,
}

impl Rig {
    /// Write the robot's bytes through the shim into the pty (what the line cannot take now is lost, as on
    /// a UART whose receiver is gone), then read the acknowledgements back through the shim.
    fn exchange(&mut self, uart: Uart) {
        self.sent.extend_from_slice(&uart.0);
        let out = self.up.pass(&uart.0);
        let _ = self.master.write_all(&out);
        let mut buf = [0u8; 4096];
        let mut back = Vec::new();
        while let Ok(n) = self.master.read(&mut buf) {
            if n == 0 {
                break;
            }
            back.extend_from_slice(&buf[..n]);
            if self.master.bytes_to_read().unwrap_or(0) == 0 {
                break;
            }
        }
        let back = self.down.pass(&back);
        // What the robot will accept: its own session's acknowledgements that check out.
        let (robot, session) = (SELF_TEST_ROBOT, self.session);
        let mut reader = AckReader::new();
        let acked = &mut self.acked;
        reader.feed(&back, robot, session, |a: Ack| {
            for i in 0..64u32 {
                if a.received >> i & 1 == 1 && a.highest >= i {
                    acked.insert(a.highest - i);
                }
            }
        });
        self.inbox.bytes.extend_from_slice(&back);
        self.robot.poll_acks(&mut self.inbox).unwrap();
    }
}

/// Every frame the robot was told is safe is in the database: its session's stored sequence state has it.
fn assert_acked_frames_are_durable(db: &Path, robot: u16, session: u32, acked: &BTreeSet<u32>) {
    let mut store = SqliteStore::open_read_only(db).unwrap();
    let base = BaseStation::<D>::restore(store.snapshot().unwrap()).unwrap();
    let Some(state) = base.sessions().get(&(robot, session)) else {
        assert!(acked.is_empty(), "acknowledged {acked:?}, nothing stored");
        return;
    };
    let highest = state.seq.highest().unwrap();
    for &s in acked {
        assert!(
            s <= highest,
            "frame {s} acknowledged, stored up to {highest}"
        );
        let back = highest - s;
        assert!(
            back >= 64 || state.seq.window() >> back & 1 == 1,
            "frame {s} acknowledged but not stored (highest {highest})"
        );
    }
}

#[test]
fn a_robot_on_a_lossy_pty_loses_nothing_through_a_base_station_killed_midway() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("global.db");
    let (mut master, slave) = TTYPort::pair().unwrap();
    let port = slave.name().unwrap();
    // The base station opens the pty itself (exclusively): the test keeps only the master.
    drop(slave);
    master.set_timeout(Duration::from_millis(1)).unwrap();

    let scenario = SELF_TEST[0]; // the 8×8 ToF, 144 frames
    let mut setup = scenario.setup().unwrap();
    // A re-send timeout longer than a commit and a round trip on this line (ticks of 15 ms).
    setup.link.resend = Resend::new(latentbki_selftest::SELF_TEST_RESEND_BYTES as u32, 20);
    let mut robot: Box<Robot> = Box::new(Robot::EMPTY);
    robot.configure(&setup).unwrap();
    let mut chunk = Box::new(Chunk::<D, 16>::ZERO);
    let mut rig = Rig {
        robot,
        master,
        up: Shim {
            rng: SplitMix::new(1),
            ber: 2e-5,
            frame_drops: 0.05,
            cut: false,
        },
        down: Shim {
            rng: SplitMix::new(2),
            ber: 2e-5,
            frame_drops: 0.1,
            cut: false,
        },
        inbox: Inbox::default(),
        sent: Vec::new(),
        acked: BTreeSet::new(),
        session: scenario.session,
    };

    let mut station = base_station(&port, &db);
    std::thread::sleep(Duration::from_millis(300));
    let mut killed_at = None;
    for frame in 0..scenario.frames {
        let t = Instant::now();
        integrate_frame(
            scenario.scene,
            frame,
            0.0,
            &mut rig.robot,
            &mut chunk,
            &mut (),
        );
        let mut uart = Uart::default();
        rig.robot.tick(&mut uart, scenario.tick_budget).unwrap();
        rig.exchange(uart);
        // An outage of the line, both ways.
        rig.up.cut = (40..55).contains(&frame);
        rig.down.cut = rig.up.cut;
        if frame == 80 {
            // SIGKILL: no commit, no goodbye.
            station.kill().unwrap();
            station.wait().unwrap();
            killed_at = Some(rig.acked.len());
            assert!(
                rig.acked.len() > 10,
                "{} frames acknowledged",
                rig.acked.len()
            );
            assert_acked_frames_are_durable(&db, SELF_TEST_ROBOT, rig.session, &rig.acked);
        }
        if frame == 95 {
            station = base_station(&port, &db);
        }
        std::thread::sleep(TICK.saturating_sub(t.elapsed()));
    }
    // Drain in budgeted steps, reading acknowledgements, until everything is acknowledged.
    let deadline = Instant::now() + Duration::from_secs(120);
    let mut done = false;
    while !(done && rig.robot.is_drained()) {
        assert!(
            Instant::now() < deadline,
            "not drained: {:?}",
            rig.robot.encoder().stats()
        );
        let t = Instant::now();
        let mut uart = Uart::default();
        done = rig
            .robot
            .drain_within(&mut uart, scenario.tick_budget)
            .is_ok_and(|r| r.done);
        rig.robot.tick(&mut uart, scenario.tick_budget).unwrap();
        rig.exchange(uart);
        std::thread::sleep(TICK.saturating_sub(t.elapsed()));
    }
    assert!(rig.acked.len() > killed_at.unwrap());
    // The base station is stopped cleanly and reports.
    unsafe_free_sigterm(&station);
    let out = station.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("acknowledgements written"), "{stdout}");

    // Every point the robot integrated is in the database, once.
    let mut store = SqliteStore::open_read_only(&db).unwrap();
    let stored = BaseStation::<D>::restore(store.snapshot().unwrap()).unwrap();
    let map = stored.map().unwrap();
    let points: f64 = map.voxels().map(|(_, v)| f64::from(v.settled.count)).sum();
    assert_eq!(points, f64::from(rig.robot.map().counters().points));
    assert!(map.voxels().all(|(_, v)| v.live.is_empty()));
    // And it is the map of a clean copy of everything the robot wrote, bit for bit.
    let mut reference = BaseStation::<D>::adopting();
    reference.receive(&rig.sent);
    assert_eq!(reference.stats().lost, 0);
    assert!(
        map == reference.map().unwrap(),
        "the database differs from the robot's stream"
    );
    let s = rig.robot.encoder().stats();
    eprintln!(
        "robot: {} frames, {} re-sent, {} acknowledged ({} before the kill), {} bad acknowledgements; {} points\n{stdout}",
        s.frames_sent, s.resent, rig.acked.len(), killed_at.unwrap(), s.bad_acks, points
    );
    assert!(s.resent > 0, "{s:?}");
    let st = stored.sessions()[&(SELF_TEST_ROBOT, rig.session)];
    assert_eq!(st.seq.lost, 0, "{st:?}");
}

/// SIGTERM (the base station commits, prints its summary and exits 0).
fn unsafe_free_sigterm(child: &Child) {
    let ok = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap()
        .success();
    assert!(ok);
}

/// `base-station --help` says where acknowledgements go and when.
#[test]
fn base_station_help_names_the_acknowledgements() {
    let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(["base-station", "--help"])
        .output()
        .unwrap();
    let help = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success());
    for wanted in [
        "Acknowledgements",
        "--serial",
        "--listen",
        "--stdio",
        "durable",
        "--no-acks",
    ] {
        assert!(help.contains(wanted), "`{wanted}` not in\n{help}");
    }
}
