//! The real scene: a labelled airborne LiDAR tile (ASPRS classes), loaded with the `las` crate.
//!
//! The tile is in US survey feet, geo-referenced about 2.4 million feet from the CRS origin: f32 would lose
//! the centimetres there, so a local origin (the tile's minimum corner) is subtracted in f64 first and only
//! then converted to metres and f32. The file is compiled into the binary, so `demo` works from any
//! directory on a fresh clone.
//!
//! The robot: the tile is already the set of surface points a real LiDAR returned, so a frame is modelled as
//! a re-measurement of it — every tile point within the sensor's range of the pose, randomly subsampled to
//! the sensor's per-frame budget, each displaced by Gaussian range noise along its ray (see
//! [`super::sensor::RangeLidar`]). Occlusion is not simulated (the tile holds first returns only, and each
//! was seen by the survey sensor). The robot flies a closed loop 2 m above the tile's lowest ground point.

use super::sensor::RangeLidar;
use super::trajectory::ellipse;
use super::{LabelledPoint, ScanFrame, Sequence};
use latentbki::rand_xoshiro::rand_core::SeedableRng;
use latentbki::rand_xoshiro::Xoshiro256PlusPlus;
use latentbki::MapConfig;
use std::io::Cursor;

/// One US survey foot in metres (exactly 1200/3937).
pub const US_SURVEY_FOOT_M: f64 = 1200.0 / 3937.0;

/// ASPRS class codes present in the tile and the phrase each one decodes to.
pub const ASPRS_CLASSES: [(u8, &str); 6] = [
    (2, "ground"),
    (3, "low vegetation"),
    (4, "medium vegetation"),
    (5, "high vegetation"),
    (6, "building"),
    (7, "noise"),
];

const BUILTIN: &[u8] = include_bytes!("../../data/file_with_both_wkt_and_geotiff_vlrs.las");

/// A labelled point cloud in local metres.
#[derive(Clone, Debug)]
pub struct Tile {
    /// Positions relative to [`Self::origin`], metres.
    pub points: Vec<[f32; 3]>,
    /// Class index into [`ASPRS_CLASSES`] per point.
    pub classes: Vec<u16>,
    /// The local origin in the file's CRS units (US survey feet), subtracted before conversion.
    pub origin: [f64; 3],
    /// Minimum and maximum corner in local metres.
    pub bounds: ([f32; 3], [f32; 3]),
}

/// Why the tile could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum TileError {
    /// The LAS reader failed.
    #[error("reading LAS: {0}")]
    Las(#[from] las::Error),
    /// A point has an ASPRS class the scene does not know.
    #[error("point {index} has ASPRS class {code}, which is not one of {known:?}")]
    UnknownClass {
        /// Point index.
        index: usize,
        /// Its class code.
        code: u8,
        /// The supported codes.
        known: Vec<u8>,
    },
}

impl Tile {
    /// The tile compiled into the binary (laspy's `file_with_both_wkt_and_geotiff_vlrs.las`).
    pub fn builtin() -> Result<Self, TileError> {
        Self::from_reader(las::Reader::new(Cursor::new(BUILTIN))?)
    }

    /// Load any LAS file whose classes are among [`ASPRS_CLASSES`] and whose units are US survey feet.
    pub fn from_path(path: &std::path::Path) -> Result<Self, TileError> {
        Self::from_reader(las::Reader::from_path(path)?)
    }

    fn from_reader(mut reader: las::Reader) -> Result<Self, TileError> {
        let data = reader.read_all()?;
        let xs: Vec<f64> = data.x().collect();
        let ys: Vec<f64> = data.y().collect();
        let zs: Vec<f64> = data.z().collect();
        let min = |v: &[f64]| v.iter().copied().fold(f64::INFINITY, f64::min);
        let origin = [min(&xs), min(&ys), min(&zs)];
        let mut points = Vec::with_capacity(xs.len());
        let mut classes = Vec::with_capacity(xs.len());
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for (i, code) in data.classification().enumerate() {
            let class = ASPRS_CLASSES
                .iter()
                .position(|(c, _)| *c == code)
                .ok_or_else(|| TileError::UnknownClass {
                    index: i,
                    code,
                    known: ASPRS_CLASSES.iter().map(|(c, _)| *c).collect(),
                })?;
            let p = [
                ((xs[i] - origin[0]) * US_SURVEY_FOOT_M) as f32,
                ((ys[i] - origin[1]) * US_SURVEY_FOOT_M) as f32,
                ((zs[i] - origin[2]) * US_SURVEY_FOOT_M) as f32,
            ];
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
            points.push(p);
            classes.push(class as u16);
        }
        Ok(Self {
            points,
            classes,
            origin,
            bounds: (lo, hi),
        })
    }

    /// The class phrases, in class-index order.
    pub fn class_names() -> Vec<String> {
        ASPRS_CLASSES.iter().map(|(_, n)| n.to_string()).collect()
    }

    /// Lowest ground point's height (local metres).
    pub fn ground_height(&self) -> f32 {
        self.points
            .iter()
            .zip(&self.classes)
            .filter(|(_, &c)| c == 0)
            .map(|(p, _)| p[2])
            .fold(f32::INFINITY, f32::min)
    }
}

/// How the robot observes the tile.
#[derive(Clone, Copy, Debug)]
pub struct TileRun {
    /// Number of frames (poses on the loop).
    pub frames: usize,
    /// The sensor.
    pub lidar: RangeLidar,
    /// Seed of the per-frame subsampling and range noise.
    pub seed: u64,
    /// Start of the loop, as a fraction of a turn (a different phase gives a different sequence).
    pub phase: f32,
}

impl Default for TileRun {
    fn default() -> Self {
        Self {
            frames: 60,
            lidar: RangeLidar::default(),
            seed: 1,
            phase: 0.0,
        }
    }
}

/// The robot's run through the tile with the paper's outdoor map configuration (0.1 m, ℓ = 0.5 m, f = 3).
pub fn sequence(tile: &Tile, run: &TileRun) -> Sequence {
    let (lo, hi) = tile.bounds;
    let centre = [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0];
    let radii = [(hi[0] - lo[0]) * 0.3, (hi[1] - lo[1]) * 0.3];
    let z = tile.ground_height() + 2.0;
    let n = run.frames.max(1);
    let loop_poses = ellipse(centre, radii, z, n * 8);
    let offset = (run.phase.rem_euclid(1.0) * (n * 8) as f32) as usize;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(run.seed);
    let instances: Vec<u32> = tile.classes.iter().map(|&c| u32::from(c)).collect();
    let frames = (0..n)
        .map(|i| {
            let pose = loop_poses[(offset + i * 8) % loop_poses.len()];
            let points: Vec<LabelledPoint> =
                run.lidar
                    .scan(&tile.points, &tile.classes, &instances, &pose, &mut rng);
            ScanFrame { pose, points }
        })
        .collect();
    Sequence {
        name: "tile".into(),
        classes: Tile::class_names(),
        config: MapConfig::default(),
        frames,
        cutaway_height: None,
    }
}
