//! Watch the map live in Foxglove (or Lichtblick), and record it as MCAP: a Foxglove WebSocket server and
//! MCAP writer beside ingest, through Foxglove's SDK (crate `foxglove`).
//!
//! **Representation: `foxglove.SceneUpdate` cubes, one entity per 8 × 8 × 8-voxel block** ([`scene`]).
//! Foxglove keys scene entities by id on a topic, so an update replaces exactly the blocks whose voxels
//! changed and nothing else — incremental updates are what this schema is for. A `foxglove.PointCloud`
//! is 7× smaller per voxel (16 B against ≈ 113 B) but replaces the whole cloud on every message: at 100k
//! voxels each update would be the full 1.6 MB, however few voxels changed. Cubes also show voxels as
//! what they are (a side of the voxel size, in metres, at any zoom), and Foxglove draws each entity's
//! cubes as one instanced mesh, so 100k cubes are ~200 draw calls. Measured (`host-sim view-bench`): the
//! full scene of a 100k-voxel map is one ≈ 12 MB message per layer; each block's entity is encoded once
//! and kept until it changes, so a late joiner's scene is those bytes joined (goal ≤ 50 ms).
//!
//! **Topics** (frame `map`): [`Layer::Classes`] `/map/classes`, [`Layer::Heat`] `/map/heat`,
//! [`Layer::Uncertainty`] `/map/uncertainty`, [`Layer::Robots`] `/map/robots` (`foxglove.SceneUpdate`,
//! protobuf); [`LEGEND_TOPIC`] (each class's name, colour and voxels; the phrase in force) and
//! [`STATUS_TOPIC`] (the link's counters and the viewer's own), JSON; [`FRAME_TOPIC`], the map's centre as a
//! frame a 3D panel follows; [`HEAT_CLOUD_TOPIC`], the heat once more as one point cloud that repaints fast. Classes take their natural colours where they have one (ground brown,
//! vegetation green, …: `export::class_colour`, the demo's figures' table), else a palette by index. The
//! map decodes once a [`Vocabulary`] is known — at the start (`--pca`) or later
//! ([`Viewer::set_vocabulary`]: the demo learns its robot's feature space after the view has started);
//! every voxel is then decoded again and re-sent. The query phrase is the Foxglove parameter
//! [`guard::QUERY_PARAMETER`]; setting it re-scores every voxel and re-sends the heat layer whole.
//!
//! **Clients**: the server is Foxglove's SDK behind a [`front`] door that also accepts the protocol's
//! classic name `foxglove.websocket.v1`, which the SDK alone refuses (older Foxglove and Lichtblick).
//! **Recording**: whole scenes at intervals, so that a reader that seeks sees the map (module `recording`).
//!
//! **Flow.** Ingest never waits on the view: it copies the voxels a frame changed into an inbox (a map
//! keyed by voxel, so a burst coalesces and the inbox never outgrows the map) under a lock held only for
//! the copy, and carries on. The view thread wakes at most `rate_hz` times a second, applies the inbox to
//! its own copy of the map, re-decodes the voxels within the kernel's reach of each change and sends the
//! blocks that changed. A client that subscribes gets the whole layer at once (late joiners see the full
//! map). Each client has its own bounded queue in the SDK (`backlog` messages; the oldest are dropped
//! when a client does not read), so a stalled client costs bounded memory and nothing else.

mod cloud;
pub mod front;
pub mod guard;
mod live;
mod recording;
pub mod scene;
mod shared;
mod worker;

pub use cloud::{heat_cloud, HEAT_CLOUD_TOPIC};
/// The Foxglove SDK the view is built on (its message types, for callers of [`DecodedMap`]).
pub use foxglove;
pub use live::Viewer;
pub use scene::{BlockKey, DecodedMap, Layer, VoxelRow};
pub use shared::RecordingSummary;
pub use worker::ViewerSummary;

use latentbki::decode::Codebook;
use std::net::SocketAddr;
use std::path::PathBuf;

/// The legend topic: JSON `{"classes": [{"index", "name", "rgb", "hex", "voxels"}], "query": phrase, ...}`.
pub const LEGEND_TOPIC: &str = "/map/legend";
/// The link's counters and the viewer's own, JSON.
pub const STATUS_TOPIC: &str = "/link/status";
/// `foxglove.FrameTransforms`: where [`CENTRE_FRAME`] is in the map's frame.
pub const FRAME_TOPIC: &str = "/tf";
/// A frame at the centre of the map's extent (5th to 95th percentile of its voxels on each axis), so that a
/// 3D panel that follows it (the committed layout does) looks at the map, wherever it lies.
pub const CENTRE_FRAME: &str = "map_centre";
/// Where the live view listens unless told otherwise (loopback only).
pub const DEFAULT_ADDR: &str = "127.0.0.1:8765";

/// Turns a phrase into a one-entry query codebook (the base station's text table and the robots' PCA).
pub type PhraseEncoder<const D: usize, const K: usize> =
    Box<dyn Fn(&str) -> Result<Codebook<D, K>, String> + Send>;

/// What decodes the map: the class names and their codebook (the robots' feature space), and the encoder
/// of the phrases clients type.
pub struct Vocabulary<const D: usize, const K: usize> {
    /// Class names, in codebook order.
    pub names: Vec<String>,
    /// The classes' text embeddings in the robots' feature space.
    pub codebook: Codebook<D, K>,
    /// Encodes the phrases clients set (None: the heat layer stays empty).
    pub phrases: Option<PhraseEncoder<D, K>>,
    /// The feature-space id of the PCA behind the codebook: a map whose robots declared another one is
    /// not decoded with it (its classes would be meaningless); the legend says why. None: not checked.
    pub feature_space: Option<u32>,
}

/// How the view runs.
pub struct ViewOptions<const D: usize, const K: usize> {
    /// Serve Foxglove's WebSocket protocol here (None: no server).
    pub listen: Option<SocketAddr>,
    /// Write the topics to this MCAP file.
    pub record: Option<PathBuf>,
    /// At most this many view updates a second.
    pub rate_hz: f64,
    /// Messages queued per client before the oldest are dropped.
    pub backlog: usize,
    /// What decodes the map (None: voxels are grey, no class, until [`Viewer::set_vocabulary`]).
    pub vocabulary: Option<Vocabulary<D, K>>,
    /// The phrase in force at the start.
    pub phrase: Option<String>,
}

impl<const D: usize, const K: usize> ViewOptions<D, K> {
    /// Defaults: no server, no recording, 10 updates/s, 64 messages per client.
    pub fn new() -> Self {
        Self {
            listen: None,
            record: None,
            rate_hz: 10.0,
            backlog: 64,
            vocabulary: None,
            phrase: None,
        }
    }
}

impl<const D: usize, const K: usize> Default for ViewOptions<D, K> {
    fn default() -> Self {
        Self::new()
    }
}

/// Why the view could not start or finish.
#[derive(Debug, thiserror::Error)]
pub enum ViewError {
    /// The WebSocket server did not start (address in use, not local, …).
    #[error("the live view cannot listen on {addr}: {error}")]
    Listen {
        /// Where.
        addr: SocketAddr,
        /// Why.
        error: String,
    },
    /// The recording could not be written.
    #[error("cannot write the recording {path}: {error}")]
    Record {
        /// The file.
        path: String,
        /// Why.
        error: foxglove::FoxgloveError,
    },
    /// A phrase could not be encoded.
    #[error("query: {0}")]
    Phrase(String),
}
