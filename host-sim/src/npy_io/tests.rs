//! The formats against bytes numpy writes, and the errors a user sees.

use super::*;

/// `np.save` of `np.arange(6, dtype='<f4').reshape(2, 3)`: numpy's header, byte for byte.
fn numpy_arange() -> Vec<u8> {
    let mut b =
        b"\x93NUMPY\x01\x00\x76\x00{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }"
            .to_vec();
    b.resize(127, b' ');
    b.push(b'\n');
    for x in 0..6 {
        b.extend((x as f32).to_le_bytes());
    }
    b
}

#[test]
fn writes_what_numpy_writes() {
    let mut ours = Vec::new();
    write_npy(&mut ours, &[2, 3], (0..6).map(|x| x as f32)).unwrap();
    assert_eq!(ours, numpy_arange());
    let mut one_d = Vec::new();
    write_npy(&mut one_d, &[2], [7i32, -1]).unwrap();
    let (h, body) = parse_npy(&one_d).unwrap();
    assert_eq!((h.descr.as_str(), h.shape.as_slice()), ("<i4", &[2][..]));
    assert_eq!(h.decode::<i32>(body).unwrap(), [7, -1]);
    assert_eq!(one_d.len() - body.len(), 128, "data starts 64-byte aligned");
    // The shape must match the data.
    assert!(write_npy(&mut Vec::new(), &[3], [1.0f32]).is_err());
}

#[test]
fn reads_numpy_headers() {
    let bytes = numpy_arange();
    let (h, body) = parse_npy(&bytes).unwrap();
    assert!(!h.fortran_order);
    assert_eq!(h.shape, [2, 3]);
    assert_eq!(
        h.decode::<f32>(body).unwrap(),
        [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
    );
    // Wrong type for the caller.
    assert_eq!(h.decode::<i32>(body).unwrap_err(), "found dtype <f4");
    // Big-endian data, a version 2 header, double quotes, Python 2 longs, no trailing comma.
    let text = "{\"descr\": \">i4\", \"shape\": (1L, 3L), \"fortran_order\": False}\n";
    let mut b = b"\x93NUMPY\x02\x00".to_vec();
    b.extend((text.len() as u32).to_le_bytes());
    b.extend(text.as_bytes());
    b.extend([0, 0, 0, 1, 0xff, 0xff, 0xff, 0xfe, 0, 0, 0, 3]);
    let (h, body) = parse_npy(&b).unwrap();
    assert_eq!(h.shape, [1, 3]);
    assert_eq!(h.decode::<i32>(body).unwrap(), [1, -2, 3]);
}

fn header(text: &str) -> Result<NpyHeader, String> {
    let mut b = b"\x93NUMPY\x01\x00".to_vec();
    b.extend((text.len() as u16).to_le_bytes());
    b.extend(text.as_bytes());
    parse_npy(&b).map(|(h, _)| h)
}

#[test]
fn rejects_what_it_cannot_read() {
    let plain = |descr: &str, fortran: &str, shape: &str| {
        header(&format!(
            "{{'descr': '{descr}', 'fortran_order': {fortran}, 'shape': {shape}, }}"
        ))
    };
    let h = plain("<f8", "False", "(4,)").unwrap();
    assert_eq!(h.decode::<f32>(&[0; 32]).unwrap_err(), "found dtype <f8");
    let h = plain("<f4", "True", "(2, 2)").unwrap();
    assert!(h.decode::<f32>(&[0; 16]).unwrap_err().contains("Fortran"));
    let h = plain("<f4", "False", "(2, 2)").unwrap();
    assert!(h.decode::<f32>(&[0; 15]).unwrap_err().contains("truncated"));
    assert_eq!(h.decode::<f32>(&[0; 16]).unwrap(), [0.0; 4]);
    let h = plain("<f4", "False", "()").unwrap();
    assert_eq!(h.decode::<f32>(&1.5f32.to_le_bytes()).unwrap(), [1.5]);
    let h = plain("<f4", "False", "(4294967296, 4294967296, 4294967296)").unwrap();
    assert!(h.decode::<f32>(&[]).unwrap_err().contains("too large"));
    // A structured dtype parses but is not ours.
    let h =
        header("{'descr': [('a', '<f4'), ('b', '<i4')], 'fortran_order': False, 'shape': (3,), }")
            .unwrap();
    assert!(h
        .decode::<f32>(&[0; 24])
        .unwrap_err()
        .starts_with("found dtype Seq"));
    for bad in [
        "",
        "{",
        "{'descr': '<f4'",
        "{'descr': '<f4', 'fortran_order': False}",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (2, x)}",
        "{'descr': '<f4' 'fortran_order': False, 'shape': (2,)}",
        "{'descr: '<f4', 'fortran_order': False, 'shape': (2,)}",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (2,), 'extra': 1}",
        "[1, 2]",
    ] {
        assert!(header(bad).is_err(), "{bad}");
    }
    for bytes in [
        &b""[..],
        b"\x93NUMPY",
        b"\x93NUMPY\x01\x00\x10",
        b"\x93NUMPY\x04\x00\x10\x00",
        b"\x93NUMPY\x01\x00\x10\x00{",
        b"PK\x03\x04",
    ] {
        assert!(parse_npy(bytes).is_err(), "{bytes:?}");
    }
}

