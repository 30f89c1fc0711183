//! The simulator: scenes, a robot's trajectory through them, its sensors and a simulated vision-language
//! encoder — everything needed to feed the maps the kind of data a robot produces, with ground truth.
//!
//! Two scenes: the real labelled airborne LiDAR tile ([`tile`]) and a seedable procedural indoor house
//! ([`indoor`]). A [`Sequence`] is what a run of a sensor along a trajectory returns: per frame, the sensor
//! pose and the labelled points it saw (in the map frame). The [`encoder`] turns labels into features the
//! way a segmentation network would, errors included; [`pca`] compresses them to the map's 64 dimensions.

pub mod asprs;
pub mod encoder;
pub mod flight;
pub mod flight_plan;
pub mod indoor;
pub mod pca;
pub mod scale;
pub mod sensor;
pub mod tile;
pub mod trajectory;
pub mod units;
pub mod vocab;
pub mod wkt;

use latentbki::nalgebra::Isometry3;
use latentbki::MapConfig;

/// One point a sensor returned, with its ground truth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LabelledPoint {
    /// Position in the map frame, metres.
    pub position: [f32; 3],
    /// True class: an index into [`Sequence::classes`].
    pub class: u16,
    /// Which object (instance) the point lies on; the encoder's segments are parts of instances.
    pub instance: u32,
}

/// What the sensor saw in one frame.
#[derive(Clone, Debug)]
pub struct ScanFrame {
    /// Sensor → map pose.
    pub pose: Isometry3<f32>,
    /// The points, in the map frame.
    pub points: Vec<LabelledPoint>,
}

/// A sensor run through a scene: the class vocabulary, the map configuration that suits the scene and the
/// frames, in order.
#[derive(Clone, Debug)]
pub struct Sequence {
    /// Short scene name (used in file names and tables).
    pub name: String,
    /// Class phrases; [`LabelledPoint::class`] indexes this list. Each must be in the vocabulary.
    pub classes: Vec<String>,
    /// The map configuration used for this scene (the paper's outdoor or indoor settings).
    pub config: MapConfig,
    /// Frames in time order.
    pub frames: Vec<ScanFrame>,
    /// Height above which voxels are hidden in top-down pictures (a ceiling), if any.
    pub cutaway_height: Option<f32>,
}

impl Sequence {
    /// Total number of points over all frames.
    pub fn points(&self) -> usize {
        self.frames.iter().map(|f| f.points.len()).sum()
    }
}

/// SplitMix64: a small, well-mixed hash used for seeded, order-independent random decisions.
pub fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Hash several words into one.
pub fn mix_all(words: &[u64]) -> u64 {
    words.iter().fold(0x5EED_u64, |h, &w| mix(h ^ w))
}

/// A uniform number in [0, 1) from a hash.
pub fn unit(h: u64) -> f32 {
    (h >> 40) as f32 / (1u64 << 24) as f32
}
