//! `host-sim base-station` end to end: a recorded stream in a file (and on stdin) becomes a saved map, a
//! PLY and PNGs; running again on the saved map with the same stream changes nothing; garbage is refused
//! with a clear message.

mod stream_common;

use host_sim::base_station::GlobalMap;
use host_sim::link::SplitMix;
use latentbki::wire::SummaryCodec;
use std::io::Write;
use std::process::{Command, Stdio};
use stream_common::*;

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

#[test]
fn base_station_command_keeps_saves_and_exports_the_map() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("robot.bin");
    std::fs::write(&input, recorded_stream()).unwrap();
    let map = dir.path().join("global.lbki");
    let bin = env!("CARGO_BIN_EXE_host-sim");
    let out = Command::new(bin)
        .arg("base-station")
        .arg(&input)
        .arg("--map")
        .arg(&map)
        .arg("--ply")
        .arg(dir.path().join("g.ply"))
        .arg("--png")
        .arg(dir.path().join("g"))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("frames lost 0"), "{stdout}");
    assert!(stdout.contains("robot 4 session 1004"), "{stdout}");
    let saved = GlobalMap::<D>::load(&map).unwrap();
    assert!(saved.len() > 1000);
    assert!(dir.path().join("g.ply").exists() && dir.path().join("g-uncertainty.png").exists());

    // Same stream on stdin, continuing the saved map: nothing merges twice.
    let mut child = Command::new(bin)
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
    assert_eq!(GlobalMap::<D>::load(&map).unwrap(), saved);

    // Garbage: a clear error, non-zero exit.
    let junk = dir.path().join("junk.bin");
    std::fs::write(&junk, b"hello, this is not a robot\n\0\x01\x02\0").unwrap();
    let out = Command::new(bin)
        .arg("base-station")
        .arg(&junk)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("no session header"), "{stderr}");
    // A PCA file that does not exist: the path in the error.
    let out = Command::new(bin)
        .arg("base-station")
        .arg(&input)
        .args(["--pca", "/nonexistent/pca.npz"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent/pca.npz"));
}
