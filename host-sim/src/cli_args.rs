//! Option groups that several commands share (one definition each, flattened into the commands).

use crate::sim::tile::{LengthUnit, ReadOptions, DEFAULT_MAX_POINTS};
use anyhow::Result;
use clap::Args;
use latentbki::{KernelMode, MapConfig, Prior};
use std::path::PathBuf;

/// The map configuration, shared by every command that builds a map.
#[derive(Args, Debug, Clone)]
pub struct MapArgs {
    /// Voxel edge length in metres [default: 0.1; with --las, from the file's point spacing].
    #[arg(long, allow_negative_numbers = true)]
    pub voxel_size: Option<f32>,
    /// Kernel length ℓ in metres [default: 0.5; with --las, five voxels (the paper's ratio)].
    #[arg(long, allow_negative_numbers = true)]
    pub kernel_length: Option<f32>,
    /// Filter size f (odd, 1..=7): a point updates f³ voxels.
    #[arg(long, default_value_t = 3)]
    pub filter_size: u8,
    /// Prior confidence λ₀.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub prior_lambda: f32,
    /// Prior mean μ₀ (every dimension).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub prior_mean: f32,
    /// Prior scatter Ψ₀ (every dimension).
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
    pub prior_psi: f32,
    /// Sub-voxel kernel: cells per axis for the point's position inside its voxel (0 = voxel-offset kernel).
    #[arg(long, default_value_t = 0)]
    pub subvoxel_cells: u8,
}

/// The paper's outdoor voxel size (metres), the default when no data decides it.
pub const DEFAULT_VOXEL_SIZE: f32 = 0.1;

impl MapArgs {
    /// The validated configuration: the given voxel size and kernel length, by default the paper's
    /// outdoor 0.1 m and 0.5 m.
    pub fn config(&self) -> Result<MapConfig> {
        self.build(
            self.voxel_size.unwrap_or(DEFAULT_VOXEL_SIZE),
            self.kernel_length.unwrap_or(5.0 * DEFAULT_VOXEL_SIZE),
        )
    }

    /// Whether the user gave the voxel size or the kernel length (else the data may choose them).
    pub fn scale_given(&self) -> bool {
        self.voxel_size.is_some() || self.kernel_length.is_some()
    }

    /// The validated configuration with the voxel size `voxel` unless one was given; the kernel length as
    /// given, else five voxels.
    pub fn config_with_voxel(&self, voxel: f32) -> Result<MapConfig> {
        let voxel = self.voxel_size.unwrap_or(voxel);
        let kernel = self
            .kernel_length
            .unwrap_or(crate::sim::scale::KERNEL_VOXELS * voxel);
        self.build(voxel, kernel)
    }

    fn build(&self, voxel: f32, kernel: f32) -> Result<MapConfig> {
        let prior = Prior {
            lambda: self.prior_lambda,
            mean: self.prior_mean,
            psi: self.prior_psi,
        };
        let mode = KernelMode::from_subvoxel_cells(self.subvoxel_cells);
        MapConfig::new(voxel, kernel, self.filter_size, prior, mode)
            .map_err(|e| anyhow::anyhow!("invalid map configuration: {e}"))
    }
}

impl Default for MapArgs {
    /// The command-line defaults (the paper's outdoor configuration).
    fn default() -> Self {
        Self {
            voxel_size: None,
            kernel_length: None,
            filter_size: 3,
            prior_lambda: 0.0,
            prior_mean: 0.0,
            prior_psi: 1.0,
            subvoxel_cells: 0,
        }
    }
}

/// Which point cloud the tile scene maps and how the robot flies over it (`demo`, `eval`, `query`).
#[derive(Args, Debug, Clone, Default, PartialEq)]
pub struct TileArgs {
    /// A labelled point cloud (.las or .laz, ASPRS classes) to map instead of the built-in tile.
    #[arg(long, value_name = "FILE")]
    pub las: Option<PathBuf>,
    /// Units of the file's coordinates [default: from its CRS (WKT, else GeoTIFF keys); metres if it has
    /// none].
    #[arg(long, value_enum)]
    pub units: Option<LengthUnit>,
    /// Sensor range in metres [default: scaled to the tile's point density, at least 10 m].
    #[arg(long, allow_negative_numbers = true)]
    pub range: Option<f32>,
    /// Flying height above the ground in metres [default: a fifth of the range].
    #[arg(long, allow_negative_numbers = true)]
    pub altitude: Option<f32>,
    /// Keep at most this many of the file's points (every k-th, in file order) [default: 2000000].
    #[arg(long)]
    pub max_points: Option<usize>,
    /// How the robot flies: `survey` (laps over every cell that holds points, as many as the built-in
    /// tile's revisits; frames planned from the tile unless --frames) or `loop` (over the middle 60 %)
    /// [default: survey with --las, loop on the built-in tile].
    #[arg(long, value_enum)]
    pub flight: Option<FlightArg>,
    /// How the map scale is chosen when --voxel-size and --kernel-length are not given: `validate`
    /// (candidates from the point spacing scored on a validation split of the integrated points) or
    /// `spacing` (voxel ≈ spacing, ℓ = 5 voxels) [default: validate with --las; the built-in tile keeps
    /// the paper's 0.1 m / 0.5 m unless asked].
    #[arg(long, value_enum)]
    pub scale: Option<ScaleArg>,
}

/// How the robot flies over the tile.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum FlightArg {
    /// Laps of a survey over every cell that holds points, planned so that each surface is observed by
    /// about as many frames as on the built-in tile.
    Survey,
    /// A closed loop over the middle 60 % of the tile (the built-in tile's flight).
    Loop,
}

/// How the tile's map scale is chosen when it is not given.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ScaleArg {
    /// Candidates from the point spacing, scored on a validation split of the integrated points.
    Validate,
    /// Voxel ≈ point spacing, ℓ = 5 voxels (the rule before validation).
    Spacing,
}

impl TileArgs {
    /// Refuse ranges and heights that cannot fly.
    pub fn check(&self) -> Result<()> {
        anyhow::ensure!(
            self.max_points != Some(0),
            "--max-points must be at least 1"
        );
        for (name, v) in [("--range", self.range), ("--altitude", self.altitude)] {
            if let Some(v) = v {
                anyhow::ensure!(
                    v.is_finite() && v > 0.0,
                    "{name} must be a positive number of metres, got {v}"
                );
            }
        }
        Ok(())
    }
}

impl TileArgs {
    /// Whether the robot flies the revisiting survey (the default with `--las`).
    pub fn survey(&self) -> bool {
        self.flight
            .map_or(self.las.is_some(), |f| f == FlightArg::Survey)
    }

    /// How to read `--las`.
    pub fn read_options(&self) -> ReadOptions {
        ReadOptions {
            units: self.units,
            max_points: self.max_points.unwrap_or(DEFAULT_MAX_POINTS),
        }
    }
}
