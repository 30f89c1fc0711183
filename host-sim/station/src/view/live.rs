//! The view thread: inbox from ingest in, scene updates out to the WebSocket server and the recording.
//! This module is ingest's side ([`Viewer`]: start, push, finish); the thread's loop is `worker`.

use super::guard::{self, QueryParameter, Subscriptions, ViewRequests};
use super::scene::Layer;
use super::worker::Worker;
use super::{ViewError, ViewOptions, LEGEND_TOPIC, STATUS_TOPIC};
use crate::{BaseStation, GlobalMap, GlobalVoxel, ReceiveStats, SessionState};
use foxglove::messages::SceneUpdate;
use foxglove::{Context, Encode, RawChannel, Schema, SinkId, WebSocketServerHandle};
use latentbki::key::VoxelKey;
use latentbki::wire::SessionConfig;
use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Arrival times kept per view update at most (a flood of tiny chunks must not grow the inbox).
pub(super) const MAX_ARRIVALS: usize = 4096;
/// Latency samples kept at most.
pub(super) const MAX_SAMPLES: usize = 1 << 20;

/// The link's counters as ingest last saw them.
pub(super) type LinkCounters = (ReceiveStats, BTreeMap<(u16, u32), SessionState>);

/// What ingest hands the view thread.
pub(super) struct Inbox<const D: usize> {
    pub(super) config: Option<SessionConfig>,
    pub(super) voxels: HashMap<VoxelKey, GlobalVoxel<D>>,
    pub(super) link: Option<LinkCounters>,
    pub(super) arrivals: Vec<Instant>,
    pub(super) full: Vec<(SinkId, String)>,
    pub(super) phrase: Option<String>,
    pub(super) stop: bool,
}

impl<const D: usize> Inbox<D> {
    pub(super) fn is_empty(&self) -> bool {
        self.voxels.is_empty()
            && self.link.is_none()
            && self.full.is_empty()
            && self.phrase.is_none()
            && self.config.is_none()
    }
}

pub(super) struct Shared<const D: usize> {
    pub(super) inbox: Mutex<Inbox<D>>,
    pub(super) wake: Condvar,
    pub(super) phrase: Mutex<String>,
}

