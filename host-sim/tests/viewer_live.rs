//! `base-station --view` and `demo --view` end to end, on loopback only: a robot stream goes in on stdin
//! (or the demo's robot maps the tile) while independent clients watch.
//!
//! - The npm client `@foxglove/ws-protocol` (`host-sim/station/viewer-test/check.js`, pinned by its
//!   lockfile) joins early (before the second half of the stream) and late (after all of it), decodes with
//!   the advertised schemas, and checks the voxels and classes against `map-info` / `map-query`, each
//!   cube's colour against the legend, and the heat layer's top voxels against `map-query --query` after
//!   setting the phrase itself. The late one (and both of the demo's) offer only the classic subprotocol
//!   name `foxglove.websocket.v1`, as clients older than Lichtblick v1.22 do.
//! - PyPI's `mcap` reader (`viewer-test/check_mcap.py`) checks the `--record` file and a `map-query --mcap`
//!   export the same way, and that a reader seeking to any time rebuilds that time's whole scene.
//! - `demo --view --record`: classes in their colours with a legend naming them, the heat of a phrase the
//!   client sets, the final map served after the run until SIGINT (a client that connects then gets it
//!   whole), and a recording that seeks.
//! - A raw socket sends garbage, an unknown subscription and an oversized frame: refused and counted,
//!   ingest unaffected. A client that subscribes and never reads leaves the database exactly as without it.
//!
//! Without node's packages (or Python's `mcap`) a check fails with the one line that installs them
//! (`cargo xtask setup`, which the README's test command runs first): never a silent pass.

mod stream_common;

use host_sim::base_station::store::SqliteStore;
use host_sim::base_station::{BaseStation, GlobalMap};
use host_sim::link::SplitMix;
use latentbki::wire::SummaryCodec;
use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::time::Duration;
use stream_common::*;

const PHRASE: &str = "road";
const TOP: usize = 5;

fn exe() -> &'static str {
    env!("CARGO_BIN_EXE_host-sim")
}

fn viewer_test_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("station/viewer-test")
}

fn required(what: &str) -> bool {
    panic!("{what} is missing: run `cargo xtask setup`");
}

fn node_ready() -> bool {
    let dir = viewer_test_dir();
    let ok = Command::new("node").arg("--version").output().is_ok()
        && dir.join("node_modules/@foxglove/ws-protocol").exists();
    ok || required("node with host-sim/station/viewer-test's packages (npm ci)")
}

fn python() -> String {
    std::env::var("LATENTBKI_VIEWER_PYTHON").unwrap_or_else(|_| "python3".into())
}

fn mcap_ready() -> bool {
    let ok = Command::new(python())
        .args(["-c", "import mcap, mcap_protobuf"])
        .output()
        .is_ok_and(|o| o.status.success());
    ok || required("Python's mcap and mcap-protobuf-support")
}

/// Two robots' streams, one after the other.
fn robot_stream(seed: u64, frames: usize) -> Vec<u8> {
    let world = World::new(SummaryCodec::DEFAULT);
    let mut out = Vec::new();
    for robot in [4, 9] {
        let mut rig = RobotRig::new(&world, robot, 2.5);
        let mut rng = SplitMix::new(seed + u64::from(robot));
        for i in 0..frames {
            let (pose, pts, feats) = scan(&world, &mut rng, 1.0 + 0.5 * i as f32, 0.5, 300, 1.6);
            rig.step(&pose, &pts, &feats, 8192);
        }
        rig.finish();
        out.extend_from_slice(&rig.uart.0);
    }
    out
}

struct Station {
    child: Child,
    stdin: Option<ChildStdin>,
    port: u16,
    stdout: BufReader<std::process::ChildStdout>,
}

fn start_station(db: &Path, pca: &Path, extra: &[&std::ffi::OsStr]) -> Station {
    let mut child = Command::new(exe())
        .args([
            "base-station",
            "-",
            "--view",
            "127.0.0.1:0",
            "--commit-ms",
            "20",
        ])
        .arg("--map")
        .arg(db)
        .arg("--pca")
        .arg(pca)
        .args(extra)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdout = BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    let port = loop {
        line.clear();
        assert!(stdout.read_line(&mut line).unwrap() > 0, "no serving line");
        if let Some(rest) = line.trim().strip_prefix("viewer: serving ws://127.0.0.1:") {
            break rest.split_whitespace().next().unwrap().parse().unwrap();
        }
    };
    Station {
        stdin: child.stdin.take(),
        child,
        port,
        stdout,
    }
}

