//! The real scene: a labelled airborne LiDAR tile (ASPRS classes), loaded with the `las` crate — the
//! committed tile, or any `.las`/`.laz` a user brings (`--las FILE`; LAS 1.0–1.4, every point format,
//! COPC read as plain LAZ, VLRs and EVLRs, extra bytes ignored).
//!
//! What real surveys deliver, and what the reader does about it:
//! - **Geo-referenced coordinates** millions of units from the CRS origin: f32 would lose the centimetres
//!   there, so a local origin (the points' minimum corner) is subtracted in f64 first and only then
//!   converted to metres and f32. The units come from the CRS ([`super::units`]); `--units` overrides.
//! - **Header bounds that disagree with the points**: the extent is taken from the points; the summary
//!   notes the disagreement.
//! - **Stray points far from the survey** (a point at (0, 0, 0), a bird 2 km up) would stretch the tile
//!   to thousands of kilometres and the robot would see nothing: points farther than the bulk's own
//!   width outside its 1st–99th percentiles (horizontally; three widths and at least 50 m vertically) are
//!   dropped, and counted in the summary.
//! - **Withheld points** (the flag says "treat as deleted") are dropped and counted.
//! - **Large files**: at most `max_points` points are kept — every k-th point in file order, which is scan
//!   order, so the subsample covers the tile evenly — and the summary says so.
//! - **Classes**: the ASPRS names ([`super::asprs`]); 0 and 1 are both "unclassified"; reserved and user
//!   codes (LAS 1.4 allows up to 255) become "class N". Tiles with one class (the summary says the
//!   accuracy columns then mean nothing) or without ground are kept:
//!   the flight then follows every non-noise point.
//!
//! The committed tile is compiled into the binary, so `demo` works from any directory on a fresh clone.
//!
//! Reading the file's points (the decoder's failures, stray points, header checks) is `las_points`; this
//! module turns them into a [`Tile`] in metres with classes and a summary.

mod las_points;
pub mod survey;

pub use super::asprs::{asprs_phrase, asprs_phrases, class_phrase};
pub use super::flight::{sequence, TerrainFollowing, TileRun};
pub use super::scale::scaled_sensor;
pub use super::units::{units_of, CrsError, LengthUnit, Units, FOOT_M, US_SURVEY_FOOT_M};
use las_points::{
    header_disagrees, las_error, quietly, read_points, uncompressed_points_in, with_the_bulk,
};
use std::collections::HashSet;
use std::io::Cursor;
use std::path::Path;

const BUILTIN: &[u8] = include_bytes!("../../../data/file_with_both_wkt_and_geotiff_vlrs.las");

/// Points kept from a file by default (every k-th beyond it): ≈ 30 MB in memory, a minute of evaluation.
pub const DEFAULT_MAX_POINTS: usize = 2_000_000;

/// A labelled point cloud in local metres.
#[derive(Clone, Debug)]
pub struct Tile {
    /// Positions relative to [`Self::origin`], metres.
    pub points: Vec<[f32; 3]>,
    /// Class index into [`Self::names`] per point.
    pub classes: Vec<u16>,
    /// Class phrases, in order of their smallest ASPRS code.
    pub names: Vec<String>,
    /// The ASPRS codes of each class (two for "unclassified" when both 0 and 1 occur).
    pub codes: Vec<Vec<u8>>,
    /// The local origin in the file's CRS units, subtracted before conversion.
    pub origin: [f64; 3],
    /// Minimum and maximum corner in local metres.
    pub bounds: ([f32; 3], [f32; 3]),
    /// The units the coordinates were read in.
    pub units: Units,
    /// Horizontal point spacing, metres: 1/√density over the area the points occupy.
    pub spacing: f32,
    /// Points the file holds.
    pub file_points: u64,
    /// What the reader changed or noticed (subsampling, dropped points, header bounds), one phrase each.
    pub notes: Vec<String>,
}

/// How to read a file.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReadOptions {
    /// Overrides the units the CRS gives.
    pub units: Option<LengthUnit>,
    /// Keep at most this many points (every k-th).
    pub max_points: usize,
}

impl Default for ReadOptions {
    fn default() -> Self {
        Self {
            units: None,
            max_points: DEFAULT_MAX_POINTS,
        }
    }
}

/// Why the tile could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum TileError {
    /// The LAS reader failed.
    #[error("reading LAS: {}", las_error(.0))]
    Las(#[from] las::Error),
    /// The file does not start with the LAS signature.
    #[error(
        "not a LAS or LAZ file (it does not start with \"LASF\"); give a .las/.laz point cloud"
    )]
    NotLas,
    /// The LAZ decoder gave up on the file.
    #[error("the LAZ decoder cannot read this file ({0}); decompress it with another tool first (`pdal translate in.laz out.las`, or LAStools' `laszip -i in.laz -o out.las`)")]
    Decoder(String),
    /// The file holds no point (or none that is not withheld).
    #[error("the file holds no point{0}")]
    Empty(String),
    /// The coordinates are not lengths.
    #[error(transparent)]
    Crs(#[from] CrsError),
}