impl<const D: usize> Shared<D> {
    pub(super) fn inbox(&self) -> std::sync::MutexGuard<'_, Inbox<D>> {
        self.inbox.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

impl<const D: usize> ViewRequests for Shared<D> {
    fn full_scene(&self, sink: SinkId, topic: &str) {
        self.inbox().full.push((sink, topic.to_string()));
        self.wake.notify_one();
    }
    fn set_phrase(&self, phrase: String) {
        *self.phrase.lock().unwrap_or_else(PoisonError::into_inner) = phrase.clone();
        self.inbox().phrase = Some(phrase);
        self.wake.notify_one();
    }
    fn phrase(&self) -> String {
        self.phrase
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
    }
}

/// What the view sent, for the summary line and the figures.
#[derive(Clone, Debug, Default)]
pub struct ViewerSummary {
    /// Voxels in the last scene.
    pub voxels: usize,
    /// Messages published (broadcast, to one late joiner, or to the recording).
    pub messages: u64,
    /// Their bytes (encoded payloads).
    pub bytes: u64,
    /// View updates sent.
    pub updates: u64,
    /// For each chunk of frames: its arrival at ingest to the end of the view update that showed it.
    pub latencies: Vec<Duration>,
    /// Client messages the server refused (garbage, oversized, unknown channels).
    pub refused: u64,
    /// Phrases that could not be encoded.
    pub phrase_errors: Vec<String>,
    /// From the view's start to its finish.
    pub elapsed: Duration,
}

/// The live view and/or recording of one base station.
pub struct Viewer<const D: usize> {
    shared: Arc<Shared<D>>,
    thread: Option<JoinHandle<ViewerSummary>>,
    server: Option<WebSocketServerHandle>,
    port: Option<u16>,
}

pub(super) struct Channels {
    /// The context the channels and sinks live in (dropping it would close them).
    pub(super) _context: Arc<Context>,
    pub(super) layers: Vec<(Layer, Arc<RawChannel>)>,
    pub(super) legend: Arc<RawChannel>,
    pub(super) status: Arc<RawChannel>,
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

impl<const D: usize> Viewer<D> {
    /// Start the server and/or the recording, and the view thread.
    pub fn start<const K: usize>(options: ViewOptions<D, K>) -> Result<Self, ViewError> {
        let ctx = Context::new();
        let layers = Layer::ALL
            .iter()
            .map(|&l| {
                let ch = ctx
                    .channel_builder(l.topic())
                    .message_encoding(SceneUpdate::get_message_encoding())
                    .schema(SceneUpdate::get_schema())
                    .build_raw()
                    .expect("a protobuf channel with its schema is valid");
                (l, ch)
            })
            .collect();
        let channels = Channels {
            _context: ctx.clone(),
            layers,
            legend: json_channel(&ctx, LEGEND_TOPIC, "latentbki.Legend"),
            status: json_channel(&ctx, STATUS_TOPIC, "latentbki.LinkStatus"),
        };
        let phrase = options.phrase.clone().unwrap_or_default();
        let shared = Arc::new(Shared {
            inbox: Mutex::new(Inbox {
                config: None,
                voxels: HashMap::new(),
                link: None,
                arrivals: Vec::new(),
                full: Vec::new(),
                phrase: Some(phrase.clone()),
                stop: false,
            }),
            wake: Condvar::new(),
            phrase: Mutex::new(phrase),
        });
        let mcap =
            match &options.record {
                Some(p) => Some(ctx.mcap_writer().create_new_buffered_file(p).map_err(
                    |error| ViewError::Record {
                        path: p.display().to_string(),
                        error,
                    },
                )?),
                None => None,
            };
        let (server, port) = match options.listen {
            Some(addr) => {
                guard::install_refusal_counter();
                let requests: Arc<dyn ViewRequests> = shared.clone();
                let server = ctx
                    .websocket_server()
                    .name("latentbki base station")
                    .bind(addr.ip().to_string(), addr.port())
                    .message_backlog_size(options.backlog.max(1))
                    .listener(Arc::new(Subscriptions(requests.clone())))
                    .parameter_handler(Arc::new(QueryParameter(requests)))
                    .start_blocking()
                    .map_err(|error| ViewError::Listen { addr, error })?;
                let port = server.port();
                (Some(server), Some(port))
            }
            None => (None, None),
        };
        let worker = Worker::<D, K> {
            shared: shared.clone(),
            channels,
            interval: Duration::from_secs_f64(1.0 / options.rate_hz.clamp(0.01, 1000.0)),
            vocab: options.vocab,
            phrases: options.phrases,
            map: None,
            scene: None,
            query: None,
            fixed_at: 0,
            summary: ViewerSummary::default(),
            last_status: None,
            mcap,
            refused_at_start: guard::refused(),
        };
        let thread = std::thread::Builder::new()
            .name("view".into())
            .spawn(move || worker.run())
            .expect("the view thread starts");
        Ok(Self {
            shared,
            thread: Some(thread),
            server,
            port,
        })
    }

    /// The port the server listens on (None without a server).
    pub fn port(&self) -> Option<u16> {
        self.port
    }

    /// Ingest's side: the voxels `changed` by bytes that arrived at `arrived` (copied; never waits on a
    /// client), and the link's counters.
    pub fn push(
        &self,
        base: &BaseStation<D>,
        changed: impl IntoIterator<Item = VoxelKey>,
        arrived: Instant,
    ) {
        let mut inbox = self.shared.inbox();
        if let Some(map) = base.map() {
            inbox.config = Some(*map.config());
            for k in changed {
                if let Some(v) = map.voxel(&k) {
                    inbox.voxels.insert(k, v.clone());
                }
            }
        }
        inbox.link = Some((base.stats(), base.sessions().clone()));
        if inbox.arrivals.len() < MAX_ARRIVALS {
            inbox.arrivals.push(arrived);
        }
        drop(inbox);
        self.shared.wake.notify_one();
    }

    /// Show a whole map (a database's, for an export): every voxel is a change.
    pub fn push_map(&self, map: &GlobalMap<D>) {
        let mut inbox = self.shared.inbox();
        inbox.config = Some(*map.config());
        inbox
            .voxels
            .extend(map.voxels().map(|(k, v)| (*k, v.clone())));
        drop(inbox);
        self.shared.wake.notify_one();
    }

    /// Send what is left, stop the server, close the recording.
    pub fn finish(mut self) -> ViewerSummary {
        self.shared.inbox().stop = true;
        self.shared.wake.notify_one();
        let summary = self
            .thread
            .take()
            .map(|t| t.join().unwrap_or_default())
            .unwrap_or_default();
        if let Some(s) = self.server.take() {
            s.stop().wait_blocking();
        }
        summary
    }
}

impl<const D: usize> Drop for Viewer<D> {
    fn drop(&mut self) {
        self.shared.inbox().stop = true;
        self.shared.wake.notify_one();
    }
}