impl Station {
    fn feed(&mut self, bytes: &[u8]) {
        self.stdin.as_mut().unwrap().write_all(bytes).unwrap();
        self.stdin.as_mut().unwrap().flush().unwrap();
    }
    /// Close stdin: the station commits, prints its summary and exits.
    fn finish(mut self) -> String {
        drop(self.stdin.take());
        let mut rest = String::new();
        self.stdout.read_to_string(&mut rest).unwrap();
        assert!(self.child.wait().unwrap().success(), "{rest}");
        rest
    }
}

fn stored(path: &Path) -> GlobalMap<D> {
    let mut store = SqliteStore::open_read_only(path).unwrap();
    BaseStation::<D>::open(&mut store)
        .unwrap()
        .into_map()
        .unwrap()
}

fn run(args: &[&std::ffi::OsStr]) -> String {
    let out = Command::new(exe()).args(args).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    text
}

/// Wait until the database holds `n` observed voxels' worth of a finished stream (map-info's count stops
/// changing between two reads 300 ms apart).
fn settled_count(db: &Path) -> usize {
    let count = || {
        let text = run(&["map-info".as_ref(), db.as_os_str()]);
        text.lines()
            .find_map(|l| l.strip_prefix("observed voxels "))
            .and_then(|l| l.split(';').next())
            .and_then(|n| n.trim().parse::<usize>().ok())
            .unwrap_or(0)
    };
    let mut last = usize::MAX;
    for _ in 0..100 {
        let n = count();
        if n == last && n > 0 {
            return n;
        }
        last = n;
        std::thread::sleep(Duration::from_millis(300));
    }
    panic!("the database never settled")
}

/// What `map-info` and `map-query` say of the database, as the clients' expectations (JSON).
fn expectations(db: &Path, pca: &Path, dir: &Path) -> String {
    let count = settled_count(db);
    let ply = dir.join("map.ply");
    let p = |x: &Path| x.as_os_str().to_owned();
    let listing = run(&[
        "map-query".as_ref(),
        &p(db),
        "--pca".as_ref(),
        &p(pca),
        "--ply".as_ref(),
        &p(&ply),
        "--query".as_ref(),
        PHRASE.as_ref(),
        "--top".as_ref(),
        TOP.to_string().as_ref(),
    ]);
    let map = stored(db);
    let voxel = map.map_config().voxel_size();
    let key_of = |x: f32, y: f32, z: f32| {
        let k = |v: f32| (v / voxel).floor() as i32;
        format!("{} {} {}", k(x), k(y), k(z))
    };
    // Per-voxel classes: the PLY's label at each observed voxel.
    let text = std::fs::read_to_string(&ply).unwrap();
    let body = text.split("end_header\n").nth(1).unwrap();
    let mut ply_labels = BTreeMap::new();
    for line in body.lines() {
        let f: Vec<&str> = line.split_whitespace().collect();
        let xyz: Vec<f32> = f[..3].iter().map(|v| v.parse().unwrap()).collect();
        ply_labels.insert(key_of(xyz[0], xyz[1], xyz[2]), f[6].parse::<i64>().unwrap());
    }
    let classes: BTreeMap<String, i64> = map
        .sorted_keys()
        .iter()
        .map(|k| {
            let key = format!("{} {} {}", k.x, k.y, k.z);
            let label = ply_labels[&key];
            (key, label)
        })
        .collect();
    // Per-class counts and the query's top voxels, as map-query prints them.
    let class_counts: Vec<usize> = listing
        .lines()
        .filter(|l| l.starts_with("  ") && l.ends_with(" voxels"))
        .map(|l| {
            l.rsplit(": ")
                .next()
                .unwrap()
                .trim_end_matches(" voxels")
                .parse()
                .unwrap()
        })
        .collect();
    let top_keys: Vec<String> = listing
        .lines()
        .filter_map(|l| l.split(" at (").nth(1))
        .map(|l| {
            let v: Vec<f32> = l
                .trim_end_matches(") m")
                .split(", ")
                .map(|x| x.parse().unwrap())
                .collect();
            key_of(v[0], v[1], v[2])
        })
        .collect();
    assert_eq!(count, map.len());
    assert_eq!(class_counts.iter().sum::<usize>(), count, "{listing}");
    assert_eq!(top_keys.len(), TOP, "{listing}");
    let json = |v: &dyn std::fmt::Debug| format!("{v:?}");
    format!(
        "{{\"count\": {count}, \"phrase\": \"{PHRASE}\", \"class_counts\": {}, \"top_keys\": {}, \"classes\": {{{}}}}}",
        json(&class_counts),
        json(&top_keys),
        classes
            .iter()
            .map(|(k, v)| format!("\"{k}\": {v}"))
            .collect::<Vec<_>>()
            .join(", ")
    )
}

