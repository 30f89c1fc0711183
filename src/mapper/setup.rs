//! What a [`Mapper`](super::Mapper) is configured with (a `const` [`Setup`]) and why it refuses one.

use crate::classes::ClassPrototypes;
use crate::config::{ConfigError, MapConfig};
#[cfg(feature = "forgetting")]
use crate::forget::Forgetting;
use crate::frame::EncoderSettings;
use crate::quant::{Cooling, MeanWeights};
use crate::wire::{SessionConfig, SummaryCodec, WireError, NO_FEATURE_SPACE};

/// Everything a [`Mapper`](super::Mapper) is configured with; `const`-constructible, so a firmware keeps it in a `static`.
///
/// ```
/// use latentbki::{EncoderSettings, MapConfig, Setup};
///
/// // Robot 3, session 12 (a boot counter); voxels within 2 m of the sensor stay on the device.
/// static SETUP: Setup = Setup::new(MapConfig::DEFAULT, 2.0, EncoderSettings::new(3, 12));
/// assert_eq!((SETUP.link.robot, SETUP.window_radius), (3, 2.0));
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Setup {
    /// Voxel size, kernel, prior.
    pub map: MapConfig,
    /// Radius of the window around the robot (m): voxels farther away are evicted and streamed.
    pub window_radius: f32,
    /// Robot id, session id, how often the session header and link statistics repeat.
    pub link: EncoderSettings,
    /// How summaries are quantized on the wire.
    pub codec: SummaryCodec,
    /// Id of the PCA the features were compressed with ([`crate::wire::feature_space_id`]), or
    /// [`NO_FEATURE_SPACE`].
    pub feature_space: u32,
    /// Scale of int8 features (a code c is the feature value `int8_scale` · c); 0 = the robot gives f32
    /// features only. Sent in the session header.
    pub int8_scale: f32,
    /// How the map cools int8 sums ([`Cooling::NATIVE`] unless a host twin asks for a board's method).
    pub cooling: Cooling,
    /// How the map forgets ([`crate::forget`]; `None`, the default: never). Needs a mapper with the
    /// [`crate::forget::Fading`] clock; sent in the session header. (Only with the `forgetting` feature,
    /// which the link needs to carry stamps.)
    #[cfg(feature = "forgetting")]
    pub forgetting: Option<Forgetting>,
    /// Per-dimension weights of the map's mean codes ([`MeanWeights::ONES`]: one step for all; others need
    /// the `mean-weights` feature and the f32 cooling). The robot's own storage: the wire does not carry them.
    pub mean_weights: MeanWeights,
}

impl Setup {
    /// A setup with the default summary codec and features that are not tied to a PCA.
    pub const fn new(map: MapConfig, window_radius: f32, link: EncoderSettings) -> Self {
        Self {
            map,
            window_radius,
            link,
            codec: SummaryCodec::DEFAULT,
            feature_space: NO_FEATURE_SPACE,
            int8_scale: 0.0,
            cooling: Cooling::NATIVE,
            #[cfg(feature = "forgetting")]
            forgetting: None,
            mean_weights: MeanWeights::ONES,
        }
    }

    /// The same setup forgetting with `forgetting` (a mapper with the [`crate::forget::Fading`] clock).
    #[cfg(feature = "forgetting")]
    pub const fn with_forgetting(self, forgetting: Option<Forgetting>) -> Self {
        Self { forgetting, ..self }
    }

    /// The same setup for a robot whose features are int8 codes: c stands for `scale` · c (e.g. an NPU's
    /// output quantization scale). f32 features stay accepted too.
    pub const fn with_int8_features(self, scale: f32) -> Self {
        Self {
            int8_scale: scale,
            ..self
        }
    }

    /// The same setup declaring the feature space its features were compressed into: the id of the PCA
    /// ([`crate::wire::feature_space_id`]; `host-sim feature-space` prints it and writes it as
    /// `FEATURE_SPACE`). Sent in the session header; the base station refuses to decode the map with
    /// another PCA.
    pub const fn with_feature_space(self, feature_space: u32) -> Self {
        Self {
            feature_space,
            ..self
        }
    }

    /// The same setup for a robot whose features are mixes of `classes`' prototypes
    /// ([`ClassPrototypes::mix`]): their feature space and their int8 scale
    /// ([`Self::with_feature_space`], [`Self::with_int8_features`]).
    pub const fn with_classes<const D: usize, const K: usize>(
        self,
        classes: &ClassPrototypes<D, K>,
    ) -> Self {
        self.with_feature_space(classes.feature_space)
            .with_int8_features(classes.scale)
    }

    /// The same setup cooling int8 sums by `cooling` (a hosted build takes either; bare metal its native).
    pub const fn with_cooling(self, cooling: Cooling) -> Self {
        Self { cooling, ..self }
    }

    /// The same setup with per-dimension weights of the map's mean codes (e.g.
    /// [`MeanWeights::from_spreads`] of the PCA components' spreads).
    pub const fn with_mean_weights(self, mean_weights: MeanWeights) -> Self {
        Self {
            mean_weights,
            ..self
        }
    }

    /// The session configuration a `dim`-dimensional map sends in its header.
    pub fn session(&self, dim: usize) -> SessionConfig {
        let session = SessionConfig::new(&self.map, dim, self.codec, self.feature_space)
            .with_int8_scale(self.int8_scale);
        #[cfg(feature = "forgetting")]
        return session.with_forgetting(self.forgetting);
        #[cfg(not(feature = "forgetting"))]
        return session;
    }
}

/// Why [`Mapper::configure`](super::Mapper::configure) refused a setup.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum SetupError {
    /// The map refused its part (window radius, sub-voxel kernel, …).
    Map(ConfigError),
    /// The encoder refused its part (codec, or buffers too small for one summary).
    Link(WireError),
}

impl core::fmt::Display for SetupError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Map(e) => write!(f, "setup refused by the map: {e}"),
            Self::Link(e) => write!(f, "setup refused by the link encoder: {e}"),
        }
    }
}

impl core::error::Error for SetupError {
    fn source(&self) -> Option<&(dyn core::error::Error + 'static)> {
        match self {
            Self::Map(e) => Some(e),
            Self::Link(e) => Some(e),
        }
    }
}
