//! Map configuration: the few numbers that define a LatentBKI map.
//!
//! Everything that two maps must agree on before they can be merged lives here (voxel size, kernel length,
//! filter size, priors, kernel mode). It is validated once, at construction, so the hot path never
//! re-checks it.

/// Default feature dimension after PCA (the paper compresses 512-d CLIP/LSeg features to 64).
pub const DEFAULT_DIM: usize = 64;

/// Largest supported filter size f (f³ = 343 neighbours).
pub const MAX_FILTER_SIZE: u8 = 7;

/// Largest supported sub-voxel resolution (cells per axis) in [`KernelMode::SubVoxel`].
pub const MAX_SUBVOXEL_CELLS: u8 = 8;

/// Normal-inverse-Wishart prior of an unobserved voxel, the same scalar on every feature dimension.
///
/// The defaults (λ₀ = 0, μ₀ = 0, Ψ₀ = 1) are those of the authors' released code: a non-informative
/// confidence, so the posterior mean is the kernel-weighted average of the observations.
///
/// ```
/// use latentbki::{KernelMode, MapConfig, Prior};
///
/// // A confident prior: 2 pseudo-points of mean 0 and scatter 0.5 in every dimension.
/// let prior = Prior { lambda: 2.0, mean: 0.0, psi: 0.5 };
/// let config = MapConfig::new(0.1, 0.5, 3, prior, KernelMode::VoxelOffset).unwrap();
/// assert_eq!(config.prior(), prior);
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Prior {
    /// λ₀: prior confidence (a weighted pseudo-count), ≥ 0.
    pub lambda: f32,
    /// μ₀: prior mean of every feature dimension.
    pub mean: f32,
    /// Ψ₀: prior diagonal scatter of every feature dimension, ≥ 0.
    pub psi: f32,
}

impl Prior {
    /// λ₀ = 0, μ₀ = 0, Ψ₀ = 1.
    pub const DEFAULT: Self = Self {
        lambda: 0.0,
        mean: 0.0,
        psi: 1.0,
    };
}

impl Default for Prior {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// How the kernel distance between a point and a neighbouring voxel is measured.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum KernelMode {
    /// Distance = |voxel offset| · voxel size: every point of a voxel weighs the same on each neighbour.
    /// This is what the authors' released configurations use, and it lets a batch be grouped by voxel.
    VoxelOffset,
    /// The point's position inside its voxel is quantized to `cells`³ sub-cells; the distance goes from the
    /// sub-cell centre to each neighbour's centroid.
    SubVoxel {
        /// Sub-cells per axis, 1..=[`MAX_SUBVOXEL_CELLS`].
        cells: u8,
    },
}

impl KernelMode {
    /// The mode from a sub-voxel cell count, as configuration files and the wire carry it: 0 is
    /// [`KernelMode::VoxelOffset`]. (The inverse is [`MapConfig::subvoxel_cells`], which gives 1 there.)
    pub const fn from_subvoxel_cells(cells: u8) -> Self {
        match cells {
            0 => Self::VoxelOffset,
            cells => Self::SubVoxel { cells },
        }
    }
}

/// A complete, validated map configuration. Construct with [`MapConfig::new`] or [`MapConfig::default`].
///
/// ```
/// use latentbki::{KernelMode, MapConfig, Prior};
///
/// // 5 cm voxels, kernel length 0.3 m, a 3³ filter: validated when the constant is built.
/// const FINE: MapConfig = match MapConfig::new(0.05, 0.3, 3, Prior::DEFAULT, KernelMode::VoxelOffset) {
///     Ok(c) => c,
///     Err(_) => panic!("invalid map configuration"),
/// };
/// assert_eq!((FINE.voxel_size(), FINE.filter_size()), (0.05, 3));
/// assert!(MapConfig::new(0.05, 0.3, 4, Prior::DEFAULT, KernelMode::VoxelOffset).is_err()); // f is odd
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MapConfig {
    voxel_size: f32,
    kernel_length: f32,
    filter_size: u8,
    prior: Prior,
    mode: KernelMode,
}