/// The classic name of the protocol (the only one clients older than Lichtblick v1.22 offer).
const CLASSIC: &str = "foxglove.websocket.v1";

fn node_check(port: u16, expect: &Path, name: &str, subprotocol: &str) -> Child {
    Command::new("node")
        .arg(viewer_test_dir().join("check.js"))
        .args(["--url", &format!("ws://127.0.0.1:{port}"), "--name", name])
        .args(["--subprotocol", subprotocol])
        .arg("--expect")
        .arg(expect)
        .args(["--timeout", "300"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

fn passed(child: Child) -> String {
    let out = child.wait_with_output().unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "{text}");
    text
}

fn mcap_check(file: &Path, expect: &Path) -> String {
    python_check(&[file.as_os_str(), expect.as_os_str()])
}

/// A reader that seeks to any time of the file rebuilds that time's whole scene.
fn mcap_seek_check(file: &Path) -> String {
    python_check(&["--seek".as_ref(), file.as_os_str()])
}

fn python_check(args: &[&std::ffi::OsStr]) -> String {
    let out = Command::new(python())
        .arg(viewer_test_dir().join("check_mcap.py"))
        .args(args)
        .output()
        .unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "{text}");
    text
}

#[test]
fn live_view_matches_map_query_for_early_and_late_clients_and_recordings_replay() {
    let node = node_ready();
    let dir = tempfile::tempdir().unwrap();
    let pca = dir.path().join("pca.npz");
    host_sim::npy_io::write_pca_npz(&pca, &World::new(SummaryCodec::DEFAULT).pca).unwrap();
    let db = dir.path().join("map.db");
    let rec = dir.path().join("live.mcap");
    let expect = dir.path().join("expect.json");
    let stream = robot_stream(11, 10);
    let mut station = start_station(&db, &pca, &["--record".as_ref(), rec.as_os_str()]);
    let half = stream.len() / 2;
    station.feed(&stream[..half]);
    let early = node.then(|| node_check(station.port, &expect, "early", "foxglove.sdk.v1"));
    station.feed(&stream[half..]);
    let json = expectations(&db, &pca, dir.path());
    std::fs::write(&expect, json).unwrap();
    if let Some(early) = early {
        println!("{}", passed(early));
        // Joins after the whole stream is in: only the full scene on subscription can satisfy it.
        println!(
            "{}",
            passed(node_check(station.port, &expect, "late", CLASSIC))
        );
    }
    let summary = station.finish();
    println!("{summary}");
    let line = summary
        .lines()
        .find(|l| l.starts_with("viewer: ") && l.contains(" voxels in the scene"))
        .unwrap();
    let n: usize = line["viewer: ".len()..]
        .split(' ')
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert_eq!(n, stored(&db).len(), "{line}");
    assert!(
        summary.contains("viewer: frame arrival to view update: median"),
        "{summary}"
    );
    if mcap_ready() {
        // The live recording's heat layer follows the phrase the viewer client set: without the client,
        // only the export (phrase given on the command line) can be checked.
        if node {
            println!("{}", mcap_check(&rec, &expect));
        }
        println!("{}", mcap_seek_check(&rec));
        let export = dir.path().join("export.mcap");
        let p = |x: &Path| x.as_os_str().to_owned();
        let out = run(&[
            "map-query".as_ref(),
            &p(&db),
            "--pca".as_ref(),
            &p(&pca),
            "--query".as_ref(),
            PHRASE.as_ref(),
            "--mcap".as_ref(),
            &p(&export),
        ]);
        assert!(out.contains("voxels in the scene"), "{out}");
        println!("{}", mcap_check(&export, &expect));
    }
}

/// A WebSocket client by hand: the handshake, then masked frames of any opcode and length.
fn raw_client(port: u16) -> TcpStream {
    raw_client_offering(port, "foxglove.sdk.v1").0
}

/// The handshake offering `protocols`; the socket and the reply's head.
fn raw_client_offering(port: u16, protocols: &str) -> (TcpStream, String) {
    let mut s = TcpStream::connect(("127.0.0.1", port)).unwrap();
    write!(
        s,
        "GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
         Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\
         Sec-WebSocket-Protocol: {protocols}\r\n\r\n"
    )
    .unwrap();
    let mut head = Vec::new();
    let mut b = [0u8; 1];
    while !head.ends_with(b"\r\n\r\n") {
        s.read_exact(&mut b).unwrap();
        head.push(b[0]);
    }
    let head = String::from_utf8_lossy(&head).into_owned();
    assert!(head.starts_with("HTTP/1.1 101"), "{head}");
    (s, head)
}

/// The protocol the server accepted, from a reply's head.
fn accepted(head: &str) -> Option<&str> {
    head.lines().find_map(|l| {
        let (k, v) = l.split_once(':')?;
        k.eq_ignore_ascii_case("sec-websocket-protocol")
            .then_some(v.trim())
    })
}

/// Read one unmasked server frame's payload (text or binary; no fragmentation).
fn read_frame(s: &mut TcpStream) -> Vec<u8> {
    let mut h = [0u8; 2];
    s.read_exact(&mut h).unwrap();
    let len = match h[1] & 0x7f {
        126 => {
            let mut l = [0u8; 2];
            s.read_exact(&mut l).unwrap();
            u64::from(u16::from_be_bytes(l))
        }
        127 => {
            let mut l = [0u8; 8];
            s.read_exact(&mut l).unwrap();
            u64::from_be_bytes(l)
        }
        n => u64::from(n),
    };
    let mut payload = vec![0u8; len as usize];
    s.read_exact(&mut payload).unwrap();
    payload
}

/// One masked frame header (and payload if given; the mask is zero, which leaves the payload as is).
fn frame(opcode: u8, len: u64, payload: &[u8]) -> Vec<u8> {
    let mut f = vec![0x80 | opcode];
    match len {
        0..=125 => f.push(0x80 | len as u8),
        126..=0xffff => {
            f.push(0x80 | 126);
            f.extend_from_slice(&(len as u16).to_be_bytes());
        }
        _ => {
            f.push(0x80 | 127);
            f.extend_from_slice(&len.to_be_bytes());
        }
    }
    f.extend_from_slice(&[0; 4]);
    f.extend_from_slice(payload);
    f
}

fn rss_kib(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("VmHWM:"))
                .and_then(|v| v.trim().trim_end_matches(" kB").trim().parse().ok())
        })
        .unwrap_or(0)
}

