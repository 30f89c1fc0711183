//! `host-sim base-station` end to end: a recorded stream in a file (and on stdin) becomes a map database, a
//! PLY and PNGs; running again on the database with the same stream changes nothing; garbage is refused
//! with a clear message.

mod stream_common;

use host_sim::base_station::store::SqliteStore;
use host_sim::base_station::{BaseStation, GlobalMap};
use host_sim::link::SplitMix;
use latentbki::wire::SummaryCodec;
use std::io::Write;
use std::process::{Command, Stdio};
use stream_common::*;

/// Run `host-sim base-station <args>` to its end: (exit code, stdout, stderr).
fn base_station<I, A>(args: I) -> (Option<i32>, String, String)
where
    I: IntoIterator<Item = A>,
    A: AsRef<std::ffi::OsStr>,
{
    let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .arg("base-station")
        .args(args)
        .output()
        .unwrap();
    let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
    (out.status.code(), text(&out.stdout), text(&out.stderr))
}

fn recorded_stream() -> Vec<u8> {
    let world = World::new(SummaryCodec::DEFAULT);
    let mut robot = RobotRig::new(&world, 4, 2.5);
    let mut rng = SplitMix::new(3);
    for i in 0..8 {
        let (pose, pts, feats) = scan(&world, &mut rng, 1.0 + 0.5 * i as f32, 0.5, 300, 1.6);
        robot.step(&pose, &pts, &feats, 8192);
    }
    robot.finish();
    robot.uart.0
}

/// The map a database holds.
fn stored(path: &std::path::Path) -> GlobalMap<D> {
    let mut store = SqliteStore::open_read_only(path).unwrap();
    BaseStation::<D>::open(&mut store)
        .unwrap()
        .into_map()
        .unwrap()
}

#[test]
fn base_station_command_keeps_saves_and_exports_the_map() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("robot.bin");
    std::fs::write(&input, recorded_stream()).unwrap();
    let map = dir.path().join("global.db");
    let (code, stdout, stderr) = base_station([
        input.as_os_str(),
        "--map".as_ref(),
        map.as_os_str(),
        "--ply".as_ref(),
        dir.path().join("g.ply").as_os_str(),
        "--png".as_ref(),
        dir.path().join("g").as_os_str(),
    ]);
    assert_eq!(code, Some(0), "{stdout}\n{stderr}");
    assert!(stdout.contains("frames lost 0"), "{stdout}");
    assert!(stdout.contains("robot 4 session 1004"), "{stdout}");
    let saved = stored(&map);
    assert!(saved.len() > 1000);
    assert!(dir.path().join("g.ply").exists() && dir.path().join("g-uncertainty.png").exists());

    // Same stream on stdin, continuing the database: nothing merges twice.
    let mut child = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(["base-station", "-", "--map"])
        .arg(&map)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(&std::fs::read(&input).unwrap())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}");
    assert!(stdout.contains("summaries merged 0, live 0"), "{stdout}");
    assert!(stored(&map) == saved);

    // Garbage: a clear error, non-zero exit.
    let junk = dir.path().join("junk.bin");
    std::fs::write(&junk, b"hello, this is not a robot\n\0\x01\x02\0").unwrap();
    let (code, _, stderr) = base_station([&junk]);
    assert_ne!(code, Some(0));
    assert!(stderr.contains("no session header"), "{stderr}");
    // A PCA file that does not exist: the path in the error.
    let (code, _, stderr) = base_station([
        input.as_os_str(),
        "--pca".as_ref(),
        "/nonexistent/pca.npz".as_ref(),
    ]);
    assert_ne!(code, Some(0));
    assert!(stderr.contains("/nonexistent/pca.npz"));
}

/// The PCA of the recorded stream's robots as the `--pca` file (`mean` 384, `components` 64 × 384).
fn write_pca(path: &std::path::Path, pca: &latentbki::decode::Pca<D, F>) {
    host_sim::npy_io::write_pca_npz(path, pca).unwrap();
}

/// Run `base-station - <args>` with stdin open and silent: the command must fail on its options without
/// waiting for the stream (a base station that read first would wait here forever). Returns stderr.
fn refused_before_reading(args: &[&std::ffi::OsStr]) -> String {
    let mut child = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(["base-station", "-"])
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stdin = child.stdin.take();
    let start = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > std::time::Duration::from_secs(60) {
            child.kill().unwrap();
            panic!("{args:?}: the base station waited for the stream before checking its options");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    drop(stdin);
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!out.status.success(), "{args:?} accepted");
    assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
    stderr
}

#[test]
fn bad_durations_and_scales_are_refused_up_front() {
    for bad in ["-1", "NaN", "inf", "1e300", "soon"] {
        // Both spellings: `--duration -1` used to be refused by clap as an unknown argument.
        for args in [
            vec!["--duration".to_string(), bad.to_string()],
            vec![format!("--duration={bad}")],
        ] {
            let args: Vec<&std::ffi::OsStr> = args.iter().map(|a| a.as_ref()).collect();
            let err = refused_before_reading(&args);
            assert!(
                err.contains("--duration") && err.contains(bad) && err.contains("seconds"),
                "{err}"
            );
        }
    }
    for bad in ["0", "100000", "2147483648"] {
        let err = refused_before_reading(&["--scale".as_ref(), bad.as_ref()]);
        assert!(
            err.contains("--scale") && err.contains("1..=16384"),
            "{err}"
        );
    }
}

