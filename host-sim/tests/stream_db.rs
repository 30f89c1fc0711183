//! The base station's map database: exact round trip, damaged input writes nothing, clear errors for
//! foreign or incompatible files, and — with the base station as a child process — SIGKILL at random points
//! loses at most the last commit interval and merges every frame exactly once; SIGTERM keeps everything
//! received; readers get consistent snapshots while the receiver writes.

mod stream_common;

use host_sim::base_station::store::{SqliteStore, StoreError};
use host_sim::base_station::{BaseStation, RestoreError};
use host_sim::link::{ByteLog, SplitMix};
use latentbki::frame::EncoderSettings;
use latentbki::wire::SummaryCodec;
use latentbki::{key::VoxelKey, obs::ObsStats, sink::Evicted, sink::EvictionSink};
use std::io::Write;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use stream_common::*;

/// One robot's recorded stream: `scans` scans along a street, some voxels left live at the end.
fn stream(scans: usize, seed: u64) -> Vec<u8> {
    let world = World::new(SummaryCodec::DEFAULT);
    let mut robot = RobotRig::new(&world, 4, 2.5);
    let mut rng = SplitMix::new(seed);
    for i in 0..scans {
        let (pose, pts, feats) = scan(&world, &mut rng, 1.0 + 0.4 * i as f32, 0.5, 300, 1.6);
        robot.step(&pose, &pts, &feats, 6000);
    }
    robot.tick(1 << 20);
    robot.uart.0
}

/// The stream cut after each 0x00 delimiter: whole frames (and lone delimiters), in order.
fn pieces(bytes: &[u8]) -> Vec<&[u8]> {
    bytes.split_inclusive(|&b| b == 0).collect()
}

fn restore(path: &Path) -> BaseStation<D> {
    let mut store = SqliteStore::open_read_only(path).unwrap();
    assert_eq!(store.integrity_check().unwrap(), "ok");
    BaseStation::open(&mut store).unwrap()
}

/// Same map and same sessions (sequence state included).
fn assert_same(a: &BaseStation<D>, b: &BaseStation<D>, what: &str) {
    assert!(a.map() == b.map(), "{what}: the maps differ");
    assert_eq!(a.sessions(), b.sessions(), "{what}: the sessions differ");
}