/// Horizontal point spacing (metres): 1/√density, the density counted in cells of twice the spacing that
/// hold a point, iterated from the bounding box's density.
pub fn measure_spacing(points: &[[f32; 3]]) -> f32 {
    let n = points.len().max(1) as f64;
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in points {
        for a in 0..2 {
            lo[a] = lo[a].min(f64::from(p[a]));
            hi[a] = hi[a].max(f64::from(p[a]));
        }
    }
    let (w, h) = ((hi[0] - lo[0]).max(0.0), (hi[1] - lo[1]).max(0.0));
    if points.len() < 2 || w.max(h) <= 0.0 {
        return 1.0; // one position: nothing to measure; any scale maps it
    }
    // A strip (one side zero) spreads its points along its length.
    let mut s = if w * h > 0.0 {
        (w * h / n).sqrt()
    } else {
        w.max(h) / n
    };
    for _ in 0..3 {
        // Cells no smaller than 1/4000 of the tile's side: at most 16 M cells.
        let cell = (2.0 * s).max(w.max(h) / 4000.0);
        let occupied: HashSet<(i64, i64)> = points
            .iter()
            .map(|p| {
                (
                    ((f64::from(p[0]) - lo[0]) / cell) as i64,
                    ((f64::from(p[1]) - lo[1]) / cell) as i64,
                )
            })
            .collect();
        s = (occupied.len() as f64 * cell * cell / n).sqrt();
    }
    s as f32
}

impl Tile {
    /// The tile compiled into the binary (laspy's `file_with_both_wkt_and_geotiff_vlrs.las`).
    pub fn builtin() -> Result<Self, TileError> {
        Self::builtin_in(None)
    }

    /// The built-in tile, its units overridden (`--units` without `--las`).
    pub fn builtin_in(units: Option<LengthUnit>) -> Result<Self, TileError> {
        let options = ReadOptions {
            units,
            ..ReadOptions::default()
        };
        Self::from_reader(las::Reader::new(Cursor::new(BUILTIN))?, &options)
    }

    /// Load a `.las` or `.laz` file; `units` overrides the units its CRS gives.
    pub fn from_path(path: &Path, units: Option<LengthUnit>) -> Result<Self, TileError> {
        let options = ReadOptions {
            units,
            ..ReadOptions::default()
        };
        Self::read(path, &options)
    }

    /// Load a `.las` or `.laz` file as `options` say.
    ///
    /// A panic inside the LAZ decoder (the `laz` crate panics on some old LASzip variants, e.g. variable
    /// chunks without a chunk table) becomes an error here: the file is unusable, which is the user's
    /// problem to solve (decompress it with another tool), not a bug of ours.
    pub fn read(path: &Path, options: &ReadOptions) -> Result<Self, TileError> {
        let mut magic = [0u8; 4];
        let n = std::fs::File::open(path)
            .and_then(|mut f| std::io::Read::read(&mut f, &mut magic))
            .map_err(las::Error::from)?;
        if n < 4 || &magic != b"LASF" {
            return Err(TileError::NotLas);
        }
        let available = uncompressed_points_in(path);
        quietly(|| Self::from_reader_with(las::Reader::from_path(path)?, options, available))
            .unwrap_or_else(|why| Err(TileError::Decoder(why)))
    }

    fn from_reader(reader: las::Reader, options: &ReadOptions) -> Result<Self, TileError> {
        Self::from_reader_with(reader, options, None)
    }