#[test]
fn refuses_deep_nesting_instead_of_overflowing_the_stack() {
    // 60,000 `[` recursed once per bracket and aborted the process on a stack overflow.
    for open in ["[", "(", "{'a': "] {
        // (A version 1 header holds at most 65,535 bytes.)
        let text = format!("{{'descr': {}", open.repeat(60_000 / open.len()));
        let err = header(&text).unwrap_err();
        assert!(
            err.contains("nested deeper than 16 levels"),
            "{}",
            &err[..80]
        );
    }
    // 16 levels are fine (numpy's structured dtypes nest 3 deep).
    let deep = format!(
        "{{'descr': {}'<f4'{}, 'fortran_order': False, 'shape': (1,), }}",
        "[".repeat(15),
        "]".repeat(15)
    );
    assert!(header(&deep).is_ok());
    let too_deep = deep
        .replace("'descr': ", "'descr': [")
        .replace("'<f4'", "'<f4']");
    assert!(header(&too_deep).unwrap_err().contains("nested deeper"));
}

#[test]
fn refuses_trailing_data() {
    let mut bytes = numpy_arange();
    bytes.extend(7.0f32.to_le_bytes());
    let (h, body) = parse_npy(&bytes).unwrap();
    let err = h.decode::<f32>(body).unwrap_err();
    assert!(
        err.contains("4 bytes of trailing data") && err.contains("expected 24"),
        "{err}"
    );
}

#[test]
fn pose_values_must_be_finite() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("poses.txt");
    for bad in ["nan", "inf", "-inf", "1e39"] {
        std::fs::write(&path, format!("0 0 0 0 0 0 1\n0 {bad} 0 0 0 0 1\n")).unwrap();
        let err = read_poses(&path).unwrap_err().to_string();
        assert!(
            err.contains("poses.txt:2") && err.contains(&format!("`{bad}` is not a finite number")),
            "{err}"
        );
    }
    std::fs::write(&path, "0 0 0 0 0 1\n").unwrap();
    let err = read_poses(&path).unwrap_err().to_string();
    assert!(
        err.contains("poses.txt:1") && err.contains("found 6 values"),
        "{err}"
    );
}

#[test]
fn os_errors_are_in_the_message_not_chained_again() {
    let err = read_frame(Path::new("/nonexistent/frame.npy")).unwrap_err();
    let msg = err.to_string();
    assert!(msg.starts_with("/nonexistent/frame.npy: "), "{msg}");
    assert!(std::error::Error::source(&err).is_none());
}

/// `np.savez` (stored, zip64 entries) and `np.savez_compressed` (deflate) archives of
/// `mean=[1.5, -2]` (float32) and `keys=[[1, -2, 3], [4, 5, -6]]` (int32).
#[test]
fn reads_numpy_archives() {
    let dir = env!("CARGO_MANIFEST_DIR");
    for name in ["numpy-savez.npz", "numpy-savez-compressed.npz"] {
        let path = Path::new(dir).join("tests/data").join(name);
        let mut npz = NpzReader::open(&path).unwrap();
        assert_eq!(
            npz.array::<f32>("mean").unwrap(),
            (vec![2], vec![1.5, -2.0])
        );
        assert_eq!(
            npz.array::<i32>("keys").unwrap(),
            (vec![2, 3], vec![1, -2, 3, 4, 5, -6])
        );
        let err = npz.array::<f32>("keys").unwrap_err().to_string();
        assert!(
            err.contains(name) && err.contains("found dtype <i4"),
            "{err}"
        );
        let err = npz.array::<f32>("psi").unwrap_err().to_string();
        assert!(err.contains("no array `psi`"), "{err}");
    }
}