#[test]
fn database_round_trip_is_exact_and_damaged_bytes_write_nothing() {
    let world = World::new(SummaryCodec::DEFAULT);
    let bytes = stream(10, 5);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("global.db");
    // Damage: flipped bits inside frames (CRC), junk between frames, a frame cut short.
    let mut rng = SplitMix::new(1);
    let mut damaged = Vec::new();
    let mut clean = Vec::new();
    for (i, p) in pieces(&bytes).into_iter().enumerate() {
        if i % 7 == 3 && p.len() > 8 {
            let mut bad = p.to_vec();
            let at = 1 + rng.below(p.len() - 2);
            bad[at] ^= 1 << rng.below(8);
            if bad[at] == 0 {
                bad[at] = 0x55;
            }
            damaged.extend_from_slice(&bad);
        } else if i % 11 == 5 {
            damaged.extend_from_slice(&p[..p.len() / 2]);
            damaged.push(0);
        } else {
            damaged.extend_from_slice(p);
            clean.extend_from_slice(p);
        }
        if i % 5 == 0 {
            damaged.extend_from_slice(b"\x13\x37junk\xff\x00");
        }
    }
    let mut store = SqliteStore::open(&path).unwrap();
    let mut base = BaseStation::<D>::open(&mut store).unwrap();
    // Commit after every chunk: the most commits, the most chances to write a damaged frame.
    let mut at = 0;
    while at < damaged.len() {
        let n = (1 + rng.below(900)).min(damaged.len() - at);
        base.receive(&damaged[at..at + n]);
        base.commit(&mut store).unwrap();
        at += n;
    }
    let s = base.stats();
    assert!(s.decoder.crc_errors > 10, "{s:?}");
    let mut reference = BaseStation::<D>::adopting();
    reference.receive(&clean);
    assert_same(
        &restore(&path),
        &reference,
        "damaged stream vs its intact frames",
    );
    assert!(
        reference
            .map()
            .unwrap()
            .voxels()
            .any(|(_, v)| !v.live.is_empty()),
        "live contributions are kept too"
    );
    // Queries answer identically after the round trip.
    let (m, r) = (restore(&path), reference.map().unwrap());
    let m = m.map().unwrap();
    for k in r.sorted_keys() {
        assert_eq!(m.label(&k, &world.vocab), r.label(&k, &world.vocab));
        assert_eq!(m.uncertainty(&k), r.uncertainty(&k));
    }
    drop(store);

    // The same frames again after a restart: recognised, nothing merged, nothing written changes.
    let mut store = SqliteStore::open(&path).unwrap();
    let mut again = BaseStation::<D>::open(&mut store).unwrap();
    again.receive(&clean);
    let s = again.stats();
    assert!(s.merged == 0 && s.updated == 0, "{s:?}");
    again.commit(&mut store).unwrap();
    assert!(restore(&path).map() == reference.map());
    drop(store);

    // One writer at a time (readers any number); the lock goes with the store.
    let writer = SqliteStore::open(&path).unwrap();
    let err = SqliteStore::open(&path).err().unwrap();
    assert!(matches!(err, StoreError::InUse(_)), "{err}");
    assert!(err.to_string().contains("another base station is writing"));
    assert!(SqliteStore::open_read_only(&path).is_ok());
    drop(writer);
    drop(SqliteStore::open(&path).unwrap());
    // A lock its holder lets go of a moment later (as a spawned child's copy of the descriptor does at
    // its `exec`) is waited for, not reported as another writer.
    let briefly = SqliteStore::open(&path).unwrap();
    let releaser = std::thread::spawn(move || {
        std::thread::sleep(std::time::Duration::from_millis(20));
        drop(briefly);
    });
    drop(SqliteStore::open(&path).expect("the lock released within the wait is taken"));
    releaser.join().unwrap();

    // Foreign files, other versions and dimensions: clear errors.
    let junk = dir.path().join("junk.db");
    std::fs::write(
        &junk,
        b"this is not a database, it is a text file of some length ........",
    )
    .unwrap();
    let err = SqliteStore::open(&junk).err().unwrap().to_string();
    assert!(
        err.contains("junk.db") && err.contains("not a database"),
        "{err}"
    );
    let other = dir.path().join("other.db");
    rusqlite::Connection::open(&other)
        .unwrap()
        .execute_batch("CREATE TABLE t (a)")
        .unwrap();
    let err = SqliteStore::open(&other).err().unwrap();
    assert!(matches!(err, StoreError::NotAMap(_)), "{err}");
    assert!(err.to_string().contains("not a latentbki map database"));
    let newer = dir.path().join("newer.db");
    std::fs::copy(&path, &newer).unwrap();
    rusqlite::Connection::open(&newer)
        .unwrap()
        .execute("UPDATE schema_version SET version = 99", [])
        .unwrap();
    for err in [
        SqliteStore::open(&newer).err().unwrap(),
        SqliteStore::open_read_only(&newer).err().unwrap(),
    ] {
        assert!(
            matches!(err, StoreError::Version { found: 99, .. }),
            "{err}"
        );
        assert!(err
            .to_string()
            .contains("schema version 99 is not supported"));
    }
    let err = BaseStation::<32>::open(&mut SqliteStore::open(&path).unwrap())
        .err()
        .unwrap();
    assert!(
        matches!(
            err,
            RestoreError::Dimension {
                found: 64,
                expected: 32
            }
        ),
        "{err}"
    );
    // A damaged voxel record is refused, not loaded.
    let broken = dir.path().join("broken.db");
    std::fs::copy(&path, &broken).unwrap();
    rusqlite::Connection::open(&broken)
        .unwrap()
        .execute(
            &format!(
                "UPDATE voxels SET record = x'{:02x}02' WHERE (x, y, z) = (SELECT x, y, z FROM voxels LIMIT 1)",
                host_sim::base_station::global_map::VOXEL_RECORD_VERSION
            ),
            [],
        )
        .unwrap();
    let err = BaseStation::<D>::open(&mut SqliteStore::open(&broken).unwrap())
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("voxel record") && err.contains("malformed"),
        "{err}"
    );
    let err = SqliteStore::open_read_only(&dir.path().join("nope.db"))
        .err()
        .unwrap()
        .to_string();
    assert!(err.contains("nope.db"), "{err}");
}

