//! Recorded data in and maps out, in numpy's formats, so users can bring frames from the authors' Python
//! tooling and read our maps back with `numpy.load`.
//!
//! A frame is an (N, 3+D) float32 array: xyz then the D-dimensional feature (the point layout of the
//! authors' released code). Errors name the file and the expected shape.
//!
//! The format code is our own and small (the `.npy` format is a magic string, a Python-literal header
//! and the raw little-endian data; `.npz` is a zip of `.npy` files): the crate reads and writes only
//! 4-byte float and int arrays, and a general-purpose numpy crate pulled in a Python-literal parser and
//! every zip codec (zstd and bzip2 in C), which was most of host-sim's cold build time.

mod format;
#[cfg(test)]
mod tests;

pub use format::{parse_npy, write_npy, Element, NpyHeader};

use latentbki::nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use latentbki::{key::VoxelKey, stats::VoxelStats};
use std::io::{BufWriter, Read, Seek, Write};
use std::path::{Path, PathBuf};

/// A problem with an input or output file.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// The file could not be opened, read or written.
    // The OS error is part of the message and deliberately not chained as a `source` as well: anyhow
    // would print it twice.
    #[error("{path}: {error}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        error: std::io::Error,
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
    move |error| IoError::Io {
        path: path.to_owned(),
        error,
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
    let (header, body) =
        parse_npy(&bytes).map_err(|e| bad(format!("not a valid .npy file ({e})")))?;
    let shape = &header.shape;
    if shape.len() != 2 || shape[1] < 4 {
        return Err(bad(format!("found shape {shape:?}")));
    }
    let data: Vec<f32> = header.decode(body).map_err(bad)?;
    let cols = shape[1] as usize;
    let dim = cols - 3;
    let n = data.len() / cols;
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
    let file = std::fs::File::create(path).map_err(io_err(path))?;
    let mut w = BufWriter::new(file);
    let rows = positions
        .iter()
        .zip(features.chunks_exact(dim))
        .flat_map(|(p, f)| p.iter().chain(f).copied());
    write_npy(&mut w, &[positions.len() as u64, (3 + dim) as u64], rows)
        .and_then(|()| w.flush())
        .map_err(io_err(path))
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
            .map(|t| match t.parse::<f32>() {
                Ok(x) if x.is_finite() => Ok(x),
                // NaN, inf, and numbers beyond f32 (1e39 parses as inf).
                Ok(_) => Err(bad(format!("`{t}` is not a finite number"))),
                Err(_) => Err(bad(format!("`{t}` is not a number"))),
            })
            .collect::<Result<_, _>>()?;
        if v.len() != 7 {
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

/// Write a map as `.npz`: `keys` (V×3 int32), `lambda` (V), `mean` (V×D), `psi` (V×D) float32, and the
/// uncertainty in the authors' convention (their `publish_map.py`): `tvar` (V×D, (λ+1)/λ²·Ψ), `eopt` (V,
/// max of t_var) and `dopt` (V, exp(mean log t_var)), all NaN where λ ≤ 2.
pub fn write_map_npz<const D: usize>(
    path: &Path,
    voxels: &[(VoxelKey, &VoxelStats<D>)],
    compression: Compression,
) -> Result<(), IoError> {
    let file = std::fs::File::create(path).map_err(io_err(path))?;
    let mut zip = zip::ZipWriter::new(BufWriter::new(file));
    let v = voxels.len() as u64;
    let keys = voxels.iter().flat_map(|(k, _)| k.as_array());
    let lambda = voxels.iter().map(|(_, s)| s.lambda);
    let mean = voxels.iter().flat_map(|(_, s)| s.mean);
    let psi = voxels.iter().flat_map(|(_, s)| s.psi);
    let tvar = voxels
        .iter()
        .flat_map(|(_, s)| s.t_var().unwrap_or([f32::NAN; D]));
    let authors = |s: &VoxelStats<D>| s.optimality(latentbki::inference::Spread::AuthorsTVar);
    let eopt = voxels
        .iter()
        .map(|(_, s)| authors(s).map_or(f32::NAN, |o| o.e));
    let dopt = voxels
        .iter()
        .map(|(_, s)| authors(s).map_or(f32::NAN, |o| o.d));
    let write = || -> std::io::Result<()> {
        let opts = compression.options();
        zip.start_file("keys.npy", opts)?;
        write_npy(&mut zip, &[v, 3], keys)?;
        zip.start_file("lambda.npy", opts)?;
        write_npy(&mut zip, &[v], lambda)?;
        zip.start_file("mean.npy", opts)?;
        write_npy(&mut zip, &[v, D as u64], mean)?;
        zip.start_file("psi.npy", opts)?;
        write_npy(&mut zip, &[v, D as u64], psi)?;
        zip.start_file("tvar.npy", opts)?;
        write_npy(&mut zip, &[v, D as u64], tvar)?;
        zip.start_file("eopt.npy", opts)?;
        write_npy(&mut zip, &[v], eopt)?;
        zip.start_file("dopt.npy", opts)?;
        write_npy(&mut zip, &[v], dopt)?;
        zip.finish()?.flush()
    };
    write().map_err(io_err(path))
}

/// How the members of a written `.npz` are stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Compression {
    /// Stored as they are, like numpy's `savez`: fast to write and to read.
    #[default]
    Stored,
    /// Deflated, like numpy's `savez_compressed`: smaller, ~10× slower to write.
    Deflated,
}

impl Compression {
    fn options(self) -> zip::write::FileOptions {
        let method = match self {
            Self::Stored => zip::CompressionMethod::Stored,
            Self::Deflated => zip::CompressionMethod::Deflated,
        };
        // Large maps pass 4 GiB of members; Zip64 is written only where needed.
        zip::write::FileOptions::default()
            .compression_method(method)
            .large_file(true)
    }
}

/// Write a PCA as `.npz`: `mean` (F) and `components` (D×F) float32, rows orthonormal — the file
/// `base-station --pca` reads.
pub fn write_pca_npz<const D: usize, const F: usize>(
    path: &Path,
    pca: &latentbki::decode::Pca<D, F>,
) -> Result<(), IoError> {
    let file = std::fs::File::create(path).map_err(io_err(path))?;
    let mut zip = zip::ZipWriter::new(BufWriter::new(file));
    let mut write = || -> std::io::Result<()> {
        let opts = zip::write::FileOptions::default();
        zip.start_file("mean.npy", opts)?;
        write_npy(&mut zip, &[F as u64], pca.mean)?;
        zip.start_file("components.npy", opts)?;
        write_npy(
            &mut zip,
            &[D as u64, F as u64],
            pca.components.iter().flatten().copied(),
        )?;
        zip.finish()?.flush()
    };
    write().map_err(io_err(path))
}

/// A `.npz` archive open for reading (numpy's `savez` and `savez_compressed` files, and ours).
pub struct NpzReader<R: Read + Seek> {
    zip: zip::ZipArchive<R>,
    path: PathBuf,
}

impl NpzReader<std::io::BufReader<std::fs::File>> {
    /// Open an archive.
    pub fn open(path: &Path) -> Result<Self, IoError> {
        let file = std::fs::File::open(path).map_err(io_err(path))?;
        let zip = zip::ZipArchive::new(std::io::BufReader::new(file))
            .map_err(|e| io_err(path)(e.into()))?;
        Ok(NpzReader {
            zip,
            path: path.to_owned(),
        })
    }
}

impl<R: Read + Seek> NpzReader<R> {
    /// The array `name` (stored as `name.npy`): its shape and C-ordered data.
    pub fn array<T: Element>(&mut self, name: &str) -> Result<(Vec<u64>, Vec<T>), IoError> {
        let path = &self.path;
        let bad = |problem: String| IoError::BadFrame {
            path: path.to_owned(),
            problem,
        };
        let mut entry = match self.zip.by_name(&format!("{name}.npy")) {
            Ok(entry) => entry,
            Err(zip::result::ZipError::FileNotFound) => {
                return Err(bad(format!("no array `{name}`")))
            }
            Err(e) => return Err(io_err(path)(e.into())),
        };
        let mut bytes = Vec::with_capacity(entry.size().min(1 << 30) as usize);
        entry.read_to_end(&mut bytes).map_err(io_err(path))?;
        let (header, body) = parse_npy(&bytes)
            .map_err(|e| bad(format!("`{name}`: not a valid .npy array ({e})")))?;
        let data = header
            .decode(body)
            .map_err(|e| bad(format!("`{name}`: {e}")))?;
        Ok((header.shape, data))
    }
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
    let mut npz = NpzReader::open(path)?;
    let (_, flat) = npz.array::<i32>("keys")?;
    let (_, lambda) = npz.array("lambda")?;
    let (shape, mean) = npz.array("mean")?;
    let (_, psi) = npz.array("psi")?;
    let keys = flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    Ok(NpzMap {
        keys,
        lambda,
        mean,
        psi,
        dim: shape.get(1).copied().unwrap_or(0) as usize,
    })
}
