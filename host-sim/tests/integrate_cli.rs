//! `host-sim integrate`: .npy frames in, .npz map out, read back; malformed input gives a clear error.

use host_sim::npy_io::{read_map_npz, write_frame, write_npy};
use host_sim::ReferenceMap;
use latentbki::nalgebra::{Isometry3, Translation3, UnitQuaternion};
use latentbki::{MapConfig, VoxelKey};
use std::process::Command;

const D: usize = 8;

fn frame(seed: u32, n: usize) -> (Vec<[f32; 3]>, Vec<f32>) {
    // A small deterministic generator keeps the test self-contained.
    let mut s = seed.wrapping_mul(2654435761).max(1);
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        (s as f32 / u32::MAX as f32) * 2.0 - 1.0
    };
    let pos = (0..n)
        .map(|_| [next() * 0.6, next() * 0.6, next() * 0.3])
        .collect();
    let feat = (0..n * D).map(|_| next()).collect();
    (pos, feat)
}

#[test]
fn integrate_round_trips_through_npy_and_npz() {
    let dir = tempfile::tempdir().unwrap();
    let poses = [
        Isometry3::identity(),
        Isometry3::from_parts(
            Translation3::new(0.3, -0.2, 0.1),
            UnitQuaternion::from_euler_angles(0.1, -0.2, 0.7),
        ),
    ];
    let pose_file = dir.path().join("poses.txt");
    let lines: Vec<String> = poses
        .iter()
        .map(|p| {
            let (t, q) = (p.translation.vector, p.rotation.quaternion());
            format!("{} {} {} {} {} {} {}", t.x, t.y, t.z, q.i, q.j, q.k, q.w)
        })
        .collect();
    std::fs::write(
        &pose_file,
        format!("# tx ty tz qx qy qz qw\n{}\n", lines.join("\n")),
    )
    .unwrap();
    // The expected map uses the poses as the command will read them back.
    let read_back = host_sim::npy_io::read_poses(&pose_file).unwrap();
    let mut paths = Vec::new();
    let mut expected = ReferenceMap::<D>::new(MapConfig::default()).unwrap();
    for (i, pose) in read_back.iter().enumerate() {
        let (p, f) = frame(i as u32 + 1, 500);
        let path = dir.path().join(format!("frame{i}.npy"));
        write_frame(&path, &p, &f, D).unwrap();
        paths.push(path);
        let feats: Vec<[f32; D]> = f.chunks_exact(D).map(|c| c.try_into().unwrap()).collect();
        expected.integrate(pose, &p, &feats);
    }
    let out = dir.path().join("map.npz");

    let status = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .arg("integrate")
        .args(&paths)
        .arg("--out")
        .arg(&out)
        .arg("--poses")
        .arg(&pose_file)
        .output()
        .unwrap();
    assert!(
        status.status.success(),
        "{}",
        String::from_utf8_lossy(&status.stderr)
    );

    let map = read_map_npz(&out).unwrap();
    assert_eq!(map.dim, D);
    assert!(expected.len() > 100);
    assert_eq!(map.keys.len(), expected.len());
    assert_eq!(map.lambda.len(), expected.len());
    for (i, k) in map.keys.iter().enumerate() {
        let v = expected
            .get(&VoxelKey::new(k[0], k[1], k[2]))
            .expect("voxel exists");
        // The same code on the same input: bit-identical.
        assert_eq!(map.lambda[i], v.lambda);
        assert_eq!(&map.mean[i * D..(i + 1) * D], &v.mean[..]);
        assert_eq!(&map.psi[i * D..(i + 1) * D], &v.psi[..]);
    }
}

fn run_integrate(args: &[&std::ffi::OsStr]) -> (bool, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .arg("integrate")
        .args(args)
        .output()
        .unwrap();
    (
        o.status.success(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn malformed_frames_give_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("map.npz");
    let o = out.as_os_str();
    for (name, bytes) in [
        ("garbage.npy", b"this is not numpy".to_vec()),
        ("empty.npy", Vec::new()),
    ] {
        let p = dir.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        let (ok, err) = run_integrate(&[p.as_os_str(), "--out".as_ref(), o]);
        assert!(!ok);
        assert!(err.contains(name) && err.contains("(N, 3+D)"), "{err}");
    }
    // Right format, wrong shape: 1-D.
    let p = dir.path().join("narrow.npy");
    let mut bytes = Vec::new();
    write_npy(&mut bytes, &[3], [1.0f32, 2.0, 3.0]).unwrap();
    std::fs::write(&p, bytes).unwrap();
    let (ok, err) = run_integrate(&[p.as_os_str(), "--out".as_ref(), o]);
    assert!(
        !ok && err.contains("narrow.npy") && err.contains("found shape [3]"),
        "{err}"
    );
    // Wrong dtype: float64, shape (2, 4).
    let p = dir.path().join("f64.npy");
    let mut bytes =
        b"\x93NUMPY\x01\x00\x76\x00{'descr': '<f8', 'fortran_order': False, 'shape': (2, 4), }"
            .to_vec();
    bytes.resize(127, b' ');
    bytes.push(b'\n');
    bytes.extend(1.0f64.to_le_bytes().repeat(8));
    std::fs::write(&p, bytes).unwrap();
    let (ok, err) = run_integrate(&[p.as_os_str(), "--out".as_ref(), o]);
    assert!(
        !ok && err.contains("f64.npy") && err.contains("found dtype <f8"),
        "{err}"
    );
    // Truncated data: a valid header promising more rows than the file holds.
    let good = dir.path().join("good.npy");
    let (pos, feat) = frame(9, 50);
    write_frame(&good, &pos, &feat, D).unwrap();
    let mut bytes = std::fs::read(&good).unwrap();
    bytes.truncate(bytes.len() - 100);
    let p = dir.path().join("truncated.npy");
    std::fs::write(&p, bytes).unwrap();
    let (ok, err) = run_integrate(&[p.as_os_str(), "--out".as_ref(), o]);
    assert!(!ok && err.contains("truncated.npy"), "{err}");
    // Frames of different D in one run.
    let other = dir.path().join("d4.npy");
    write_frame(&other, &pos, &feat[..50 * 4], 4).unwrap();
    let (ok, err) = run_integrate(&[good.as_os_str(), other.as_os_str(), "--out".as_ref(), o]);
    assert!(
        !ok && err.contains("d4.npy") && err.contains("dimension"),
        "{err}"
    );
    // A bad pose line names the file and line.
    let poses = dir.path().join("poses.txt");
    std::fs::write(&poses, "0 0 0 0 0 0 1\n1 2 three 0 0 0 1\n").unwrap();
    let (ok, err) = run_integrate(&[
        good.as_os_str(),
        good.as_os_str(),
        "--poses".as_ref(),
        poses.as_os_str(),
        "--out".as_ref(),
        o,
    ]);
    assert!(!ok && err.contains("poses.txt:2"), "{err}");
    assert!(!out.exists(), "no output is written on error");
}