#[test]
fn bad_and_stalled_clients_are_refused_or_ignored_and_ingest_is_unchanged() {
    let dir = tempfile::tempdir().unwrap();
    let pca = dir.path().join("pca.npz");
    host_sim::npy_io::write_pca_npz(&pca, &World::new(SummaryCodec::DEFAULT).pca).unwrap();
    let stream = robot_stream(5, 14);
    // Without any client: the reference database.
    let quiet_db = dir.path().join("quiet.db");
    let mut quiet = start_station(&quiet_db, &pca, &[]);
    quiet.feed(&stream);
    std::thread::sleep(Duration::from_millis(500));
    let quiet_rss = rss_kib(quiet.child.id());
    let quiet_out = quiet.finish();
    // With a client that subscribes to everything and never reads, and one that sends garbage.
    let busy_db = dir.path().join("busy.db");
    let mut busy = start_station(&busy_db, &pca, &["--view-backlog".as_ref(), "8".as_ref()]);
    let mut stalled = raw_client(busy.port);
    let subscribe = (1..=6)
        .map(|i| format!("{{\"id\":{i},\"channelId\":{i}}}"))
        .collect::<Vec<_>>()
        .join(",");
    let sub = format!("{{\"op\":\"subscribe\",\"subscriptions\":[{subscribe}]}}");
    stalled
        .write_all(&frame(1, sub.len() as u64, sub.as_bytes()))
        .unwrap();
    let mut bad = raw_client(busy.port);
    for text in [
        "this is not json",
        "{\"op\":\"nonsense\"}",
        "{\"op\":\"subscribe\",\"subscriptions\":[{\"id\":1,\"channelId\":4242}]}",
    ] {
        bad.write_all(&frame(1, text.len() as u64, text.as_bytes()))
            .unwrap();
    }
    // A frame announcing 64 MiB: refused from its header, the connection closed.
    let mut big = raw_client(busy.port);
    big.write_all(&frame(2, 64 << 20, &[0; 1024])).unwrap();
    busy.feed(&stream);
    std::thread::sleep(Duration::from_millis(500));
    let busy_rss = rss_kib(busy.child.id());
    let busy_out = busy.finish();
    drop((stalled, bad, big));
    println!(
        "quiet: {quiet_out}\nbusy: {busy_out}\npeak RSS quiet {quiet_rss} KiB, busy {busy_rss} KiB"
    );
    // The database is the same map, bit for bit, with or without those clients.
    assert!(stored(&quiet_db) == stored(&busy_db));
    let refused: u64 = busy_out
        .lines()
        .find_map(|l| l.strip_prefix("viewer: client messages refused "))
        .unwrap()
        .trim()
        .parse()
        .unwrap();
    assert!(
        refused >= 4,
        "garbage, unknown op, unknown channel, oversized: {busy_out}"
    );
    // The stalled client's queue is bounded (8 messages): memory stays near the quiet run's.
    assert!(
        busy_rss < quiet_rss + 64 * 1024,
        "peak RSS {busy_rss} KiB with a stalled client, {quiet_rss} KiB without"
    );
}

