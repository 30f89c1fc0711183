//! A fleet on one base station: four robots (the firmware's host twin, four self-test scenarios of one map
//! configuration in the same room, each its own robot id) stream at once to one `host-sim base-station` —
//! three over ptys (one through a lossy shim: bit errors, dropped frames, dropped acknowledgements), one
//! through a TCP gateway (`--listen`) that reconnects when the base station comes back — beside a pty that
//! carries only garbage and a TCP connection that never says a word. Midway the base station is SIGKILLed and
//! restarted on its database.
//!
//! Checked: at the kill every frame any robot was told is safe is in the database; at the end every point
//! arrived once, the garbage and the silent link were counted on their own lines without holding up the
//! others, and the database is bit for bit the map of the four robots' streams fed one after another —
//! in either order. Also: recordings given as inputs are the same as feeding them in turn, and
//! `map-merge` of two databases equals one database of both (and refuses maps of another configuration).

use host_sim::base_station::store::{MapStore, SqliteStore};
use host_sim::base_station::BaseStation;
use host_sim::link::SplitMix;
use latentbki::frame::{Ack, AckReader, Resend};
use latentbki::quant::packed_len;
use latentbki::Mapper;
use latentbki_selftest::{
    integrate_frame, Chunk, Scenario, SELF_TEST, SELF_TEST_CAPACITY, SELF_TEST_FRAME_BYTES,
    SELF_TEST_QUEUE_BYTES, SELF_TEST_RESEND_BYTES,
};
use serialport::{SerialPort, TTYPort};
use std::collections::BTreeSet;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Child, ChildStdout, Command, Stdio};
use std::time::{Duration, Instant};

use host_sim::sim::vocab::D;
type Robot =
    Mapper<D, SELF_TEST_CAPACITY, { packed_len(D) }, SELF_TEST_QUEUE_BYTES, SELF_TEST_FRAME_BYTES>;

const TICK: Duration = Duration::from_millis(15);

/// The four scenarios of one configuration (f = 3, f32 features): depth frames, the full map, the ToF and
/// the scanning LiDAR, all in the self-test's room.
fn scenarios() -> Vec<Scenario> {
    let names = ["depth_f3", "full_map", "tof_f3", "lidar_f3"];
    names
        .iter()
        .map(|n| *SELF_TEST.iter().find(|s| s.name == *n).unwrap())
        .collect()
}

/// The robot of scenario `i`: robot id 20 + i, a re-send timeout longer than a commit and a round trip.
fn robot(s: &Scenario, i: usize) -> Box<Robot> {
    let mut setup = s.setup().unwrap();
    setup.link.robot = 20 + i as u16;
    setup.link.resend = Resend::new(SELF_TEST_RESEND_BYTES as u32, 20);
    let mut r: Box<Robot> = Box::new(Robot::EMPTY);
    r.configure(&setup).unwrap();
    r
}

/// A robot's UART for one tick.
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

/// The whole stream a robot writes on a perfect line (every frame acknowledged at once): what the
/// reference base station is fed.
fn clean_stream(s: &Scenario, i: usize) -> Vec<u8> {
    let mut r = robot(s, i);
    let mut chunk = Box::new(Chunk::<D, 16>::ZERO);
    let mut out = Vec::new();
    let mut station = BaseStation::<D>::adopting();
    for f in 0..s.frames {
        integrate_frame(s.scene, f, 0.0, &mut r, &mut chunk, &mut ());
        let mut uart = Uart::default();
        r.tick(&mut uart, s.tick_budget).unwrap();
        station.receive(&uart.0);
        r.feed_acks(&station.take_acks());
        out.extend(uart.0);
    }
    loop {
        let mut uart = Uart::default();
        let done = match r.drain_within(&mut uart, s.tick_budget) {
            Ok(d) => d.done,
            Err(e) => panic!(
                "{e:?}: queued {}, map {}, unacked {}, pending {}, seq {}, {:?} station {:?}",
                r.encoder().queued(),
                r.map().len(),
                r.encoder().unacknowledged(),
                r.encoder().has_pending(),
                r.encoder().next_seq(),
                r.encoder().stats(),
                station.stats()
            ),
        };
        station.receive(&uart.0);
        r.feed_acks(&station.take_acks());
        out.extend(uart.0);
        if done && r.is_drained() {
            return out;
        }
    }
}

/// A lossy line: bit errors and whole frames dropped.
struct Shim {
    rng: SplitMix,
    ber: f64,
    drops: f64,
}

