//! What ingest's side ([`super::live`]) and the view thread ([`super::worker`]) share: the inbox ingest
//! fills under a short lock, the wake-up, the query phrase in force, and the channels the view publishes
//! on. Its own module so that neither side reaches into the other.

use super::guard::ViewRequests;
use super::scene::Layer;
use super::Vocabulary;
use crate::base_station::ReceiveStats;
use crate::global_map::GlobalVoxel;
use crate::session::SessionState;
use foxglove::{Context, RawChannel, Schema, SinkId};
use latentbki::key::VoxelKey;
use latentbki::wire::SessionConfig;
use std::collections::{BTreeMap, HashMap};
use std::sync::mpsc::Sender;
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::time::Instant;

/// Arrival times kept per view update at most (a flood of tiny chunks must not grow the inbox).
pub(super) const MAX_ARRIVALS: usize = 4096;
/// Latency samples kept at most.
pub(super) const MAX_SAMPLES: usize = 1 << 20;

/// The link's counters as ingest last saw them.
pub(super) type LinkCounters = (ReceiveStats, BTreeMap<(u16, u32), SessionState>);

/// What the recording wrote, when it was closed.
#[derive(Clone, Debug, Default)]
pub struct RecordingSummary {
    /// Full scenes written (each of one or more layers, whole).
    pub snapshots: u64,
    /// Messages written.
    pub messages: u64,
    /// Their bytes (encoded payloads, before the file's compression).
    pub bytes: u64,
    /// Voxels in the last snapshot.
    pub voxels: usize,
    /// The file's size on disk.
    pub file_bytes: u64,
}

/// What ingest hands the view thread.
pub(super) struct Inbox<const D: usize, const K: usize> {
    pub(super) config: Option<SessionConfig>,
    pub(super) voxels: HashMap<VoxelKey, GlobalVoxel<D>>,
    pub(super) link: Option<LinkCounters>,
    pub(super) arrivals: Vec<Instant>,
    pub(super) full: Vec<(SinkId, String)>,
    /// A new phrase, and when a client set it (None: the phrase the view started with).
    pub(super) phrase: Option<(String, Option<Instant>)>,
    pub(super) vocabulary: Option<Vocabulary<D, K>>,
    /// Close the recording (its last snapshot written) and say so on this channel.
    pub(super) end_recording: Option<Sender<Option<RecordingSummary>>>,
    pub(super) stop: bool,
}

impl<const D: usize, const K: usize> Inbox<D, K> {
    pub(super) fn new(stop: bool) -> Self {
        Self {
            config: None,
            voxels: HashMap::new(),
            link: None,
            arrivals: Vec::new(),
            full: Vec::new(),
            phrase: None,
            vocabulary: None,
            end_recording: None,
            stop,
        }
    }
    pub(super) fn is_empty(&self) -> bool {
        self.voxels.is_empty()
            && self.link.is_none()
            && self.full.is_empty()
            && self.phrase.is_none()
            && self.config.is_none()
            && self.vocabulary.is_none()
            && self.end_recording.is_none()
    }
}

pub(super) struct Shared<const D: usize, const K: usize> {
    pub(super) inbox: Mutex<Inbox<D, K>>,
    pub(super) wake: Condvar,
    pub(super) phrase: Mutex<String>,
}

impl<const D: usize, const K: usize> Shared<D, K> {
    pub(super) fn inbox(&self) -> std::sync::MutexGuard<'_, Inbox<D, K>> {
        self.inbox.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

impl<const D: usize, const K: usize> ViewRequests for Shared<D, K> {
    fn full_scene(&self, sink: SinkId, topic: &str) {
        self.inbox().full.push((sink, topic.to_string()));
        self.wake.notify_one();
    }
    fn set_phrase(&self, phrase: String) {
        *self.phrase.lock().unwrap_or_else(PoisonError::into_inner) = phrase.clone();
        self.inbox().phrase = Some((phrase, Some(Instant::now())));
        self.wake.notify_one();
    }
    fn phrase(&self) -> String {
        self.phrase
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
    }
}

/// The channels the view publishes on, in one context (the live server's, or the recording's).
pub(super) struct Channels {
    /// The context the channels and sinks live in (dropping it would close them).
    pub(super) _context: Arc<Context>,
    pub(super) layers: Vec<(Layer, Arc<RawChannel>)>,
    pub(super) legend: Arc<RawChannel>,
    pub(super) status: Arc<RawChannel>,
    pub(super) frame: Arc<RawChannel>,
    pub(super) heat_cloud: Arc<RawChannel>,
}

fn json_channel(ctx: &Arc<Context>, topic: &str, name: &str) -> Arc<RawChannel> {
    ctx.channel_builder(topic)
        .message_encoding("json")
        .schema(Schema::new(
            name,
            "jsonschema",
            br#"{"type":"object"}"#.as_slice(),
        ))
        .build_raw()
        .expect("a JSON channel with a schema is valid")
}

fn protobuf_channel<T: foxglove::Encode>(ctx: &Arc<Context>, topic: &str) -> Arc<RawChannel> {
    ctx.channel_builder(topic)
        .message_encoding(T::get_message_encoding())
        .schema(T::get_schema())
        .build_raw()
        .expect("a protobuf channel with its schema is valid")
}

impl Channels {
    /// Every topic of the view, in `ctx`.
    pub(super) fn new(ctx: &Arc<Context>) -> Self {
        use foxglove::messages::{FrameTransforms, PointCloud, SceneUpdate};
        Self {
            _context: ctx.clone(),
            layers: Layer::ALL
                .iter()
                .map(|&l| (l, protobuf_channel::<SceneUpdate>(ctx, l.topic())))
                .collect(),
            legend: json_channel(ctx, super::LEGEND_TOPIC, "latentbki.Legend"),
            status: json_channel(ctx, super::STATUS_TOPIC, "latentbki.LinkStatus"),
            frame: protobuf_channel::<FrameTransforms>(ctx, super::FRAME_TOPIC),
            heat_cloud: protobuf_channel::<PointCloud>(ctx, super::HEAT_CLOUD_TOPIC),
        }
    }
    pub(super) fn layer(&self, layer: Layer) -> &Arc<RawChannel> {
        &self.layers[layer as usize].1
    }
}