#[test]
fn every_name_of_the_protocol_is_accepted_and_unknown_ones_refused() {
    let dir = tempfile::tempdir().unwrap();
    let pca = dir.path().join("pca.npz");
    host_sim::npy_io::write_pca_npz(&pca, &World::new(SummaryCodec::DEFAULT).pca).unwrap();
    let db = dir.path().join("map.db");
    let mut station = start_station(&db, &pca, &[]);
    for (offer, want) in [
        (CLASSIC, CLASSIC),
        ("foxglove.sdk.v1", "foxglove.sdk.v1"),
        ("foxglove.sdk.v1.1", "foxglove.sdk.v1.1"),
        ("chat, foxglove.websocket.v1", CLASSIC),
        ("foxglove.websocket.v1, foxglove.sdk.v1", "foxglove.sdk.v1"),
    ] {
        let (mut s, head) = raw_client_offering(station.port, offer);
        assert_eq!(accepted(&head), Some(want), "offered {offer}: {head}");
        // The protocol itself follows: the server's first message is its serverInfo.
        let first = String::from_utf8(read_frame(&mut s)).unwrap();
        assert!(
            first.contains("\"op\":\"serverInfo\""),
            "offered {offer}: {first}"
        );
    }
    // No name the server knows: refused at the handshake, as the SDK refuses it.
    let mut s = TcpStream::connect(("127.0.0.1", station.port)).unwrap();
    write!(
        s,
        "GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
         Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\
         Sec-WebSocket-Protocol: chat\r\n\r\n"
    )
    .unwrap();
    let mut reply = String::new();
    let _ = s.read_to_string(&mut reply);
    assert!(reply.starts_with("HTTP/1.1 400"), "{reply}");
    station.feed(&robot_stream(3, 2));
    station.finish();
}

/// A PCA of another feature space than the robots' decodes nothing in the view, and its legend says why
/// (the classes would be meaningless); the base station refuses it at the end as `map-query` does.
#[test]
fn a_pca_of_another_feature_space_decodes_nothing_and_the_legend_says_why() {
    if !mcap_ready() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let mut other = World::new(SummaryCodec::DEFAULT).pca;
    other.mean[0] += 0.5;
    let pca = dir.path().join("other.npz");
    host_sim::npy_io::write_pca_npz(&pca, &other).unwrap();
    let rec = dir.path().join("rec.mcap");
    let db = dir.path().join("map.db");
    let mut station = start_station(&db, &pca, &["--record".as_ref(), rec.as_os_str()]);
    station.feed(&robot_stream(3, 4));
    drop(station.stdin.take());
    let mut rest = String::new();
    station.stdout.read_to_string(&mut rest).unwrap();
    assert!(!station.child.wait().unwrap().success(), "{rest}");
    let out = python_check(&["--legend".as_ref(), rec.as_os_str()]);
    println!("{out}");
    assert!(
        out.contains("\"error\": \"the PCA's feature space") && out.contains("is not the robots'"),
        "{out}"
    );
    // Every cube grey (unclassified): nothing decoded with the wrong PCA.
    assert!(out.trim().ends_with("\"colours\": [\"#808080\"]}"), "{out}");
}

