//! The real scene: a labelled airborne LiDAR tile (ASPRS classes), loaded with the `las` crate — the
//! committed tile, or any `.las`/`.laz` a user brings (`--las FILE`).
//!
//! Geo-referenced coordinates are millions of units from the CRS origin: f32 would lose the centimetres
//! there, so a local origin (the tile's minimum corner) is subtracted in f64 first and only then converted
//! to metres and f32. The units come from the file's CRS (the WKT VLR, else the GeoTIFF keys), so a tile
//! in US survey feet (the committed one) and a tile in metres both come out in metres; `--units`
//! overrides. Classes are the ASPRS standard classes by name ([`asprs_phrase`]); reserved and user codes
//! (23–255) become "class N" instead of an error. The committed tile is compiled into the binary, so
//! `demo` works from any directory on a fresh clone.
//!
//! The robot: the tile is already the set of surface points a real LiDAR returned, so a frame is modelled as
//! a re-measurement of it — every tile point within the sensor's range of the pose, randomly subsampled to
//! the sensor's per-frame budget, each displaced by Gaussian range noise along its ray (see
//! [`super::sensor::RangeLidar`]). Occlusion is not simulated (the tile holds first returns only, and each
//! was seen by the survey sensor). The robot flies a closed loop over the tile and follows the terrain
//! ([`TerrainFollowing`]); its range and altitude scale with the tile's point density ([`scaled_sensor`]).

use super::sensor::RangeLidar;
use super::trajectory::ellipse;
use super::{LabelledPoint, ScanFrame, Sequence};
use latentbki::rand_xoshiro::rand_core::SeedableRng;
use latentbki::rand_xoshiro::Xoshiro256PlusPlus;
use latentbki::MapConfig;
use std::collections::HashMap;
use std::io::Cursor;
use std::path::Path;

/// One US survey foot in metres (exactly 1200/3937).
pub const US_SURVEY_FOOT_M: f64 = 1200.0 / 3937.0;
/// One international foot in metres.
pub const FOOT_M: f64 = 0.3048;

/// A length unit of a point cloud's coordinates (`--units`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum LengthUnit {
    /// Metres (EPSG 9001).
    #[value(alias = "m", alias = "meter", alias = "metres", alias = "meters")]
    Metre,
    /// International feet, 0.3048 m (EPSG 9002).
    #[value(alias = "ft", alias = "feet")]
    Foot,
    /// US survey feet, 1200/3937 m (EPSG 9003).
    #[value(alias = "ftus", alias = "us-ft")]
    UsSurveyFoot,
}

impl LengthUnit {
    /// Metres per unit.
    pub fn metres(self) -> f64 {
        match self {
            Self::Metre => 1.0,
            Self::Foot => FOOT_M,
            Self::UsSurveyFoot => US_SURVEY_FOOT_M,
        }
    }
    /// The unit of an EPSG unit code, if it is one of these.
    pub fn from_epsg(code: u16) -> Option<Self> {
        match code {
            9001 => Some(Self::Metre),
            9002 => Some(Self::Foot),
            9003 => Some(Self::UsSurveyFoot),
            _ => None,
        }
    }
    /// A conversion factor read from a WKT, snapped to the exact factor of a known unit (WKT prints
    /// US survey feet as 0.304800609601219).
    fn snap(factor: f64) -> f64 {
        [Self::Metre, Self::Foot, Self::UsSurveyFoot]
            .into_iter()
            .map(Self::metres)
            .find(|m| (factor / m - 1.0).abs() < 1e-9)
            .unwrap_or(factor)
    }
    fn name_of(factor: f64) -> String {
        if factor == 1.0 {
            "metre".into()
        } else if factor == FOOT_M {
            "foot".into()
        } else if factor == US_SURVEY_FOOT_M {
            "US survey foot".into()
        } else {
            format!("{factor} m")
        }
    }
}

/// The units of a tile's coordinates and where they were read.
#[derive(Clone, Debug, PartialEq)]
pub struct Units {
    /// Metres per horizontal (x, y) unit.
    pub horizontal: f64,
    /// Metres per vertical (z) unit.
    pub vertical: f64,
    /// Where the units come from (`WKT`, `GeoTIFF keys`, `--units`, or an assumption).
    pub source: String,
}

