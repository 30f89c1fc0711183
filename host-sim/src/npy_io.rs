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

use latentbki::nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use latentbki::{VoxelKey, VoxelStats};
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

/// An element type of the arrays this module reads and writes: a 4-byte number.
pub trait Element: Copy {
    /// numpy's type code without the byte order (`f4`, `i4`).
    const CODE: &'static str;
    /// From little-endian bytes.
    fn from_le(b: [u8; 4]) -> Self;
    /// To little-endian bytes.
    fn to_le(self) -> [u8; 4];
}

impl Element for f32 {
    const CODE: &'static str = "f4";
    fn from_le(b: [u8; 4]) -> Self {
        f32::from_le_bytes(b)
    }
    fn to_le(self) -> [u8; 4] {
        self.to_le_bytes()
    }
}

impl Element for i32 {
    const CODE: &'static str = "i4";
    fn from_le(b: [u8; 4]) -> Self {
        i32::from_le_bytes(b)
    }
    fn to_le(self) -> [u8; 4] {
        self.to_le_bytes()
    }
}

/// The header of a `.npy` file.
#[derive(Clone, Debug, PartialEq)]
pub struct NpyHeader {
    /// The dtype as written (`<f4`; a structured dtype is kept as its literal text).
    pub descr: String,
    /// Column-major data.
    pub fortran_order: bool,
    /// The array's shape (empty for a scalar).
    pub shape: Vec<u64>,
}

impl NpyHeader {
    /// The data of a C-ordered array of `T` (either byte order), checked against the shape.
    pub fn decode<T: Element>(&self, body: &[u8]) -> Result<Vec<T>, String> {
        let big_endian = match self.descr.strip_suffix(T::CODE) {
            Some("<") => false,
            Some(">") => true,
            Some("=") => cfg!(target_endian = "big"),
            _ => return Err(format!("found dtype {}", self.descr)),
        };
        if self.fortran_order {
            return Err("found a Fortran-ordered array".into());
        }
        let n = self
            .shape
            .iter()
            .try_fold(1u64, |n, &d| n.checked_mul(d))
            .and_then(|n| usize::try_from(n).ok())
            .filter(|n| n.checked_mul(4).is_some())
            .ok_or_else(|| format!("shape {:?} is too large", self.shape))?;
        if body.len() < n * 4 {
            return Err(format!(
                "truncated data: {} bytes for shape {:?}, expected {}",
                body.len(),
                self.shape,
                n * 4
            ));
        }
        if body.len() > n * 4 {
            return Err(format!(
                "{} bytes of trailing data: {} bytes for shape {:?}, expected {}",
                body.len() - n * 4,
                body.len(),
                self.shape,
                n * 4
            ));
        }
        Ok(body[..n * 4]
            .chunks_exact(4)
            .map(|c| {
                let mut b = [c[0], c[1], c[2], c[3]];
                if big_endian {
                    b.reverse();
                }
                T::from_le(b)
            })
            .collect())
    }
}

/// Split a `.npy` file into its header and data (versions 1, 2 and 3 of the format).
pub fn parse_npy(bytes: &[u8]) -> Result<(NpyHeader, &[u8]), String> {
    let rest = bytes
        .strip_prefix(b"\x93NUMPY")
        .ok_or("no .npy magic string")?;
    let version = *rest.first().ok_or("no format version")?;
    let (width, start): (usize, usize) = match version {
        1 => (2, 10),
        2 | 3 => (4, 12),
        v => return Err(format!("unknown format version {v}")),
    };
    // The header length: little-endian u16 (version 1) or u32.
    let len = rest
        .get(2..2 + width)
        .ok_or("truncated header")?
        .iter()
        .rev()
        .fold(0usize, |n, &b| n << 8 | b as usize);
    let text = bytes
        .get(start..start.saturating_add(len))
        .ok_or("truncated header")?;
    let text = std::str::from_utf8(text).map_err(|_| "header is not text")?;
    let header = parse_header(text).map_err(|e| {
        // Quote the header, but not a hostile 60 kB of it.
        let text = text.trim_end();
        match text.char_indices().nth(120) {
            Some((cut, _)) => format!("header `{}…` ({} bytes): {e}", &text[..cut], text.len()),
            None => format!("header `{text}`: {e}"),
        }
    })?;
    Ok((header, &bytes[start + len..]))
}

/// A value of the Python-literal subset that `.npy` headers use.
#[derive(Debug)]
enum Lit<'a> {
    Str(&'a str),
    Int(u64),
    Bool(bool),
    Seq(Vec<Lit<'a>>),
    Dict(Vec<(Lit<'a>, Lit<'a>)>),
    None,
}

/// How deeply a header's literals may nest (numpy's headers nest 3 deep at most, for structured dtypes):
/// the parser recurses, and a hostile header of 60,000 `[` would overflow the stack.
const MAX_NESTING: usize = 16;

struct LitParser<'a> {
    s: &'a str,
    i: usize,
    /// Open brackets around the current position.
    depth: usize,
}

impl<'a> LitParser<'a> {
    fn ws(&mut self) {
        while self.s[self.i..].starts_with(|c: char| c.is_ascii_whitespace()) {
            self.i += 1;
        }
    }

    fn eat(&mut self, c: char) -> bool {
        self.ws();
        let hit = self.s[self.i..].starts_with(c);
        if hit {
            self.i += 1;
        }
        hit
    }