#[test]
fn values_the_codec_clamps_are_counted() {
    let world = World::new(SummaryCodec::DEFAULT);
    let mut encoder = Box::new(Encoder::new(world.config, EncoderSettings::new(1, 1)).unwrap());
    let mut uart = ByteLog::default();
    let stats = |m: f32, p: f32| ObsStats::<D> {
        count: 4.0,
        mean: core::array::from_fn(|i| if i % 2 == 0 { m } else { -m }),
        scatter: [p; D],
    };
    // Huge mean (scale ≫ 6e4), huge Ψ (≫ 9.6e5), both, and an ordinary voxel.
    let voxels = [
        stats(1e6, 1.0),
        stats(0.5, 1e8),
        stats(1e6, 1e8),
        stats(0.5, 2.0),
    ];
    for (i, s) in voxels.iter().enumerate() {
        encoder
            .evict(Evicted {
                key: VoxelKey::new(i as i32, 0, 0),
                obs: s,
                residency: i as u32,
                time: 0,
            })
            .unwrap();
    }
    encoder
        .tick(&mut uart, usize::MAX, core::iter::empty())
        .unwrap();
    let mut base = BaseStation::<D>::new(world.config).unwrap();
    base.receive(&uart.0);
    let s = base.stats();
    assert_eq!(
        (s.merged, s.clamped_mean_scale, s.clamped_psi),
        (4, 2, 2),
        "{s:?}"
    );
}