impl Units {
    /// One unit for all three axes.
    pub fn uniform(unit: LengthUnit, source: &str) -> Self {
        Self {
            horizontal: unit.metres(),
            vertical: unit.metres(),
            source: source.into(),
        }
    }
    /// "US survey foot (from the WKT)" or "metre horizontally, US survey foot vertically (…)".
    pub fn describe(&self) -> String {
        let (h, v) = (
            LengthUnit::name_of(self.horizontal),
            LengthUnit::name_of(self.vertical),
        );
        if h == v {
            format!("{h} ({})", self.source)
        } else {
            format!("{h} horizontally, {v} vertically ({})", self.source)
        }
    }
}

/// The phrase an ASPRS standard class code decodes to (LAS 1.4 R15, table 17); `None` for reserved
/// (23–63) and user-definable (64–255) codes. Codes 0 and 1 share "unclassified", so a tile with both has
/// one such class. Where the vocabulary already had a phrase for a class (`noise`, `road` …) it is kept.
pub fn asprs_phrase(code: u8) -> Option<&'static str> {
    Some(match code {
        0 | 1 => "unclassified", // 0: created, never classified
        2 => "ground",
        3 => "low vegetation",
        4 => "medium vegetation",
        5 => "high vegetation",
        6 => "building",
        7 => "noise",           // low point (noise)
        8 => "model key point", // reserved in 1.4, model key-point in 1.0–1.3
        9 => "water",
        10 => "rail",
        11 => "road surface",
        12 => "overlap",        // reserved in 1.4, overlap points in 1.0–1.3
        13 => "guard wire",     // wire – guard (shield)
        14 => "conductor wire", // wire – conductor (phase)
        15 => "transmission tower",
        16 => "insulator", // wire-structure connector (e.g. insulator)
        17 => "bridge deck",
        18 => "high noise",
        19 => "overhead structure",
        20 => "ignored ground", // e.g. breakline proximity
        21 => "snow",
        22 => "temporal exclusion",
        _ => return None,
    })
}

/// The class phrase of a code: the ASPRS name, or "class N" for reserved and user codes.
pub fn class_phrase(code: u8) -> String {
    asprs_phrase(code).map_or_else(|| format!("class {code}"), str::to_string)
}

/// Every distinct phrase of the ASPRS standard classes (the vocabulary must hold them all).
pub fn asprs_phrases() -> Vec<&'static str> {
    let mut out: Vec<&'static str> = Vec::new();
    for p in (0..=u8::MAX).filter_map(asprs_phrase) {
        if !out.contains(&p) {
            out.push(p);
        }
    }
    out
}

const BUILTIN: &[u8] = include_bytes!("../../data/file_with_both_wkt_and_geotiff_vlrs.las");

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
}

/// Why the tile could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum TileError {
    /// The LAS reader failed.
    #[error("reading LAS: {0}")]
    Las(#[from] las::Error),
    /// The file holds no point.
    #[error("the file holds no point")]
    Empty,
    /// The coordinates are angles, not lengths.
    #[error("the CRS is geographic ({0}): coordinates are degrees, not lengths; reproject the file to a projected CRS in metres or feet (e.g. `pdal translate in.laz out.laz reprojection --filters.reprojection.out_srs=EPSG:<your UTM zone>`)")]
    Geographic(String),
    /// The CRS names a unit we do not know.
    #[error(
        "the CRS gives the unit {0}, which is not metre, foot or US survey foot: pass --units"
    )]
    UnknownUnit(String),
}

impl Tile {
    /// The tile compiled into the binary (laspy's `file_with_both_wkt_and_geotiff_vlrs.las`).
    pub fn builtin() -> Result<Self, TileError> {
        Self::builtin_in(None)
    }

    /// The built-in tile, its units overridden (`--units` without `--las`).
    pub fn builtin_in(units: Option<LengthUnit>) -> Result<Self, TileError> {
        Self::from_reader(las::Reader::new(Cursor::new(BUILTIN))?, units)
    }

    /// Load a `.las` or `.laz` file; `units` overrides the units its CRS gives.
    pub fn from_path(path: &Path, units: Option<LengthUnit>) -> Result<Self, TileError> {
        Self::from_reader(las::Reader::from_path(path)?, units)
    }