/// Why a [`MapConfig`] was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ConfigError {
    /// The voxel size must be finite and > 0.
    VoxelSize,
    /// The kernel length ℓ must be finite and > 0.
    KernelLength,
    /// The filter size f must be odd and in 1..=[`MAX_FILTER_SIZE`].
    FilterSize,
    /// λ₀ and Ψ₀ must be finite and ≥ 0, μ₀ finite.
    Prior,
    /// Sub-voxel cells must be in 1..=[`MAX_SUBVOXEL_CELLS`].
    SubVoxelCells,
    /// The kernel table does not fit the capacity chosen for it.
    LutCapacity,
    /// A local map's window radius must be at least one voxel and at most 16,000 voxels.
    Window,
    /// The on-device map stores per-voxel observation statistics, which cannot express the sub-voxel
    /// kernel (it weighs each point by its position inside its voxel).
    SubVoxelOnDevice,
    /// The scale of int8 features must be finite and > 0, and small enough that no feature exceeds
    /// [`crate::batch::FEATURE_LIMIT`].
    Int8Scale,
    /// This build does not link the requested cooling method ([`crate::quant::Cooling::is_built`]).
    Cooling,
    /// Forgetting asked of a map that keeps no stamps ([`crate::forget::Timeless`]: use
    /// [`crate::forget::Fading`]).
    Forgetting,
    /// Mean weights ([`crate::quant::MeanWeights`]) must have non-decreasing breakpoints in 1..D, and a
    /// build with the `mean-weights` feature.
    MeanWeights,
    /// The fixed-point cooling ([`crate::quant::Cooling::Fixed`]) codes every dimension on one step: a map
    /// with mean weights cools in f32.
    MeanWeightsFixedCooling,
}

impl core::fmt::Display for ConfigError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::VoxelSize => "voxel size must be finite and > 0",
            Self::KernelLength => "kernel length must be finite and > 0",
            Self::FilterSize => "filter size must be odd and between 1 and 7",
            Self::Prior => "prior: lambda and psi must be finite and >= 0, mean finite",
            Self::SubVoxelCells => "sub-voxel cells per axis must be between 1 and 8",
            Self::LutCapacity => "kernel lookup table capacity too small for this configuration",
            Self::Window => "window radius must be between 1 and 16000 voxels",
            Self::SubVoxelOnDevice => {
                "the on-device map needs the voxel-offset kernel (sub-voxel cells = 0)"
            }
            Self::Int8Scale => {
                "int8 feature scale must be finite, > 0 and at most FEATURE_LIMIT / (127 sqrt(D))"
            }
            Self::Cooling => "this build does not link the requested cooling method",
            Self::Forgetting => "this map never forgets: give it the Fading clock to forget",
            Self::MeanWeights => {
                "mean weights: breakpoints must be non-decreasing and in 1..D, in a build with feature mean-weights"
            }
            Self::MeanWeightsFixedCooling => {
                "mean weights need the f32 cooling (the fixed-point cooling codes every dimension on one step)"
            }
        })
    }
}

impl core::error::Error for ConfigError {}

impl Default for MapConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl MapConfig {
    /// The paper's outdoor configuration: 0.1 m voxels, ℓ = 0.5 m, f = 3, offset-distance kernel, default prior.
    pub const DEFAULT: Self = Self {
        voxel_size: 0.1,
        kernel_length: 0.5,
        filter_size: 3,
        prior: Prior::DEFAULT,
        mode: KernelMode::VoxelOffset,
    };

    /// All-zero placeholder of an unconfigured map (so a `static` map is zero-initialised, in .bss).
    pub(crate) const UNCONFIGURED: Self = Self {
        voxel_size: 0.0,
        kernel_length: 0.0,
        filter_size: 0,
        prior: Prior {
            lambda: 0.0,
            mean: 0.0,
            psi: 0.0,
        },
        mode: KernelMode::VoxelOffset,
    };

