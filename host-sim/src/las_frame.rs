//! A recorded frame as a point cloud file plus its features: `scan.las` (or `.laz`) holds the points, and
//! `scan.npy` beside it an (N, D) float32 array whose row i is the feature of the file's point i.
//!
//! Why an `.npy` beside the cloud rather than LAS extra bytes: features come out of a network as an array,
//! and `numpy.save` writes this file with no LAS rewriting, for any D; 64 extra-byte fields per point would
//! need a LAS writer that declares them, which most tools (PDAL filters, CloudCompare) handle poorly at that
//! width. The cloud keeps its geo-referencing and its CRS, from which the units are read
//! ([`crate::sim::tile::units_of`], `--units` overrides); coordinates become metres relative to a local
//! origin (the first file's minimum corner), as f32 cannot hold geo-referenced centimetres.

use crate::npy_io::{parse_npy, Frame};
use crate::sim::tile::{units_of, LengthUnit, Units};
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};

/// Whether a path names a LAS or LAZ file (by extension).
pub fn is_point_cloud(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("las") || e.eq_ignore_ascii_case("laz"))
}

/// The features file of a point cloud: the same path with the extension `.npy`.
pub fn features_path(cloud: &Path) -> PathBuf {
    cloud.with_extension("npy")
}

/// A point cloud frame in local metres.
#[derive(Clone, Debug)]
pub struct CloudFrame {
    /// Positions (metres from `origin`) and features.
    pub frame: Frame,
    /// The local origin, in the file's units (its minimum corner unless one was given).
    pub origin: [f64; 3],
    /// The units the coordinates were read in.
    pub units: Units,
}

/// Read `cloud` and its features (see the module documentation). `origin` (file units) defaults to the
/// file's minimum corner; `units` overrides the CRS's.
pub fn read_cloud_frame(
    cloud: &Path,
    units: Option<LengthUnit>,
    origin: Option<[f64; 3]>,
) -> Result<CloudFrame> {
    // One line per problem: the file, then what is wrong with it.
    let at = |e: &dyn std::fmt::Display| anyhow::anyhow!("{}: {e}", cloud.display());
    let mut reader = las::Reader::from_path(cloud).map_err(|e| at(&e))?;
    let units = match units {
        Some(u) => Units::uniform(u, "--units"),
        None => units_of(reader.header())
            .map_err(|e| at(&e))?
            .unwrap_or_else(|| {
                Units::uniform(
                    LengthUnit::Metre,
                    "assumed: the file has no CRS; --units to change",
                )
            }),
    };
    let data = reader.read_all().map_err(|e| at(&e))?;
    let origin = origin.unwrap_or_else(|| {
        let b = reader.header().bounds();
        [b.min.x, b.min.y, b.min.z]
    });
    let positions: Vec<[f32; 3]> = data
        .x()
        .zip(data.y())
        .zip(data.z())
        .map(|((x, y), z)| {
            [
                ((x - origin[0]) * units.horizontal) as f32,
                ((y - origin[1]) * units.horizontal) as f32,
                ((z - origin[2]) * units.vertical) as f32,
            ]
        })
        .collect();
    let path = features_path(cloud);
    let bytes = std::fs::read(&path).with_context(|| {
        format!(
            "{}: the features of {} (an (N, D) float32 .npy beside it, row i = point i)",
            path.display(),
            cloud.display()
        )
    })?;
    let (header, body) = parse_npy(&bytes)
        .map_err(|e| anyhow::anyhow!("{}: not a valid .npy file ({e})", path.display()))?;
    let (rows, dim) = match header.shape[..] {
        [n, d] if d >= 1 => (n as usize, d as usize),
        _ => bail!(
            "{}: found shape {:?}; expected (N, D) float32 features, one row per point of {}",
            path.display(),
            header.shape,
            cloud.display()
        ),
    };
    if rows != positions.len() {
        bail!(
            "{}: {rows} feature rows for the {} points of {}",
            path.display(),
            positions.len(),
            cloud.display()
        );
    }
    let features: Vec<f32> = header
        .decode(body)
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    Ok(CloudFrame {
        frame: Frame {
            dim,
            positions,
            features,
        },
        origin,
        units,
    })
}