/// `demo --view --record`: the final map in colour to clients offering only the classic protocol name,
/// served after the run until SIGINT, and a recording that seeks.
#[test]
fn demo_view_is_in_colour_for_classic_clients_stays_up_and_its_recording_seeks() {
    let node = node_ready();
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("demo.mcap");
    let expect = dir.path().join("expect.json");
    let mut child = Command::new(exe())
        .args(["demo", "--view", "127.0.0.1:0", "--view-hz", "5", "--out"])
        .arg(dir.path().join("out"))
        .arg("--record")
        .arg(&rec)
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdout = BufReader::new(child.stdout.take().unwrap());
    let mut printed = String::new();
    let mut next_line = |printed: &mut String| {
        let mut line = String::new();
        assert!(
            stdout.read_line(&mut line).unwrap() > 0,
            "the demo ended early:\n{printed}"
        );
        printed.push_str(&line);
        line
    };
    let port: u16 = loop {
        let line = next_line(&mut printed);
        if let Some(rest) = line.trim().strip_prefix("viewer: serving ws://127.0.0.1:") {
            break rest.split_whitespace().next().unwrap().parse().unwrap();
        }
    };
    // Connected while the robot maps: it must end with the same whole scene as one that joins after.
    let early = node.then(|| node_check(port, &expect, "demo-early", CLASSIC));
    let voxels: usize = loop {
        let line = next_line(&mut printed);
        if let Some(rest) = line.trim().strip_prefix("viewer: recorded ") {
            let n = rest.rsplit("last scene ").next().unwrap();
            break n.trim_end_matches(" voxels").parse().unwrap();
        }
    };
    let serving = next_line(&mut printed);
    assert!(
        serving
            .starts_with("viewer: the run is over; still serving the final map at ws://127.0.0.1:")
            && serving.contains("until interrupted"),
        "{serving}"
    );
    assert!(voxels > 1000, "{printed}");
    // A phrase the demo does not start with (it starts on its pictured query, "house").
    std::fs::write(
        &expect,
        format!("{{\"count\": {voxels}, \"phrase\": \"tree\"}}"),
    )
    .unwrap();
    if let Some(early) = early {
        println!("{}", passed(early));
        // Joins after the run: the whole final scene from the subscription alone.
        println!(
            "{}",
            passed(node_check(port, &expect, "demo-late", CLASSIC))
        );
    }
    // Still serving: a classic handshake is answered after the run too.
    let (mut s, head) = raw_client_offering(port, CLASSIC);
    assert_eq!(accepted(&head), Some(CLASSIC));
    assert!(String::from_utf8(read_frame(&mut s))
        .unwrap()
        .contains("serverInfo"));
    drop(s);
    let kill = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(kill.success());
    let mut rest = String::new();
    stdout.read_to_string(&mut rest).unwrap();
    assert!(child.wait().unwrap().success(), "{printed}{rest}");
    println!("{printed}{rest}");
    assert!(rest.contains("viewer: interrupted: stopping"), "{rest}");
    assert!(
        rest.contains(&format!("viewer: {voxels} voxels in the scene")),
        "{rest}"
    );
    if node {
        assert!(
            rest.contains("viewer: query phrase to heat layer: median"),
            "{rest}"
        );
    }
    if mcap_ready() {
        println!("{}", mcap_seek_check(&rec));
    }
}

#[test]
#[ignore = "writes a sample stream and PCA to $VIEWER_SAMPLE_DIR for manual runs"]
fn write_sample() {
    let dir = PathBuf::from(std::env::var("VIEWER_SAMPLE_DIR").unwrap());
    host_sim::npy_io::write_pca_npz(&dir.join("pca.npz"), &World::new(SummaryCodec::DEFAULT).pca)
        .unwrap();
    std::fs::write(dir.join("robot.bin"), robot_stream(11, 10)).unwrap();
}
