//! `host-sim integrate`: .npy frames in, .npz map out, read back; malformed input gives a clear error.

use host_sim::npy_io::{read_map_npz, write_frame, write_npy};
use host_sim::{ObsMap, ReferenceMap};
use latentbki::nalgebra::{Isometry3, Translation3, UnitQuaternion};
use latentbki::{key::VoxelKey, MapConfig};
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
    let mut observations = ObsMap::<D>::new(MapConfig::default()).unwrap();
    for (i, pose) in read_back.iter().enumerate() {
        let (p, f) = frame(i as u32 + 1, 500);
        let path = dir.path().join(format!("frame{i}.npy"));
        write_frame(&path, &p, &f, D).unwrap();
        paths.push(path);
        let feats: Vec<[f32; D]> = f.chunks_exact(D).map(|c| c.try_into().unwrap()).collect();
        expected.integrate(pose, &p, &feats);
        observations.integrate(pose, &p, &feats);
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
        // The same code on the same input: bit-identical to the observation map's gather.
        let g = observations.posterior(VoxelKey::new(k[0], k[1], k[2]));
        assert_eq!(map.lambda[i], g.lambda);
        assert_eq!(&map.mean[i * D..(i + 1) * D], &g.mean[..]);
        assert_eq!(&map.psi[i * D..(i + 1) * D], &g.psi[..]);
        // And the paper's literal batch-by-batch update to f32 rounding.
        assert!((map.lambda[i] - v.lambda).abs() <= 1e-5 * v.lambda);
        for d in 0..D {
            let (m, p) = (map.mean[i * D + d], map.psi[i * D + d]);
            assert!(
                (m - v.mean[d]).abs() <= 1e-5 * (1.0 + v.mean[d].abs()),
                "μ {m} vs {}",
                v.mean[d]
            );
            assert!(
                (p - v.psi[d]).abs() <= 1e-5 * v.psi[d],
                "Ψ {p} vs {}",
                v.psi[d]
            );
        }
    }
    check_authors_uncertainty(&out, &map);
}

/// `tvar`, `eopt`, `dopt` as the authors' `publish_map.py` computes them from the written λ and Ψ, in f64:
/// t_var = (λ+1)/λ²·Ψ, E-opt = max t_var, D-opt = exp(mean log t_var), masked (NaN) where λ ≤ 2.
fn check_authors_uncertainty(path: &std::path::Path, map: &host_sim::npy_io::NpzMap) {
    let mut npz = host_sim::npy_io::NpzReader::open(path).unwrap();
    let (tshape, tvar) = npz.array::<f32>("tvar").unwrap();
    let (eshape, eopt) = npz.array::<f32>("eopt").unwrap();
    let (dshape, dopt) = npz.array::<f32>("dopt").unwrap();
    let v = map.keys.len() as u64;
    assert_eq!(
        (tshape, eshape, dshape),
        (vec![v, D as u64], vec![v], vec![v])
    );
    let (mut gated, mut live) = (0, 0);
    for i in 0..map.keys.len() {
        let l = map.lambda[i] as f64;
        let row = &tvar[i * D..(i + 1) * D];
        if l <= 2.0 || l.is_nan() {
            gated += 1;
            assert!(row.iter().all(|x| x.is_nan()) && eopt[i].is_nan() && dopt[i].is_nan());
            continue;
        }
        live += 1;
        let want: Vec<f64> = map.psi[i * D..(i + 1) * D]
            .iter()
            .map(|&p| (l + 1.0) / (l * l) * p as f64)
            .collect();
        for (a, b) in row.iter().zip(&want) {
            assert!((*a as f64 - b).abs() <= 1e-6 * b, "tvar {a} vs {b}");
        }
        let e = want.iter().cloned().fold(f64::MIN, f64::max);
        let d = (want.iter().map(|x| x.ln()).sum::<f64>() / D as f64).exp();
        assert!(
            (eopt[i] as f64 - e).abs() <= 1e-6 * e,
            "eopt {} vs {e}",
            eopt[i]
        );
        assert!(
            (dopt[i] as f64 - d).abs() <= 2e-5 * d,
            "dopt {} vs {d}",
            dopt[i]
        );
    }
    assert!(
        gated > 0 && live > 0,
        "both cases covered: {gated} gated, {live} live"
    );
    numpy_reads_the_uncertainty(path);
}

