//! Recorded data in and maps out, in numpy's formats, so users can bring frames from the authors' Python
//! tooling and read our maps back with `numpy.load`.
//!
//! A frame is an (N, 3+D) float32 array: xyz then the D-dimensional feature (the point layout of the
//! authors' released code). Errors name the file and the expected shape.

use latentbki::nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use latentbki::{VoxelKey, VoxelStats};
use npyz::WriterBuilder;
use std::path::{Path, PathBuf};

/// A problem with an input or output file.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// The file could not be opened, read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The file is not the array we expect.
    #[error("{path}: {problem}; expected a 2-D float32 .npy array of shape (N, 3+D) with D >= 1 (xyz, then the feature)")]
    BadFrame {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        problem: String,
    },
    /// Frames in one run must share their feature dimension.
    #[error("{path}: feature dimension {found} differs from the first frame's {expected}")]
    DimensionMismatch {
        /// The file.
        path: PathBuf,
        /// D of the first frame.
        expected: usize,
        /// D of this frame.
        found: usize,
    },
    /// A pose line is malformed.
    #[error("{path}:{line}: {problem}; expected `tx ty tz qx qy qz qw` (sensor to map, metres, unit quaternion)")]
    BadPose {
        /// The pose file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        problem: String,
    },
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> IoError + '_ {
    move |source| IoError::Io {
        path: path.to_owned(),
        source,
    }
}

/// One frame of points: positions and features (row-major N × D).
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// Feature dimension D.
    pub dim: usize,
    /// Sensor-frame (or map-frame, with an identity pose) positions.
    pub positions: Vec<[f32; 3]>,
    /// Features, N × D row-major.
    pub features: Vec<f32>,
}

/// Read an (N, 3+D) float32 frame.
pub fn read_frame(path: &Path) -> Result<Frame, IoError> {
    let bad = |problem: String| IoError::BadFrame {
        path: path.to_owned(),
        problem,
    };
    let bytes = std::fs::read(path).map_err(io_err(path))?;
    let npy =
        npyz::NpyFile::new(&bytes[..]).map_err(|e| bad(format!("not a valid .npy file ({e})")))?;
    let shape = npy.shape().to_vec();
    let dtype = npy.dtype();
    if shape.len() != 2 || shape[1] < 4 {
        return Err(bad(format!("found shape {shape:?}")));
    }
    let is_f32 = matches!(&dtype, npyz::DType::Plain(t) if t.type_char() == npyz::TypeChar::Float && t.size_field() == 4);
    if !is_f32 {
        return Err(bad(format!("found dtype {}", dtype.descr())));
    }
    if npy.order() != npyz::Order::C {
        return Err(bad("found a Fortran-ordered array".into()));
    }
    let (n, cols) = (shape[0] as usize, shape[1] as usize);
    let data: Vec<f32> = npy
        .into_vec()
        .map_err(|e| bad(format!("truncated or unreadable data ({e})")))?;
    if data.len() != n * cols {
        return Err(bad(format!(
            "holds {} values for shape {shape:?}",
            data.len()
        )));
    }
    let dim = cols - 3;
    let mut positions = Vec::with_capacity(n);
    let mut features = Vec::with_capacity(n * dim);
    for row in data.chunks_exact(cols) {
        positions.push([row[0], row[1], row[2]]);
        features.extend_from_slice(&row[3..]);
    }
    Ok(Frame {
        dim,
        positions,
        features,
    })
}

/// Write an (N, 3+D) float32 frame (used by tests and the simulator's recorder).
pub fn write_frame(
    path: &Path,
    positions: &[[f32; 3]],
    features: &[f32],
    dim: usize,
) -> Result<(), IoError> {
    let mut flat = Vec::with_capacity(positions.len() * (3 + dim));
    for (p, f) in positions.iter().zip(features.chunks_exact(dim)) {
        flat.extend_from_slice(p);
        flat.extend_from_slice(f);
    }
    let file = std::fs::File::create(path).map_err(io_err(path))?;
    let mut w = npyz::WriteOptions::new()
        .default_dtype()
        .shape(&[positions.len() as u64, (3 + dim) as u64])
        .writer(std::io::BufWriter::new(file))
        .begin_nd()
        .map_err(io_err(path))?;
    w.extend(flat).map_err(io_err(path))?;
    w.finish().map_err(io_err(path))
}