    fn from_reader(mut reader: las::Reader, units: Option<LengthUnit>) -> Result<Self, TileError> {
        let units = match units {
            Some(u) => Units::uniform(u, "--units"),
            None => units_of(reader.header())?.unwrap_or_else(|| {
                Units::uniform(
                    LengthUnit::Metre,
                    "assumed: the file has no CRS; --units to change",
                )
            }),
        };
        let data = reader.read_all()?;
        if data.is_empty() {
            return Err(TileError::Empty);
        }
        let xs: Vec<f64> = data.x().collect();
        let ys: Vec<f64> = data.y().collect();
        let zs: Vec<f64> = data.z().collect();
        let min = |v: &[f64]| v.iter().copied().fold(f64::INFINITY, f64::min);
        let origin = [min(&xs), min(&ys), min(&zs)];
        // Classes in order of their smallest code (for the committed tile: 2–7, as the tables list them).
        let mut present = [false; 256];
        for code in data.classification() {
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
        let (h, v) = (units.horizontal, units.vertical);
        let mut points = Vec::with_capacity(xs.len());
        let mut classes = Vec::with_capacity(xs.len());
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for (i, code) in data.classification().enumerate() {
            let p = [
                ((xs[i] - origin[0]) * h) as f32,
                ((ys[i] - origin[1]) * h) as f32,
                ((zs[i] - origin[2]) * v) as f32,
            ];
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
            points.push(p);
            classes.push(index_of[usize::from(code)]);
        }
        Ok(Self {
            points,
            classes,
            names,
            codes,
            origin,
            bounds: (lo, hi),
            units,
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

    /// One line describing the tile: points, extent, units, classes with their counts.
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
        format!(
            "{} points, {:.1} × {:.1} × {:.1} m, units {}; ASPRS classes: {}",
            self.points.len(),
            hi[0] - lo[0],
            hi[1] - lo[1],
            hi[2] - lo[2],
            self.units.describe(),
            classes.join(", ")
        )
    }
}

/// The units a LAS header's CRS gives: the WKT VLR first (LAS 1.4's CRS record), else the GeoTIFF keys;
/// `None` when the file has neither.
pub fn units_of(header: &las::Header) -> Result<Option<Units>, TileError> {
    if let Some(bytes) = header.get_wkt_crs_bytes() {
        let wkt = String::from_utf8_lossy(bytes);
        let wkt = wkt.trim_end_matches('\0');
        if let Some(units) = wkt_units(wkt)? {
            return Ok(Some(units));
        }
    }
    let Ok(Some(geotiff)) = header.get_geotiff_crs() else {
        return Ok(None);
    };
    let key = |id: u16| {
        geotiff.entries.iter().find_map(|e| match e.data {
            las::crs::GeoTiffData::U16(v) if e.id == id => Some(v),
            _ => None,
        })
    };
    // GTModelTypeGeoKey 2 = geographic (lat/long).
    if key(1024) == Some(2) {
        return Err(TileError::Geographic("GeoTIFF model type 2".into()));
    }
    let unit = |id: u16| -> Result<Option<f64>, TileError> {
        match key(id) {
            None => Ok(None),
            Some(code) => LengthUnit::from_epsg(code)
                .map(|u| Some(u.metres()))
                .ok_or_else(|| TileError::UnknownUnit(format!("EPSG:{code}"))),
        }
    };
    // ProjLinearUnitsGeoKey, VerticalUnitsGeoKey.
    let (h, v) = (unit(3076)?, unit(4099)?);
    Ok(match (h.or(v), key(3072)) {
        (Some(h), _) => Some(Units {
            horizontal: h,
            vertical: v.unwrap_or(h),
            source: "from the GeoTIFF keys".into(),
        }),
        // A projected CRS named only by its EPSG code: most are metric, and we carry no EPSG table.
        (None, Some(code)) => Some(Units::uniform(
            LengthUnit::Metre,
            &format!("assumed: the GeoTIFF keys name EPSG:{code} but no unit; --units to change"),
        )),
        (None, None) => None,
    })
}

/// A node of a WKT: `KEYWORD[arg, …]`.
#[derive(Debug)]
struct WktNode {
    key: String,
    numbers: Vec<f64>,
    strings: Vec<String>,
    children: Vec<WktNode>,
}

/// Parse WKT (1 or 2) into its node tree; `None` if it is not well formed.
fn parse_wkt(text: &str) -> Option<WktNode> {
    fn skip(s: &[u8], i: &mut usize) {
        while *i < s.len() && s[*i].is_ascii_whitespace() {
            *i += 1;
        }
    }
    fn node(s: &[u8], i: &mut usize) -> Option<WktNode> {
        skip(s, i);
        let start = *i;
        while *i < s.len() && (s[*i].is_ascii_alphanumeric() || s[*i] == b'_') {
            *i += 1;
        }
        let key = String::from_utf8_lossy(&s[start..*i]).to_uppercase();
        let mut n = WktNode {
            key,
            numbers: Vec::new(),
            strings: Vec::new(),
            children: Vec::new(),
        };
        skip(s, i);
        if *i >= s.len() || !(s[*i] == b'[' || s[*i] == b'(') {
            return Some(n); // a bare word (WKT2 axis directions, …)
        }
        *i += 1;
        loop {
            skip(s, i);
            match s.get(*i)? {
                b']' | b')' => {
                    *i += 1;
                    return Some(n);
                }
                b',' => *i += 1,
                b'"' => {
                    *i += 1;
                    let mut v = Vec::new();
                    loop {
                        match s.get(*i)? {
                            b'"' if s.get(*i + 1) == Some(&b'"') => {
                                v.push(b'"');
                                *i += 2;
                            }
                            b'"' => {
                                *i += 1;
                                break;
                            }
                            &c => {
                                v.push(c);
                                *i += 1;
                            }
                        }
                    }
                    n.strings.push(String::from_utf8_lossy(&v).into_owned());
                }
                c if c.is_ascii_digit() || *c == b'-' || *c == b'+' || *c == b'.' => {
                    let start = *i;
                    while *i < s.len() && !matches!(s[*i], b',' | b']' | b')') {
                        *i += 1;
                    }
                    let t = String::from_utf8_lossy(&s[start..*i]);
                    n.numbers.push(t.trim().parse().ok()?);
                }
                _ => n.children.push(node(s, i)?),
            }
        }
    }
    let mut i = 0;
    node(text.as_bytes(), &mut i)
}

impl WktNode {
    fn find(&self, keys: &[&str]) -> Option<&WktNode> {
        if keys.contains(&self.key.as_str()) {
            return Some(self);
        }
        self.children.iter().find_map(|c| c.find(keys))
    }
    /// The length unit of a CRS node: its own `UNIT`/`LENGTHUNIT`, else its axes' (WKT2).
    fn length_unit(&self) -> Option<&WktNode> {
        fn own(n: &WktNode) -> Option<&WktNode> {
            n.children
                .iter()
                .find(|c| c.key == "UNIT" || c.key == "LENGTHUNIT")
        }
        own(self).or_else(|| {
            self.children
                .iter()
                .filter(|c| c.key == "AXIS" || c.key == "CS")
                .find_map(own)
        })
    }
}

/// Metres per unit from a WKT's projected and vertical CRS.
fn wkt_units(wkt: &str) -> Result<Option<Units>, TileError> {
    let Some(root) = parse_wkt(wkt) else {
        return Ok(None);
    };
    let factor = |n: &WktNode| -> Result<f64, TileError> {
        match n.numbers.first() {
            Some(&f) if f.is_finite() && f > 0.0 => Ok(LengthUnit::snap(f)),
            _ => Err(TileError::UnknownUnit(format!(
                "{:?} without a conversion factor",
                n.strings.first().map_or("", String::as_str)
            ))),
        }
    };
    let projected = root.find(&["PROJCS", "PROJCRS", "PROJECTEDCRS"]);
    let vertical = root.find(&["VERT_CS", "VERTCRS", "VERTICALCRS"]);
    let h = match projected.and_then(WktNode::length_unit) {
        Some(u) => Some(factor(u)?),
        None => None,
    };
    let v = match vertical.and_then(WktNode::length_unit) {
        Some(u) => Some(factor(u)?),
        None => None,
    };
    if projected.is_none() {
        if let Some(g) = root.find(&["GEOGCS", "GEOGCRS", "GEOGRAPHICCRS"]) {
            return Err(TileError::Geographic(
                g.strings.first().cloned().unwrap_or_default(),
            ));
        }
    }
    Ok(h.map(|h| Units {
        horizontal: h,
        vertical: v.unwrap_or(h),
        source: "from the WKT".into(),
    }))
}

/// The sensor, scaled to the tile: a range whose sphere holds about four frames' budget of points at the
/// tile's mean density (never below the default 10 m, which the committed tile uses), and a flying height
/// above the ground of a fifth of the range (2 m at 10 m).
pub fn scaled_sensor(tile: &Tile, points_per_frame: usize) -> (f32, f32) {
    let default = RangeLidar::default().range_m;
    let density = tile.points.len() as f32 / tile.area().max(1e-6);
    let range = (4.0 * points_per_frame as f32 / (std::f32::consts::PI * density)).sqrt();
    let range = if range.is_finite() {
        range.max(default)
    } else {
        default
    };
    (range, range / 5.0)
}

/// Terrain following: the robot flies `altitude` above the lowest terrain point and leaves that height
/// only where the local ground (the median height of the terrain points within `altitude` of it,
/// horizontally; within the 3 × 3 cells of that size around it if there are none that close) would bring
/// it closer than `altitude / 2` or farther than `3 · altitude / 2`: it then holds the nearest edge of that
/// band. A deadband, as terrain-following autopilots use, so it does
/// not chase every bump: on a flat tile (the committed one: its ground spans 0.43 m) it flies level, and on
/// relief it stays between half and one and a half times its altitude above the ground beneath it.
pub struct TerrainFollowing {
    cell: f32,
    lo: [f32; 2],
    cells: HashMap<(i32, i32), Vec<[f32; 3]>>,
    floor: f32,
    altitude: f32,
}

impl TerrainFollowing {
    /// The terrain of `tile` for a flight `altitude` above it.
    pub fn new(tile: &Tile, altitude: f32) -> Self {
        let cell = altitude.max(0.05);
        let lo = [tile.bounds.0[0], tile.bounds.0[1]];
        let mut cells: HashMap<(i32, i32), Vec<[f32; 3]>> = HashMap::new();
        let terrain = tile.terrain_points();
        for p in &terrain {
            let k = (
                ((p[0] - lo[0]) / cell).floor() as i32,
                ((p[1] - lo[1]) / cell).floor() as i32,
            );
            cells.entry(k).or_default().push(*p);
        }
        let floor = terrain.iter().map(|p| p[2]).fold(f32::INFINITY, f32::min);
        Self {
            cell,
            lo,
            cells,
            floor,
            altitude,
        }
    }

    /// The local ground height around (x, y), if there is terrain nearby.
    pub fn ground(&self, x: f32, y: f32) -> Option<f32> {
        let (cx, cy) = (
            ((x - self.lo[0]) / self.cell).floor() as i32,
            ((y - self.lo[1]) / self.cell).floor() as i32,
        );
        let near: Vec<[f32; 3]> = (-1..=1)
            .flat_map(|dx| (-1..=1).map(move |dy| (cx + dx, cy + dy)))
            .filter_map(|k| self.cells.get(&k))
            .flatten()
            .copied()
            .collect();
        let r2 = self.cell * self.cell;
        let mut z: Vec<f32> = near
            .iter()
            .filter(|p| (p[0] - x).powi(2) + (p[1] - y).powi(2) <= r2)
            .map(|p| p[2])
            .collect();
        if z.is_empty() {
            z = near.iter().map(|p| p[2]).collect();
        }
        if z.is_empty() {
            return None;
        }
        let k = z.len() / 2;
        z.select_nth_unstable_by(k, f32::total_cmp);
        Some(z[k])
    }

    /// The flying height over (x, y).
    pub fn height(&self, x: f32, y: f32) -> f32 {
        let level = self.floor + self.altitude;
        match self.ground(x, y) {
            Some(g) if self.floor.is_finite() => {
                level.clamp(g + 0.5 * self.altitude, g + 1.5 * self.altitude)
            }
            _ => level,
        }
    }
}

/// How the robot observes the tile.
#[derive(Clone, Copy, Debug)]
pub struct TileRun {
    /// Number of frames (poses on the loop).
    pub frames: usize,
    /// The sensor.
    pub lidar: RangeLidar,
    /// Flying height above the ground, metres (see [`TerrainFollowing`]).
    pub altitude: f32,
    /// Seed of the per-frame subsampling and range noise.
    pub seed: u64,
    /// Start of the loop, as a fraction of a turn (a different phase gives a different sequence).
    pub phase: f32,
    /// The map configuration the sequence asks for.
    pub config: MapConfig,
}

impl Default for TileRun {
    fn default() -> Self {
        Self {
            frames: 60,
            lidar: RangeLidar::default(),
            altitude: 2.0,
            seed: 1,
            phase: 0.0,
            config: MapConfig::default(),
        }
    }
}

/// The robot's run through the tile: a closed loop over the middle 60 % of the tile, terrain-following.
/// The default map configuration is the paper's outdoor one (0.1 m, ℓ = 0.5 m, f = 3).
pub fn sequence(tile: &Tile, run: &TileRun) -> Sequence {
    let (lo, hi) = tile.bounds;
    let centre = [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0];
    let radii = [(hi[0] - lo[0]) * 0.3, (hi[1] - lo[1]) * 0.3];
    let terrain = TerrainFollowing::new(tile, run.altitude);
    let z = tile.ground_height() + run.altitude;
    let n = run.frames.max(1);
    let loop_poses = ellipse(centre, radii, z, n * 8);
    let offset = (run.phase.rem_euclid(1.0) * (n * 8) as f32) as usize;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(run.seed);
    let instances: Vec<u32> = tile.classes.iter().map(|&c| u32::from(c)).collect();
    let frames = (0..n)
        .map(|i| {
            let mut pose = loop_poses[(offset + i * 8) % loop_poses.len()];
            let t = &mut pose.translation.vector;
            t.z = terrain.height(t.x, t.y);
            let points: Vec<LabelledPoint> =
                run.lidar
                    .scan(&tile.points, &tile.classes, &instances, &pose, &mut rng);
            ScanFrame { pose, points }
        })
        .collect();
    Sequence {
        name: "tile".into(),
        classes: tile.class_names(),
        config: run.config,
        frames,
        cutaway_height: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wkt_units_of_projected_and_compound_crs() {
        let ftus = r#"COMPD_CS["x",PROJCS["NAD83(2011) / Nebraska (ftUS)",GEOGCS["NAD83(2011)",DATUM["D",SPHEROID["GRS 1980",6378137,298.257222101]],UNIT["degree",0.0174532925199433]],PROJECTION["Lambert_Conformal_Conic_2SP"],PARAMETER["false_easting",1640416.6667],UNIT["US survey foot",0.304800609601219,AUTHORITY["EPSG","9003"]],AXIS["X",EAST]],VERT_CS["NAVD88 height (m)",VERT_DATUM["North American Vertical Datum 1988",2005],UNIT["metre",1.0]]]"#;
        let u = wkt_units(ftus).unwrap().unwrap();
        assert_eq!(u.horizontal, US_SURVEY_FOOT_M);
        assert_eq!(u.vertical, 1.0);
        let wkt2 = r#"PROJCRS["WGS 84 / UTM zone 33N",BASEGEOGCRS["WGS 84",ANGLEUNIT["degree",0.0174532925199433]],CONVERSION["UTM zone 33N",PARAMETER["False easting",500000,LENGTHUNIT["metre",1]]],CS[Cartesian,2],AXIS["(E)",east,ORDER[1],LENGTHUNIT["metre",1]],AXIS["(N)",north,ORDER[2],LENGTHUNIT["metre",1]],ID["EPSG",32633]]"#;
        let u = wkt_units(wkt2).unwrap().unwrap();
        assert_eq!((u.horizontal, u.vertical), (1.0, 1.0));
        let geo = r#"GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],UNIT["degree",0.0174532925199433]]"#;
        assert!(matches!(wkt_units(geo), Err(TileError::Geographic(_))));
        let odd = r#"PROJCS["x",UNIT["link",0.201168]]"#;
        assert_eq!(wkt_units(odd).unwrap().unwrap().horizontal, 0.201168);
    }

    #[test]
    fn every_code_has_a_name() {
        assert_eq!(class_phrase(1), "unclassified");
        assert_eq!(class_phrase(0), "unclassified");
        assert_eq!(class_phrase(9), "water");
        assert_eq!(class_phrase(17), "bridge deck");
        assert_eq!(class_phrase(23), "class 23");
        assert_eq!(class_phrase(64), "class 64");
        assert_eq!(class_phrase(255), "class 255");
        assert_eq!(asprs_phrases().len(), 22);
        // The committed table embeds every one of them.
        let vocab = super::super::vocab::Vocabulary::builtin();
        for p in asprs_phrases() {
            vocab.get(p).unwrap();
        }
    }

    #[test]
    fn builtin_units_come_from_its_crs() {
        let t = Tile::builtin().unwrap();
        assert_eq!(t.units.horizontal, US_SURVEY_FOOT_M);
        assert_eq!(t.units.vertical, US_SURVEY_FOOT_M);
        assert_eq!(t.units.source, "from the WKT");
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
    fn builtin_flies_level_and_keeps_its_range() {
        // The committed tile is flat (its ground spans 0.43 m): the terrain following leaves the old
        // level flight (2 m above the lowest ground point) unchanged, so its figures do not move.
        let t = Tile::builtin().unwrap();
        assert_eq!(scaled_sensor(&t, 3000), (10.0, 2.0));
        let seq = sequence(&t, &TileRun::default());
        let level = t.ground_height() + 2.0;
        assert!(seq
            .frames
            .iter()
            .all(|f| f.pose.translation.vector.z == level));
    }
}