/// The `host-sim` binary as a base station on stdin, writing `db`.
fn spawn_station(db: &Path, commit_ms: u64) -> Child {
    Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args([
            "base-station",
            "-",
            "--commit-ms",
            &commit_ms.to_string(),
            "--map",
        ])
        .arg(db)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

fn signal(child: &Child, sig: &str) {
    let ok = Command::new("kill")
        .args([sig, &child.id().to_string()])
        .status()
        .unwrap()
        .success();
    assert!(ok, "kill {sig}");
}

#[test]
fn sigkill_at_random_points_loses_at_most_the_last_commit_interval_and_merges_once() {
    const COMMIT_MS: u64 = 100;
    let bytes = stream(24, 11);
    let all = pieces(&bytes);
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("global.db");
    let mut rng = SplitMix::new(42);
    // The in-process twin of what the database holds: fed, run by run, exactly the pieces each child
    // committed; `merged` lists the stream's pieces it took, in order.
    let mut twin = BaseStation::<D>::adopting();
    twin.keep_journal();
    let mut at = 0usize; // next piece of the stream
    let kills = 4;
    for run in 0..kills {
        // The restart re-sends a few frames from before the cut (a robot that resends): already merged ones
        // must be recognised, lost ones are new.
        let from = at.saturating_sub(rng.below(4));
        let span = (all.len() - from) / (kills + 1 - run);
        let pause_at = (from + 1 + rng.below(span.max(1))).min(all.len() - 2);
        let kill_at = (pause_at + rng.below(30)).min(all.len() - 1);
        let cut = rng.below(all[kill_at].len()); // bytes of the piece at the kill point already sent
        let mut child = spawn_station(&db, COMMIT_MS);
        let mut stdin = child.stdin.take().unwrap();
        let mut delivered: Vec<Vec<u8>> = Vec::new();
        for p in &all[from..pause_at] {
            stdin.write_all(p).unwrap();
            delivered.push(p.to_vec());
        }
        stdin.flush().unwrap();
        // Longer than a commit interval: everything above must be committed before the kill.
        std::thread::sleep(Duration::from_millis(COMMIT_MS * 3 + 1200));
        // Up to the last whole frame (a lone delimiter after it changes nothing to commit).
        let must_have = delivered
            .iter()
            .rposition(|p| seq_of(p).is_some())
            .map_or(0, |i| i + 1);
        for p in &all[pause_at..kill_at] {
            stdin.write_all(p).unwrap();
            delivered.push(p.to_vec());
        }
        stdin.write_all(&all[kill_at][..cut]).unwrap();
        delivered.push(all[kill_at][..cut].to_vec());
        stdin.flush().unwrap();
        signal(&child, "-KILL");
        child.wait().unwrap();
        drop(stdin);
        // The database after the crash: the twin fed the shortest prefix of this run's pieces whose
        // sequence state matches; that prefix includes everything sent before the pause, and the maps agree.
        let stored = restore(&db);
        let mut committed = 0;
        while twin.sessions() != stored.sessions() {
            assert!(
                committed < delivered.len(),
                "run {run}: the database holds no prefix of what was sent"
            );
            twin.receive(&delivered[committed]);
            committed += 1;
        }
        assert!(
            committed >= must_have,
            "run {run}: only {committed} of the {must_have} pieces sent a commit interval before the kill were committed"
        );
        assert_same(&stored, &twin, &format!("run {run} after SIGKILL"));
        // The child's decoder state died with it; the twin's is at a frame boundary (every committed piece
        // ends with a delimiter, except a cut one, which a delimiter closes here as the next run's first
        // whole piece would).
        if committed > 0 && delivered[committed - 1].last() != Some(&0) {
            twin.receive(&[0]);
        }
        at = kill_at + usize::from(cut > 0);
    }
    // The last run gets the rest and ends cleanly.
    let mut child = spawn_station(&db, COMMIT_MS);
    let mut stdin = child.stdin.take().unwrap();
    for p in &all[at..] {
        stdin.write_all(p).unwrap();
    }
    drop(stdin);
    let out = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("continuing"), "{stdout}");
    for p in &all[at..] {
        twin.receive(p);
    }
    let fin = restore(&db);
    assert_same(&fin, &twin, "final");

    // Against the uninterrupted run: only frames counted lost are missing, and none is merged twice — the
    // database equals a base station fed each frame the twin accepted exactly once, in stream order.
    let mut whole = BaseStation::<D>::adopting();
    whole.receive(&bytes);
    let (f, w) = (fin.sessions(), whole.sessions());
    assert_eq!(f.len(), 1);
    let (fs, ws) = (
        f.values().next().unwrap().seq,
        w.values().next().unwrap().seq,
    );
    assert_eq!(ws.lost, 0);
    assert_eq!(fs.highest(), ws.highest());
    let accepted: Vec<u32> = twin.journal().iter().map(|e| e.seq).collect();
    assert!(
        accepted.windows(2).all(|w| w[0] < w[1]),
        "accepted once each, in order"
    );
    let taken: std::collections::HashSet<u32> = accepted.iter().copied().collect();
    let mut once = BaseStation::<D>::adopting();
    let mut missing = 0;
    for p in &all {
        match seq_of(p) {
            Some(seq) if !taken.contains(&seq) => missing += 1,
            _ => once.receive(p),
        }
    }
    assert_eq!(
        missing, fs.lost,
        "every frame missing from the map is counted lost"
    );
    assert_eq!(ws.received - fs.received, fs.lost);
    assert!(once.map() == fin.map(), "each frame merged exactly once");
    println!(
        "{kills} SIGKILLs: {} of {} frames lost in the crash windows",
        fs.lost, ws.received
    );
}

/// Sequence number of a frame piece (None for a lone delimiter or a non-frame).
fn seq_of(piece: &[u8]) -> Option<u32> {
    let mut d = latentbki::frame::FrameDecoder::<4096>::new();
    match d.feed(piece) {
        latentbki::frame::Feed::Frame { body, .. } => {
            latentbki::wire::parse_body(body).ok().map(|(h, _)| h.seq)
        }
        _ => None,
    }
}