/// Read a pose file: one `tx ty tz qx qy qz qw` line per frame; `#` starts a comment.
pub fn read_poses(path: &Path) -> Result<Vec<Isometry3<f32>>, IoError> {
    let text = std::fs::read_to_string(path).map_err(io_err(path))?;
    let mut poses = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let bad = |problem: String| IoError::BadPose {
            path: path.to_owned(),
            line: i + 1,
            problem,
        };
        let v: Vec<f32> = line
            .split_whitespace()
            .map(|t| {
                t.parse::<f32>()
                    .map_err(|_| bad(format!("`{t}` is not a number")))
            })
            .collect::<Result<_, _>>()?;
        if v.len() != 7 || v.iter().any(|x| !x.is_finite()) {
            return Err(bad(format!("found {} values", v.len())));
        }
        let q = Quaternion::new(v[6], v[3], v[4], v[5]);
        if (q.norm() - 1.0).abs() > 1e-3 {
            return Err(bad(format!("quaternion norm is {}", q.norm())));
        }
        poses.push(Isometry3::from_parts(
            Translation3::new(v[0], v[1], v[2]),
            UnitQuaternion::from_quaternion(q),
        ));
    }
    Ok(poses)
}

/// Write a map as `.npz`: `keys` (V×3 int32), `lambda` (V), `mean` (V×D), `psi` (V×D) float32.
pub fn write_map_npz<const D: usize>(
    path: &Path,
    voxels: &[(VoxelKey, &VoxelStats<D>)],
) -> Result<(), IoError> {
    let mut npz = npyz::npz::NpzWriter::create(path).map_err(io_err(path))?;
    let v = voxels.len() as u64;
    let opts = zip::write::FileOptions::default();
    let keys = voxels.iter().flat_map(|(k, _)| k.as_array());
    let lambda = voxels.iter().map(|(_, s)| s.lambda);
    let mean = voxels.iter().flat_map(|(_, s)| s.mean);
    let psi = voxels.iter().flat_map(|(_, s)| s.psi);
    macro_rules! array {
        ($name:expr, $ty:ty, $shape:expr, $data:expr) => {{
            let mut w = npz
                .array::<$ty>($name, opts)
                .map_err(io_err(path))?
                .default_dtype()
                .shape($shape)
                .begin_nd()
                .map_err(io_err(path))?;
            w.extend($data).map_err(io_err(path))?;
            w.finish().map_err(io_err(path))?;
        }};
    }
    array!("keys", i32, &[v, 3], keys);
    array!("lambda", f32, &[v], lambda);
    array!("mean", f32, &[v, D as u64], mean);
    array!("psi", f32, &[v, D as u64], psi);
    Ok(())
}

/// A map read back from `.npz` (for tests and the base station).
#[derive(Debug, Default)]
pub struct NpzMap {
    /// V × 3 keys.
    pub keys: Vec<[i32; 3]>,
    /// V confidences.
    pub lambda: Vec<f32>,
    /// V × D means, row-major.
    pub mean: Vec<f32>,
    /// V × D scatter diagonals, row-major.
    pub psi: Vec<f32>,
    /// D.
    pub dim: usize,
}

/// Read a map written by [`write_map_npz`].
pub fn read_map_npz(path: &Path) -> Result<NpzMap, IoError> {
    let mut npz = npyz::npz::NpzArchive::open(path).map_err(io_err(path))?;
    fn array<T: npyz::Deserialize, R: std::io::Read + std::io::Seek>(
        npz: &mut npyz::npz::NpzArchive<R>,
        path: &Path,
        name: &str,
    ) -> Result<(Vec<u64>, Vec<T>), IoError> {
        let bad = |problem: String| IoError::BadFrame {
            path: path.to_owned(),
            problem,
        };
        let f = npz
            .by_name(name)
            .map_err(io_err(path))?
            .ok_or_else(|| bad(format!("no array `{name}`")))?;
        let shape = f.shape().to_vec();
        Ok((shape, f.into_vec().map_err(io_err(path))?))
    }
    let (_, flat) = array::<i32, _>(&mut npz, path, "keys")?;
    let (_, lambda) = array(&mut npz, path, "lambda")?;
    let (shape, mean) = array(&mut npz, path, "mean")?;
    let (_, psi) = array(&mut npz, path, "psi")?;
    let keys = flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    Ok(NpzMap {
        keys,
        lambda,
        mean,
        psi,
        dim: shape.get(1).copied().unwrap_or(0) as usize,
    })
}