    /// Validate and build a configuration. A `const fn`: a firmware validates its configuration at compile
    /// time (`const MAP: MapConfig = match MapConfig::new(…) { Ok(c) => c, Err(_) => panic!(…) };`).
    pub const fn new(
        voxel_size: f32,
        kernel_length: f32,
        filter_size: u8,
        prior: Prior,
        mode: KernelMode,
    ) -> Result<Self, ConfigError> {
        if !(voxel_size.is_finite() && voxel_size > 0.0) {
            return Err(ConfigError::VoxelSize);
        }
        if !(kernel_length.is_finite() && kernel_length > 0.0) {
            return Err(ConfigError::KernelLength);
        }
        if filter_size == 0 || filter_size.is_multiple_of(2) || filter_size > MAX_FILTER_SIZE {
            return Err(ConfigError::FilterSize);
        }
        let prior_ok = prior.lambda.is_finite()
            && prior.lambda >= 0.0
            && prior.psi.is_finite()
            && prior.psi >= 0.0
            && prior.mean.is_finite();
        if !prior_ok {
            return Err(ConfigError::Prior);
        }
        if let KernelMode::SubVoxel { cells } = mode {
            if cells == 0 || cells > MAX_SUBVOXEL_CELLS {
                return Err(ConfigError::SubVoxelCells);
            }
        }
        Ok(Self {
            voxel_size,
            kernel_length,
            filter_size,
            prior,
            mode,
        })
    }

    /// The local map's window radius (m) for a sensor whose returns reach `sensor_range` metres: the range,
    /// plus two voxels for the rounding of the point's and the sensor's voxel keys (the window is measured
    /// between keys; a return outside it is refused), plus the kernel's reach, so the voxels a far return
    /// updates through the kernel stay in the window while it is taken. A `const fn`, for a `static`
    /// [`crate::Setup`].
    pub const fn window_for_range(&self, sensor_range: f32) -> f32 {
        sensor_range + (self.filter_size / 2 + 2) as f32 * self.voxel_size
    }

    /// Edge length of a voxel in metres.
    pub fn voxel_size(&self) -> f32 {
        self.voxel_size
    }
    /// Kernel length ℓ in metres: the kernel is zero at and beyond it.
    pub fn kernel_length(&self) -> f32 {
        self.kernel_length
    }
    /// Filter size f: a point updates the f³ voxels centred on its own.
    pub fn filter_size(&self) -> u8 {
        self.filter_size
    }
    /// Half-width of the filter, (f − 1) / 2.
    pub fn reach(&self) -> i32 {
        i32::from(self.filter_size / 2)
    }
    /// The prior of an unobserved voxel.
    pub fn prior(&self) -> Prior {
        self.prior
    }
    /// How kernel distances are measured.
    pub fn mode(&self) -> KernelMode {
        self.mode
    }
    /// Sub-cells per axis (1 in voxel-offset mode).
    pub fn subvoxel_cells(&self) -> u8 {
        match self.mode {
            KernelMode::VoxelOffset => 1,
            KernelMode::SubVoxel { cells } => cells,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_bad_values() {
        let p = Prior::default();
        let m = KernelMode::VoxelOffset;
        assert_eq!(
            MapConfig::new(0.0, 0.5, 3, p, m),
            Err(ConfigError::VoxelSize)
        );
        assert_eq!(
            MapConfig::new(f32::NAN, 0.5, 3, p, m),
            Err(ConfigError::VoxelSize)
        );
        assert_eq!(
            MapConfig::new(0.1, -1.0, 3, p, m),
            Err(ConfigError::KernelLength)
        );
        assert_eq!(
            MapConfig::new(0.1, 0.5, 2, p, m),
            Err(ConfigError::FilterSize)
        );
        assert_eq!(
            MapConfig::new(0.1, 0.5, 9, p, m),
            Err(ConfigError::FilterSize)
        );
        let bad = Prior { lambda: -1.0, ..p };
        assert_eq!(MapConfig::new(0.1, 0.5, 3, bad, m), Err(ConfigError::Prior));
        let sub = KernelMode::SubVoxel { cells: 0 };
        assert_eq!(
            MapConfig::new(0.1, 0.5, 3, p, sub),
            Err(ConfigError::SubVoxelCells)
        );
        assert!(MapConfig::new(0.1, 0.5, 5, p, KernelMode::SubVoxel { cells: 4 }).is_ok());
    }
}