#[test]
fn options_are_checked_before_the_stream_is_read() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let pca = d.join("pca.npz");
    write_pca(&pca, &World::new(SummaryCodec::DEFAULT).pca);
    let junk = d.join("junk.lbki");
    std::fs::write(&junk, b"not a map").unwrap();
    let missing = d.join("missing");
    let p = |p: &std::path::Path| p.as_os_str().to_owned();
    let cases: Vec<(Vec<std::ffi::OsString>, Vec<String>)> = vec![
        (
            vec!["--pca".into(), "/nonexistent/pca.npz".into()],
            vec!["/nonexistent/pca.npz".into()],
        ),
        (
            vec!["--classes".into(), "ground,road".into()],
            vec!["--classes needs --pca".into()],
        ),
        (
            vec!["--query".into(), "road".into()],
            vec!["--query needs --pca".into()],
        ),
        (
            vec![
                "--pca".into(),
                p(&pca),
                "--classes".into(),
                "ground,raod".into(),
            ],
            vec![
                "--classes".into(),
                "\"raod\" is not in the committed vocabulary".into(),
            ],
        ),
        (
            vec!["--pca".into(), p(&pca), "--query".into(), "raod".into()],
            vec!["--query".into(), "\"raod\"".into()],
        ),
        (
            vec!["--map".into(), p(&missing.join("g.lbki"))],
            vec![
                "--map".into(),
                format!("{} does not exist", missing.display()),
            ],
        ),
        // (A missing folder of --png or --ply is created when the file is written.)
        (
            vec!["--png".into(), p(&junk.join("g"))],
            vec![
                "--png".into(),
                format!("{} is not a folder", junk.display()),
            ],
        ),
        (
            vec!["--ply".into(), p(&junk.join("g.ply"))],
            vec![
                "--ply".into(),
                format!("{} is not a folder", junk.display()),
            ],
        ),
        (
            vec!["--ply".into(), p(d)],
            vec!["--ply".into(), "is a folder".into()],
        ),
        (
            vec!["--map".into(), p(&junk.join("g.lbki"))],
            vec![format!("{} is not a folder", junk.display())],
        ),
        // A map database that is not one: the error names the file.
        (
            vec!["--map".into(), p(&junk)],
            vec![junk.display().to_string(), "not a database".into()],
        ),
    ];
    for (args, wanted) in cases {
        let refs: Vec<&std::ffi::OsStr> = args.iter().map(|a| a.as_os_str()).collect();
        let err = refused_before_reading(&refs);
        for w in wanted {
            assert!(err.contains(&w), "{args:?}: wanted `{w}` in {err}");
        }
    }
    assert!(!missing.exists());
}

#[test]
fn vocabulary_query_and_image_size_after_the_stream() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("robot.bin");
    std::fs::write(&input, recorded_stream()).unwrap();
    let world = World::new(SummaryCodec::DEFAULT);
    let pca = dir.path().join("pca.npz");
    write_pca(&pca, &world.pca);
    // Loaded up front, used at the end.
    let (code, stdout, stderr) = base_station([
        input.as_os_str(),
        "--pca".as_ref(),
        pca.as_os_str(),
        "--classes".as_ref(),
        "ground, road ,building".as_ref(),
        "--query".as_ref(),
        "road".as_ref(),
        "--png".as_ref(),
        dir.path().join("g").as_os_str(),
    ]);
    assert_eq!(code, Some(0), "{stdout}\n{stderr}");
    assert!(stdout.contains("  road: "), "{stdout}");
    assert!(dir.path().join("g-heat.png").exists());
    // Another PCA: refused once the robots' feature space is known.
    let mut other = world.pca.clone();
    other.mean[0] += 0.5;
    write_pca(&pca, &other);
    let (code, _, stderr) = base_station([input.as_os_str(), "--pca".as_ref(), pca.as_os_str()]);
    assert!(
        code != Some(0) && stderr.contains("feature-space id"),
        "{stderr}"
    );
    // A scale the clap range allows, but too large for this map's width: a clear error, no abort.
    let (code, _, stderr) = base_station([
        input.as_os_str(),
        "--png".as_ref(),
        dir.path().join("big").as_os_str(),
        "--scale".as_ref(),
        "16384".as_ref(),
    ]);
    assert!(
        code == Some(1) && stderr.contains("too large an image"),
        "{stderr}"
    );
    assert!(!dir.path().join("big-labels.png").exists());
}

#[test]
fn map_database_errors_name_the_file_once() {
    let dir = tempfile::tempdir().unwrap();
    let err = SqliteStore::open_read_only(&dir.path().join("nope.db"))
        .err()
        .unwrap();
    // As main prints it: the message and its chain of causes.
    let shown = format!("{:?}", anyhow::Error::new(err));
    assert_eq!(shown.matches("nope.db").count(), 1, "{shown}");
    let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .arg("map-info")
        .arg(dir.path().join("nope.db"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && stderr.contains("no such map database"),
        "{stderr}"
    );
    assert!(
        !dir.path().join("nope.db").exists(),
        "a reader never creates a database"
    );
}