/// If numpy is installed, it reads the file and recomputes the three arrays as `publish_map.py` does
/// (`np.log`, `np.max(np.abs(..))`, the `t_v > 2` mask). Without numpy it fails with the line that installs it
/// (`cargo xtask setup`).
fn numpy_reads_the_uncertainty(path: &std::path::Path) {
    let has_numpy = Command::new("python3")
        .args(["-c", "import numpy"])
        .output()
        .is_ok_and(|o| o.status.success());
    // `cargo xtask test` (the README's test command) installs numpy first: missing, this is a failure with
    // the line that fixes it, never a silent pass.
    assert!(
        has_numpy,
        "numpy is missing: run `cargo xtask setup` (or `pip install numpy`)"
    );
    let script = r#"
import sys, numpy as np
m = np.load(sys.argv[1])
lam, psi = m["lambda"].astype(np.float64)[:, None], m["psi"].astype(np.float64)
tv = (lam + 1) / (lam * lam) * psi
live = (lam > 2).reshape(-1)
assert m["tvar"].dtype == np.float32 and m["tvar"].shape == psi.shape
assert np.isnan(m["tvar"][~live]).all() and np.isnan(m["eopt"][~live]).all() and np.isnan(m["dopt"][~live]).all()
assert np.allclose(m["tvar"][live], tv[live], rtol=1e-6, atol=0)
e = np.max(np.abs(tv[live]), axis=-1)
d = np.exp(np.sum(np.log(tv[live]), axis=-1) / tv.shape[-1])
assert np.allclose(m["eopt"][live], e, rtol=1e-6, atol=0)
assert np.allclose(m["dopt"][live], d, rtol=2e-5, atol=0)
print("numpy ok", int(live.sum()), int((~live).sum()))
"#;
    let out = Command::new("python3")
        .arg("-c")
        .arg(script)
        .arg(path)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "numpy check failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).starts_with("numpy ok"));
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

/// A `.npy` file with this header text (version 1) and body.
fn npy_with_header(text: &str, body: &[u8]) -> Vec<u8> {
    let mut b = b"\x93NUMPY\x01\x00".to_vec();
    b.extend((text.len() as u16).to_le_bytes());
    b.extend(text.as_bytes());
    b.extend(body);
    b
}

#[test]
fn deeply_nested_header_is_an_error_not_a_stack_overflow() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("map.npz");
    let p = dir.path().join("nested.npy");
    std::fs::write(
        &p,
        npy_with_header(&format!("{{'descr': {}", "[".repeat(60_000)), &[]),
    )
    .unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .arg("integrate")
        .arg(&p)
        .arg("--out")
        .arg(&out)
        // The message alone: anyhow appends a backtrace when these are set.
        .env_remove("RUST_BACKTRACE")
        .env_remove("RUST_LIB_BACKTRACE")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    // Exit code 1 (an error), not a signal.
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("nested.npy") && err.contains("nested deeper than 16 levels"),
        "{err}"
    );
    assert!(
        err.len() < 2000,
        "the 60 kB header is not quoted whole: {err}"
    );
}

#[test]
fn data_beyond_the_shape_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("map.npz");
    let p = dir.path().join("long.npy");
    let (pos, feat) = frame(3, 10);
    write_frame(&p, &pos, &feat, D).unwrap();
    let mut bytes = std::fs::read(&p).unwrap();
    bytes.extend([0u8; 8]);
    std::fs::write(&p, bytes).unwrap();
    let (ok, err) = run_integrate(&[p.as_os_str(), "--out".as_ref(), out.as_os_str()]);
    assert!(
        !ok && err.contains("long.npy") && err.contains("8 bytes of trailing data"),
        "{err}"
    );
    assert!(!out.exists());
}

#[test]
fn nothing_integrated_is_an_error_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("map.npz");
    let p = dir.path().join("nan.npy");
    let (mut pos, feat) = frame(4, 20);
    pos.iter_mut().for_each(|q| q[0] = f32::NAN);
    write_frame(&p, &pos, &feat, D).unwrap();
    let (ok, err) = run_integrate(&[p.as_os_str(), "--out".as_ref(), out.as_os_str()]);
    assert!(
        !ok && err.contains("no point was integrated: 20 rejected (non-finite position 20"),
        "{err}"
    );
    assert!(!out.exists(), "no empty map is written");
}

#[test]
fn negative_numbers_need_no_equals_sign() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("map.npz");
    let p = dir.path().join("f.npy");
    let (pos, feat) = frame(5, 50);
    write_frame(&p, &pos, &feat, D).unwrap();
    let (ok, err) = run_integrate(&[
        p.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
        "--prior-mean".as_ref(),
        "-5".as_ref(),
        "--prior-lambda".as_ref(),
        "1".as_ref(),
    ]);
    assert!(ok, "{err}");
    // The same map as with `--prior-mean=-5` (which always worked), not the default prior's.
    let mean = read_map_npz(&out).unwrap().mean;
    let with_equals = dir.path().join("equals.npz");
    let (ok, err) = run_integrate(&[
        p.as_os_str(),
        "--out".as_ref(),
        with_equals.as_os_str(),
        "--prior-mean=-5".as_ref(),
        "--prior-lambda=1".as_ref(),
    ]);
    assert!(ok, "{err}");
    assert_eq!(mean, read_map_npz(&with_equals).unwrap().mean);
    let (ok, err) = run_integrate(&[p.as_os_str(), "--out".as_ref(), with_equals.as_os_str()]);
    assert!(ok, "{err}");
    assert_ne!(mean, read_map_npz(&with_equals).unwrap().mean);
    // A negative value that makes no sense reaches the configuration check, not clap's parser.
    let (ok, err) = run_integrate(&[
        p.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
        "--voxel-size".as_ref(),
        "-0.1".as_ref(),
    ]);
    assert!(!ok && err.contains("voxel size"), "{err}");
}

#[test]
fn non_finite_pose_values_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("map.npz");
    let good = dir.path().join("good.npy");
    let (pos, feat) = frame(6, 20);
    write_frame(&good, &pos, &feat, D).unwrap();
    let poses = dir.path().join("poses.txt");
    for bad in ["nan", "inf", "1e39"] {
        std::fs::write(&poses, format!("0 0 0 0 0 0 1\n0 0 {bad} 0 0 0 1\n")).unwrap();
        let (ok, err) = run_integrate(&[
            good.as_os_str(),
            good.as_os_str(),
            "--poses".as_ref(),
            poses.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
        ]);
        assert!(
            !ok && err.contains("poses.txt:2")
                && err.contains(&format!("`{bad}` is not a finite number")),
            "{err}"
        );
        assert!(!err.contains("found 7 values"), "{err}");
    }
}

#[test]
fn os_errors_are_printed_once() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.npy");
    let out = dir.path().join("map.npz");
    let (ok, err) = run_integrate(&[missing.as_os_str(), "--out".as_ref(), out.as_os_str()]);
    assert!(!ok && err.contains("missing.npy"), "{err}");
    assert_eq!(err.matches("os error 2").count(), 1, "{err}");
}