    /// Items up to `close`, separated by commas, a trailing comma allowed.
    fn items<T>(
        &mut self,
        close: char,
        mut item: impl FnMut(&mut Self) -> Result<T, String>,
    ) -> Result<Vec<T>, String> {
        let mut out = Vec::new();
        loop {
            if self.eat(close) {
                return Ok(out);
            }
            out.push(item(self)?);
            if self.eat(close) {
                return Ok(out);
            }
            if !self.eat(',') {
                return Err(format!("expected `,` or `{close}` at byte {}", self.i));
            }
        }
    }

    fn value(&mut self) -> Result<Lit<'a>, String> {
        self.ws();
        let rest = &self.s[self.i..];
        let Some(c) = rest.chars().next() else {
            return Err("unexpected end".into());
        };
        if matches!(c, '(' | '[' | '{') {
            if self.depth >= MAX_NESTING {
                return Err(format!(
                    "nested deeper than {MAX_NESTING} levels at byte {}",
                    self.i
                ));
            }
            self.depth += 1;
            let v = self.nested(c);
            self.depth -= 1;
            return v;
        }
        match c {
            '\'' | '"' => {
                let end = rest[1..]
                    .find(c)
                    .ok_or_else(|| format!("unterminated string at byte {}", self.i))?;
                self.i += end + 2;
                Ok(Lit::Str(&rest[1..=end]))
            }
            _ => {
                let len = rest
                    .find(|c: char| !c.is_ascii_alphanumeric())
                    .unwrap_or(rest.len());
                let word = &rest[..len];
                self.i += len;
                match word {
                    "True" => Ok(Lit::Bool(true)),
                    "False" => Ok(Lit::Bool(false)),
                    "None" => Ok(Lit::None),
                    // Python 2 wrote long integers with an `L`.
                    _ => word
                        .strip_suffix('L')
                        .unwrap_or(word)
                        .parse()
                        .map(Lit::Int)
                        .map_err(|_| format!("unexpected `{word}`")),
                }
            }
        }
    }

    /// A tuple, list or dict opening with `open` (at the current position).
    fn nested(&mut self, open: char) -> Result<Lit<'a>, String> {
        self.i += 1;
        match open {
            '{' => Ok(Lit::Dict(self.items('}', |p| {
                let k = p.value()?;
                if !p.eat(':') {
                    return Err(format!("expected `:` at byte {}", p.i));
                }
                Ok((k, p.value()?))
            })?)),
            '(' => Ok(Lit::Seq(self.items(')', Self::value)?)),
            _ => Ok(Lit::Seq(self.items(']', Self::value)?)),
        }
    }
}

fn parse_header(text: &str) -> Result<NpyHeader, String> {
    let mut p = LitParser {
        s: text,
        i: 0,
        depth: 0,
    };
    let Lit::Dict(entries) = p.value()? else {
        return Err("not a dict".into());
    };
    let (mut descr, mut fortran_order, mut shape) = (None, None, None);
    for (key, value) in entries {
        match (key, value) {
            (Lit::Str("descr"), Lit::Str(d)) => descr = Some(d.to_owned()),
            (Lit::Str("descr"), other) => descr = Some(format!("{other:?}")),
            (Lit::Str("fortran_order"), Lit::Bool(b)) => fortran_order = Some(b),
            (Lit::Str("shape"), Lit::Seq(dims)) => {
                let dims = dims.into_iter().map(|d| match d {
                    Lit::Int(d) => Ok(d),
                    other => Err(format!("bad dimension {other:?}")),
                });
                shape = Some(dims.collect::<Result<Vec<_>, _>>()?);
            }
            (key, _) => return Err(format!("unexpected entry {key:?}")),
        }
    }
    Ok(NpyHeader {
        descr: descr.ok_or("no `descr`")?,
        fortran_order: fortran_order.ok_or("no `fortran_order`")?,
        shape: shape.ok_or("no `shape`")?,
    })
}

/// Write a C-ordered little-endian array of `T` as a version 1.0 `.npy` (the header padded as numpy pads
/// it, so the data starts 64-byte aligned).
pub fn write_npy<T: Element>(
    w: &mut impl Write,
    shape: &[u64],
    data: impl IntoIterator<Item = T>,
) -> std::io::Result<()> {
    let dims: Vec<String> = shape.iter().map(u64::to_string).collect();
    let shape_text = match dims.len() {
        1 => format!("({},)", dims[0]),
        _ => format!("({})", dims.join(", ")),
    };
    let mut header = format!(
        "{{'descr': '<{}', 'fortran_order': False, 'shape': {shape_text}, }}",
        T::CODE
    );
    let total = 10 + header.len() + 1;
    header.extend(std::iter::repeat_n(' ', total.next_multiple_of(64) - total));
    header.push('\n');
    let len = u16::try_from(header.len())
        .map_err(|_| std::io::Error::other("array shape too long for a .npy header"))?;
    w.write_all(b"\x93NUMPY\x01\x00")?;
    w.write_all(&len.to_le_bytes())?;
    w.write_all(header.as_bytes())?;
    let expected: u64 = shape.iter().product();
    let mut written = 0u64;
    for x in data {
        w.write_all(&x.to_le())?;
        written += 1;
    }
    if written != expected {
        return Err(std::io::Error::other(format!(
            "{written} values for shape {shape:?}"
        )));
    }
    Ok(())
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
    let authors = |s: &VoxelStats<D>| s.optimality(latentbki::Spread::AuthorsTVar);
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
    pca: &latentbki::Pca<D, F>,
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

#[cfg(test)]
mod tests {
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
        let h = header(
            "{'descr': [('a', '<f4'), ('b', '<i4')], 'fortran_order': False, 'shape': (3,), }",
        )
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
                err.contains("poses.txt:2")
                    && err.contains(&format!("`{bad}` is not a finite number")),
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
}