    fn from_reader_with(
        mut reader: las::Reader,
        options: &ReadOptions,
        available: Option<u64>,
    ) -> Result<Self, TileError> {
        let units = match options.units {
            Some(u) => Units::uniform(u, "--units"),
            None => units_of(reader.header())?.unwrap_or_else(|| {
                Units::uniform(
                    LengthUnit::Metre,
                    "assumed: the file has no CRS; --units to change",
                )
            }),
        };
        let raw = read_points(&mut reader, options.max_points, available)?;
        let mut notes = Vec::new();
        if let Some(a) = available.filter(|&a| a < raw.file_points) {
            notes.push(format!(
                "the file is truncated: it holds {a} of the {} points its header announces",
                raw.file_points
            ));
        }
        if raw.stride > 1 {
            notes.push(format!(
                "kept every {} of its {} points (--max-points {})",
                ordinal(raw.stride),
                raw.file_points,
                options.max_points
            ));
        }
        if raw.withheld > 0 {
            notes.push(format!("dropped {} withheld points", raw.withheld));
        }
        if raw.xyz.is_empty() {
            let why = if raw.withheld > 0 {
                " that is not withheld".to_string()
            } else {
                String::new()
            };
            return Err(TileError::Empty(why));
        }
        let metres = [units.horizontal, units.horizontal, units.vertical];
        let bulk = with_the_bulk(&raw.xyz, metres);
        let strays = bulk.iter().filter(|k| !**k).count();
        if strays > 0 {
            notes.push(format!(
                "dropped {strays} stray points far outside the survey's extent"
            ));
        }
        let kept = || {
            raw.xyz
                .iter()
                .zip(&raw.codes)
                .zip(&bulk)
                .filter(|(_, k)| **k)
                .map(|(p, _)| p)
        };
        let mut origin = [f64::INFINITY; 3];
        let mut far = [f64::NEG_INFINITY; 3];
        for (p, _) in kept() {
            for a in 0..3 {
                origin[a] = origin[a].min(p[a]);
                far[a] = far[a].max(p[a]);
            }
        }
        if let Some(note) = header_disagrees(&reader.header().bounds(), origin, far, metres) {
            notes.push(note);
        }
        // Classes in order of their smallest code (for the committed tile: 2–7, as the tables list them).
        let mut present = [false; 256];
        for (_, &code) in kept() {
            present[usize::from(code)] = true;
        }
        let mut names: Vec<String> = Vec::new();
        let mut codes: Vec<Vec<u8>> = Vec::new();
        let mut index_of = [0u16; 256];
        for code in (0..=u8::MAX).filter(|&c| present[usize::from(c)]) {
            let phrase = class_phrase(code);
            let i = match names.iter().position(|n| *n == phrase) {
                Some(i) => i,
                None => {
                    names.push(phrase);
                    codes.push(Vec::new());
                    names.len() - 1
                }
            };
            codes[i].push(code);
            index_of[usize::from(code)] = i as u16;
        }
        if let [only] = names.as_slice() {
            // Raw surveys often come unclassified (0/1): the map and its queries still work, but every
            // method labels every voxel with the one class, so the tables' accuracy says nothing.
            notes.push(format!(
                "one class only ({only}): every method scores 100 % by construction, so the accuracy \
                 columns say nothing; classify the file first (e.g. PDAL's filters.smrf or LAStools' \
                 lasground) for a meaningful table"
            ));
        }
        let mut points = Vec::with_capacity(raw.xyz.len());
        let mut classes = Vec::with_capacity(raw.xyz.len());
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for (p, &code) in kept() {
            let p = [
                ((p[0] - origin[0]) * metres[0]) as f32,
                ((p[1] - origin[1]) * metres[1]) as f32,
                ((p[2] - origin[2]) * metres[2]) as f32,
            ];
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
            points.push(p);
            classes.push(index_of[usize::from(code)]);
        }
        let spacing = measure_spacing(&points);
        Ok(Self {
            points,
            classes,
            names,
            codes,
            origin,
            bounds: (lo, hi),
            units,
            spacing,
            file_points: raw.file_points,
            notes,
        })
    }

    /// The class phrases, in class-index order.
    pub fn class_names(&self) -> Vec<String> {
        self.names.clone()
    }

    /// Points per class, in class-index order.
    pub fn histogram(&self) -> Vec<usize> {
        let mut h = vec![0; self.names.len()];
        for &c in &self.classes {
            h[usize::from(c)] += 1;
        }
        h
    }

    /// The points the terrain is estimated from: the ground class (ASPRS 2), or, in a tile without one,
    /// every point that is not noise.
    pub fn terrain_points(&self) -> Vec<[f32; 3]> {
        let pick = |want: &dyn Fn(&str) -> bool| -> Vec<[f32; 3]> {
            self.points
                .iter()
                .zip(&self.classes)
                .filter(|(_, &c)| want(&self.names[usize::from(c)]))
                .map(|(p, _)| *p)
                .collect()
        };
        let ground = pick(&|n| n == "ground");
        if ground.is_empty() {
            pick(&|n| n != "noise" && n != "high noise")
        } else {
            ground
        }
    }

    /// Lowest terrain point's height (local metres).
    pub fn ground_height(&self) -> f32 {
        self.terrain_points()
            .iter()
            .map(|p| p[2])
            .fold(f32::INFINITY, f32::min)
    }

    /// Horizontal area of the bounding box, m².
    pub fn area(&self) -> f32 {
        let (lo, hi) = self.bounds;
        (hi[0] - lo[0]) * (hi[1] - lo[1])
    }