impl Shim {
    fn pass(&mut self, bytes: &[u8]) -> Vec<u8> {
        let mut out = Vec::with_capacity(bytes.len());
        for run in bytes.split_inclusive(|&b| b == 0) {
            if self.rng.unit() < self.drops {
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

/// How a robot reaches the base station.
enum Line {
    Pty(TTYPort),
    /// A gateway forwarding the robot's bytes over TCP (reconnecting when the base station comes back).
    Tcp(Option<TcpStream>),
}

struct Rig {
    scenario: Scenario,
    robot: Box<Robot>,
    chunk: Box<Chunk<D, 16>>,
    line: Line,
    shim: Option<(Shim, Shim)>,
    frame: u32,
    done: bool,
    acked: BTreeSet<u32>,
    sent: Vec<u8>,
    id: (u16, u32),
}

impl Rig {
    /// One tick: a sensor frame (or a drain step), the bytes through the line, acknowledgements back.
    fn step(&mut self, port: Option<u16>) {
        let mut uart = Uart::default();
        if self.frame < self.scenario.frames {
            integrate_frame(
                self.scenario.scene,
                self.frame,
                0.0,
                &mut self.robot,
                &mut self.chunk,
                &mut (),
            );
            self.frame += 1;
            self.robot
                .tick(&mut uart, self.scenario.tick_budget)
                .unwrap();
        } else {
            self.done = self
                .robot
                .drain_within(&mut uart, self.scenario.tick_budget)
                .is_ok_and(|r| r.done);
            self.robot
                .tick(&mut uart, self.scenario.tick_budget)
                .unwrap();
        }
        self.sent.extend_from_slice(&uart.0);
        let up = match &mut self.shim {
            Some((up, _)) => up.pass(&uart.0),
            None => uart.0,
        };
        let mut back = Vec::new();
        let mut buf = [0u8; 4096];
        match &mut self.line {
            Line::Pty(p) => {
                let _ = p.write_all(&up);
                while let Ok(n) = p.read(&mut buf) {
                    if n == 0 {
                        break;
                    }
                    back.extend_from_slice(&buf[..n]);
                    if p.bytes_to_read().unwrap_or(0) == 0 {
                        break;
                    }
                }
            }
            Line::Tcp(conn) => {
                if conn.is_none() {
                    *conn = port.and_then(|p| TcpStream::connect(("127.0.0.1", p)).ok());
                    if let Some(c) = conn {
                        c.set_nonblocking(true).unwrap();
                    }
                }
                if let Some(c) = conn {
                    let mut dead = write_all_nonblocking(c, &up).is_err();
                    loop {
                        match c.read(&mut buf) {
                            Ok(0) => {
                                dead = true;
                                break;
                            }
                            Ok(n) => back.extend_from_slice(&buf[..n]),
                            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => break,
                            Err(_) => {
                                dead = true;
                                break;
                            }
                        }
                    }
                    if dead {
                        *conn = None;
                    }
                }
            }
        }
        let back = match &mut self.shim {
            Some((_, down)) => down.pass(&back),
            None => back,
        };
        let (robot, session) = self.id;
        let acked = &mut self.acked;
        AckReader::new().feed(&back, robot, session, |a: Ack| {
            for i in 0..64u32 {
                if a.received >> i & 1 == 1 && a.highest >= i {
                    acked.insert(a.highest - i);
                }
            }
        });
        self.robot.feed_acks(&back);
    }

    fn finished(&self) -> bool {
        self.done && self.robot.is_drained()
    }
}

fn write_all_nonblocking(c: &mut TcpStream, mut bytes: &[u8]) -> std::io::Result<()> {
    let deadline = Instant::now() + Duration::from_millis(50);
    while !bytes.is_empty() {
        match c.write(bytes) {
            Ok(0) => return Err(std::io::ErrorKind::WriteZero.into()),
            Ok(n) => bytes = &bytes[n..],
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock && Instant::now() < deadline => {
                std::thread::sleep(Duration::from_millis(1))
            }
            Err(e) => return Err(e),
        }
    }
    Ok(())
}

/// The base station on these ptys, listening on a free TCP port; returns it, the port and its stdout.
fn start(ports: &[String], db: &Path) -> (Child, u16, BufReader<ChildStdout>) {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_host-sim"));
    cmd.args([
        "base-station",
        "--commit-ms",
        "20",
        "--listen=127.0.0.1:0",
        "--map",
    ])
    .arg(db);
    for p in ports {
        cmd.args(["--serial", p]);
    }
    let mut child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut out = BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    let port = loop {
        line.clear();
        assert!(
            out.read_line(&mut line).unwrap() > 0,
            "the base station ended"
        );
        if let Some(a) = line.trim().strip_prefix("listening on tcp ") {
            break a
                .split(' ')
                .next()
                .unwrap()
                .rsplit(':')
                .next()
                .unwrap()
                .parse()
                .unwrap();
        }
    };
    (child, port, out)
}

fn stored(db: &Path) -> BaseStation<D> {
    let mut store = SqliteStore::open_read_only(db).unwrap();
    BaseStation::<D>::restore(store.snapshot().unwrap()).unwrap()
}

fn assert_durable(db: &Path, rigs: &[Rig]) {
    let base = stored(db);
    for r in rigs {
        let Some(st) = base.sessions().get(&r.id) else {
            assert!(
                r.acked.is_empty(),
                "{:?}: acknowledged, nothing stored",
                r.id
            );
            continue;
        };
        let h = st.seq.highest().unwrap();
        for &s in &r.acked {
            assert!(
                s <= h && (h - s >= 64 || st.seq.window() >> (h - s) & 1 == 1),
                "{:?}: frame {s} acknowledged but not stored",
                r.id
            );
        }
    }
}

/// The reference: a base station fed whole streams one after another.
fn fed(streams: &[&[u8]]) -> BaseStation<D> {
    let mut b = BaseStation::<D>::adopting();
    for s in streams {
        b.receive(s);
    }
    b
}

#[test]
fn four_robots_on_ptys_and_a_gateway_merge_into_one_database_through_a_kill() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("fleet.db");
    let scenarios = scenarios();
    let mut ports = Vec::new();
    let mut rigs = Vec::new();
    for (i, s) in scenarios.iter().enumerate() {
        let line = if i == 3 {
            Line::Tcp(None)
        } else {
            let (mut master, slave) = TTYPort::pair().unwrap();
            ports.push(slave.name().unwrap());
            drop(slave);
            master.set_timeout(Duration::from_millis(1)).unwrap();
            Line::Pty(master)
        };
        let shim = (i == 1).then(|| {
            (
                Shim {
                    rng: SplitMix::new(11),
                    ber: 2e-5,
                    drops: 0.05,
                },
                Shim {
                    rng: SplitMix::new(12),
                    ber: 2e-5,
                    drops: 0.1,
                },
            )
        });
        rigs.push(Rig {
            scenario: *s,
            robot: robot(s, i),
            chunk: Box::new(Chunk::ZERO),
            line,
            shim,
            frame: 0,
            done: false,
            acked: BTreeSet::new(),
            sent: Vec::new(),
            id: (20 + i as u16, s.session),
        });
    }
    // A pty that carries only garbage, and a TCP connection that never says a word.
    let (mut garbage, g_slave) = TTYPort::pair().unwrap();
    ports.push(g_slave.name().unwrap());
    drop(g_slave);
    garbage.set_timeout(Duration::from_millis(1)).unwrap();
    let mut noise = SplitMix::new(99);

    let (mut station, mut port, mut report) = start(&ports, &db);
    let _silent = TcpStream::connect(("127.0.0.1", port)).unwrap();
    let deadline = Instant::now() + Duration::from_secs(180);
    let mut tick = 0u32;
    while !rigs.iter().all(Rig::finished) {
        assert!(Instant::now() < deadline, "not drained after 180 s");
        let t = Instant::now();
        for r in &mut rigs {
            r.step(Some(port));
        }
        let junk: Vec<u8> = (0..512).map(|_| noise.below(256) as u8).collect();
        let _ = garbage.write_all(&junk);
        let mut sink = [0u8; 1024];
        let _ = garbage.read(&mut sink);
        tick += 1;
        if tick == 60 {
            station.kill().unwrap();
            station.wait().unwrap();
            let mut rest = String::new();
            let _ = report.read_to_string(&mut rest);
            assert!(rigs.iter().map(|r| r.acked.len()).sum::<usize>() > 20);
            assert_durable(&db, &rigs);
        }
        if tick == 75 {
            (station, port, report) = start(&ports, &db);
        }
        std::thread::sleep(TICK.saturating_sub(t.elapsed()));
    }
    let ok = Command::new("kill")
        .args(["-TERM", &station.id().to_string()])
        .status()
        .unwrap();
    assert!(ok.success());
    let mut stdout = String::new();
    report.read_to_string(&mut stdout).unwrap();
    let out = station.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    eprintln!("{stdout}");
    // Each link on its own line; the garbage pty's refusals are its own.
    let garbage_line = stdout
        .lines()
        .find(|l| l.starts_with("link ") && l.contains(ports.last().unwrap().as_str()))
        .unwrap();
    assert!(
        garbage_line.contains(" 0 frames applied") && !garbage_line.contains("refused: 0 damaged"),
        "{garbage_line}"
    );

    let db_map = stored(&db);
    let map = db_map.map().unwrap();
    let points: f64 = map.voxels().map(|(_, v)| f64::from(v.settled.count)).sum();
    let integrated: u32 = rigs.iter().map(|r| r.robot.map().counters().points).sum();
    assert_eq!(points, f64::from(integrated), "every point once");
    for r in &rigs {
        assert_eq!(db_map.sessions()[&r.id].seq.lost, 0, "{:?}", r.id);
    }
    // Bit for bit the map of the four streams fed one after another, in either order.
    let streams: Vec<&[u8]> = rigs.iter().map(|r| r.sent.as_slice()).collect();
    let forward = fed(&streams);
    assert!(
        map == forward.map().unwrap(),
        "the database differs from the streams fed in turn"
    );
    let backward: Vec<&[u8]> = streams.iter().rev().copied().collect();
    assert!(
        map == fed(&backward).map().unwrap(),
        "the merge depends on the order"
    );
}

/// `base-station X.bin Y.bin --map db` equals feeding X.bin then Y.bin; `map-merge` of two databases equals
/// one database of both, bit for bit, and refuses maps of another configuration with one line.
#[test]
fn recordings_fed_in_turn_and_merged_databases_give_one_map() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let scenarios = scenarios();
    let (x, y) = (d.join("x.bin"), d.join("y.bin"));
    let sx = clean_stream(&scenarios[0], 0);
    let sy = clean_stream(&scenarios[2], 2);
    std::fs::write(&x, &sx).unwrap();
    std::fs::write(&y, &sy).unwrap();
    let run = |args: &[&std::ffi::OsStr]| {
        let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
            .args(args)
            .output()
            .unwrap();
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stdout).into_owned(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let both = d.join("both.db");
    let (code, o, e) = run(&[
        "base-station".as_ref(),
        x.as_ref(),
        y.as_ref(),
        "--map".as_ref(),
        both.as_ref(),
    ]);
    assert_eq!(code, Some(0), "{o}\n{e}");
    let reference = fed(&[&sx, &sy]);
    assert!(stored(&both).map().unwrap() == reference.map().unwrap());
    assert_eq!(stored(&both).sessions(), reference.sessions());

    let (a, b, c) = (d.join("a.db"), d.join("b.db"), d.join("c.db"));
    for (input, db) in [(&x, &a), (&y, &b)] {
        let (code, o, e) = run(&[
            "base-station".as_ref(),
            input.as_ref(),
            "--map".as_ref(),
            db.as_ref(),
        ]);
        assert_eq!(code, Some(0), "{o}\n{e}");
    }
    let (code, o, e) = run(&[
        "map-merge".as_ref(),
        a.as_ref(),
        b.as_ref(),
        "--out".as_ref(),
        c.as_ref(),
    ]);
    assert_eq!(code, Some(0), "{o}\n{e}");
    let merged = stored(&c);
    assert!(
        merged.map().unwrap() == reference.map().unwrap(),
        "map-merge is not the map of both"
    );
    assert_eq!(merged.sessions(), reference.sessions());
    // The merged database continues either stream: a re-sent copy is a duplicate, not a second merge.
    let mut cont = BaseStation::<D>::open(&mut SqliteStore::open(&c).unwrap()).unwrap();
    cont.receive(&sx);
    assert!(cont.map().unwrap() == reference.map().unwrap());

    // Another configuration (f = 1): refused with one line naming the difference.
    let other = d.join("other.db");
    let z = d.join("z.bin");
    std::fs::write(&z, clean_stream(&SELF_TEST[0], 9)).unwrap();
    let (code, o, e) = run(&[
        "base-station".as_ref(),
        z.as_ref(),
        "--map".as_ref(),
        other.as_ref(),
    ]);
    assert_eq!(code, Some(0), "{o}\n{e}");
    let (code, _, e) = run(&[
        "map-merge".as_ref(),
        a.as_ref(),
        other.as_ref(),
        "--out".as_ref(),
        d.join("no.db").as_ref(),
    ]);
    assert_ne!(code, Some(0));
    assert_eq!(e.trim().lines().count(), 1, "{e}");
    assert!(
        e.contains("cannot be merged") && e.contains("filter sizes (3 and 1)"),
        "{e}"
    );
    assert!(!d.join("no.db").exists());
}