#[test]
fn sigterm_commits_everything_received() {
    let bytes = stream(10, 3);
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("global.db");
    // A commit interval far longer than the test: only the signal can commit.
    let mut child = spawn_station(&db, 3_600_000);
    let mut stdin = child.stdin.take().unwrap();
    stdin.write_all(&bytes).unwrap();
    stdin.flush().unwrap();
    std::thread::sleep(Duration::from_millis(1500));
    signal(&child, "-TERM");
    let out = child.wait_with_output().unwrap();
    drop(stdin);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("stopped by a signal") && stdout.contains("frames lost 0"),
        "{stdout}"
    );
    // What it says it accepted (all of it, unless the machine was too slow to read the pipe in 1.5 s) is
    // what the database holds: the stream's prefix of that many frames.
    let accepted: u32 = stdout
        .split("frames accepted ")
        .nth(1)
        .and_then(|t| t.split(';').next())
        .and_then(|n| n.parse().ok())
        .unwrap();
    let stored = restore(&db);
    let mut twin = BaseStation::<D>::adopting();
    let mut pieces = pieces(&bytes).into_iter();
    while twin.stats().frames < accepted {
        twin.receive(pieces.next().unwrap());
    }
    assert_same(&stored, &twin, "after SIGTERM");
    let mut whole = BaseStation::<D>::adopting();
    whole.receive(&bytes);
    println!(
        "SIGTERM: {accepted} of {} frames received, all in the database",
        whole.stats().frames
    );
    assert!(
        accepted > whole.stats().frames / 2,
        "the child read too little to test anything"
    );
}

#[test]
fn readers_get_consistent_snapshots_while_the_receiver_writes() {
    let bytes = stream(16, 8);
    let all = pieces(&bytes);
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("global.db");
    let mut child = spawn_station(&db, 50);
    let mut stdin = child.stdin.take().unwrap();
    let writer = std::thread::spawn({
        let all: Vec<Vec<u8>> = all.iter().map(|p| p.to_vec()).collect();
        move || {
            for chunk in all.chunks(4) {
                for p in chunk {
                    stdin.write_all(p).unwrap();
                }
                stdin.flush().unwrap();
                std::thread::sleep(Duration::from_millis(30));
            }
        }
    });
    // Snapshots while it runs: each equals the stream's prefix up to the frame its sequence state says.
    let mut twin = BaseStation::<D>::adopting();
    let mut fed = 0;
    let mut checked = 0;
    let start = Instant::now();
    let mut cli_ran = false;
    while child.try_wait().unwrap().is_none() && start.elapsed() < Duration::from_secs(120) {
        std::thread::sleep(Duration::from_millis(10));
        let Ok(mut store) = SqliteStore::open_read_only(&db) else {
            continue; // not created or not initialised yet
        };
        let snap = BaseStation::<D>::open(&mut store).unwrap();
        if snap.sessions().is_empty() {
            continue;
        }
        while twin.sessions() != snap.sessions() {
            assert!(
                fed < all.len(),
                "a snapshot matches no prefix of the stream"
            );
            twin.receive(all[fed]);
            fed += 1;
        }
        assert_same(&snap, &twin, "live snapshot");
        checked += 1;
        if !cli_ran {
            // The command-line readers work on the live database too.
            let info = Command::new(env!("CARGO_BIN_EXE_host-sim"))
                .args(["map-info"])
                .arg(&db)
                .output()
                .unwrap();
            let text = String::from_utf8_lossy(&info.stdout);
            assert!(
                info.status.success() && text.contains("robot 4 session 1004"),
                "{text}"
            );
            let pca = dir.path().join("pca.npz");
            host_sim::npy_io::write_pca_npz(&pca, &World::new(SummaryCodec::DEFAULT).pca).unwrap();
            let q = Command::new(env!("CARGO_BIN_EXE_host-sim"))
                .arg("map-query")
                .arg(&db)
                .arg("--pca")
                .arg(&pca)
                .args(["--query", "road", "--top", "3", "--png"])
                .arg(dir.path().join("live"))
                .arg("--ply")
                .arg(dir.path().join("live.ply"))
                .output()
                .unwrap();
            let text = String::from_utf8_lossy(&q.stdout);
            assert!(
                q.status.success(),
                "{text}{}",
                String::from_utf8_lossy(&q.stderr)
            );
            assert_eq!(text.matches("query \"road\": score").count(), 3, "{text}");
            assert!(dir.path().join("live-heat.png").exists());
            cli_ran = true;
        }
    }
    writer.join().unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success());
    assert!(
        checked >= 3 && cli_ran,
        "only {checked} snapshots taken during the run"
    );
    let mut whole = BaseStation::<D>::adopting();
    whole.receive(&bytes);
    assert_same(&restore(&db), &whole, "after the run");
}