    /// One line describing the tile: points, extent, spacing, units, classes with their counts, and what
    /// the reader changed.
    pub fn summary(&self) -> String {
        let (lo, hi) = self.bounds;
        let classes: Vec<String> = self
            .names
            .iter()
            .zip(&self.codes)
            .zip(self.histogram())
            .map(|((n, c), k)| {
                let c: Vec<String> = c.iter().map(u8::to_string).collect();
                format!("{} {n} ({k})", c.join("+"))
            })
            .collect();
        let mut line = format!(
            "{} points, {:.1} × {:.1} × {:.1} m, ≈ {} m apart, units {}; ASPRS classes: {}",
            self.points.len(),
            hi[0] - lo[0],
            hi[1] - lo[1],
            hi[2] - lo[2],
            significant(self.spacing),
            self.units.describe(),
            classes.join(", ")
        );
        for n in &self.notes {
            line += "; ";
            line += n;
        }
        line
    }
}

/// Three significant digits, for lengths from millimetres to kilometres.
pub fn significant(x: f32) -> String {
    if !(x.is_finite() && x > 0.0) {
        return format!("{x}");
    }
    let decimals = (2 - x.log10().floor() as i32).clamp(0, 6) as usize;
    format!("{x:.decimals$}")
}

/// "2nd", "50th".
fn ordinal(n: u64) -> String {
    let suffix = match (n % 10, n % 100) {
        (1, r) if r != 11 => "st",
        (2, r) if r != 12 => "nd",
        (3, r) if r != 13 => "rd",
        _ => "th",
    };
    format!("{n}{suffix}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_units_come_from_its_crs() {
        let t = Tile::builtin().unwrap();
        assert_eq!(t.units.horizontal, US_SURVEY_FOOT_M);
        assert_eq!(t.units.vertical, US_SURVEY_FOOT_M);
        assert_eq!(t.units.source, "from the WKT");
        assert!(t.notes.is_empty(), "{:?}", t.notes);
        // data/README.md: mean spacing 1/√density ≈ 0.094 m over the 18.28 × 12.19 m box it fills.
        assert!((t.spacing - 0.094).abs() < 0.004, "{}", t.spacing);
        // Its GeoTIFF keys agree (ProjLinearUnits = VerticalUnits = 9003).
        let r = las::Reader::new(Cursor::new(BUILTIN)).unwrap();
        let mut b = las::Builder::from(r.header().clone());
        b.vlrs.retain(|v| !v.is_wkt_crs());
        b.evlrs.retain(|v| !v.is_wkt_crs());
        let g = units_of(&b.clone().into_header().unwrap())
            .unwrap()
            .unwrap();
        assert_eq!(
            (g.horizontal, g.vertical),
            (US_SURVEY_FOOT_M, US_SURVEY_FOOT_M)
        );
        assert_eq!(g.source, "from the GeoTIFF keys");
        b.vlrs.clear();
        b.evlrs.clear();
        assert_eq!(units_of(&b.into_header().unwrap()).unwrap(), None);
    }

    #[test]
    fn spacing_counts_the_occupied_area_only() {
        // A 100 × 100 grid at 0.5 m; a 500 × 20 grid turned 45° (and stretched √2: 0.71 m apart) along the
        // diagonal of a box 18 times its area.
        let grid: Vec<[f32; 3]> = (0..10_000)
            .map(|i| [(i % 100) as f32 * 0.5, (i / 100) as f32 * 0.5, 0.0])
            .collect();
        assert!(
            (measure_spacing(&grid) - 0.5).abs() < 0.03,
            "{}",
            measure_spacing(&grid)
        );
        let strip: Vec<[f32; 3]> = (0..10_000)
            .map(|i| {
                let (u, v) = ((i % 500) as f32 * 0.5, (i / 500) as f32 * 0.5);
                [u + v, u - v + 250.0, 0.0]
            })
            .collect();
        let s = measure_spacing(&strip);
        assert!((s - 0.707).abs() < 0.05, "{s}");
        // Degenerate: one position, or a line.
        assert_eq!(measure_spacing(&[[1.0, 2.0, 3.0]; 5]), 1.0);
        let line: Vec<[f32; 3]> = (0..100).map(|i| [i as f32 * 0.2, 0.0, 0.0]).collect();
        assert!(measure_spacing(&line) > 0.0);
        assert_eq!(ordinal(2), "2nd");
        assert_eq!(ordinal(11), "11th");
        assert_eq!(ordinal(50), "50th");
        assert_eq!(significant(0.0943), "0.0943");
        assert_eq!(significant(12.34), "12.3");
        assert_eq!(significant(1234.0), "1234");
    }
}
