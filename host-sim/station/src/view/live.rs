//! The view thread: inbox from ingest in, scene updates out to the WebSocket server and the recording.

use super::guard::{self, QueryParameter, Subscriptions, ViewRequests};
use super::scene::{Layer, Scene};
use super::{ViewError, ViewOptions, LEGEND_TOPIC, STATUS_TOPIC};
use crate::export::label_colour;
use crate::{BaseStation, GlobalMap, GlobalVoxel, ReceiveStats, SessionState};
use foxglove::messages::{SceneUpdate, Timestamp};
use foxglove::{
    Context, Encode, McapWriterHandle, RawChannel, Schema, SinkId, WebSocketServerHandle,
};
use latentbki::wire::SessionConfig;
use latentbki::{decode::Codebook, key::VoxelKey};
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Arrival times kept per view update at most (a flood of tiny chunks must not grow the inbox).
const MAX_ARRIVALS: usize = 4096;
/// Latency samples kept at most.
const MAX_SAMPLES: usize = 1 << 20;

/// The link's counters as ingest last saw them.
type LinkCounters = (ReceiveStats, BTreeMap<(u16, u32), SessionState>);

/// What ingest hands the view thread.
struct Inbox<const D: usize> {
    config: Option<SessionConfig>,
    voxels: HashMap<VoxelKey, GlobalVoxel<D>>,
    link: Option<LinkCounters>,
    arrivals: Vec<Instant>,
    full: Vec<(SinkId, String)>,
    phrase: Option<String>,
    stop: bool,
}

impl<const D: usize> Inbox<D> {
    fn is_empty(&self) -> bool {
        self.voxels.is_empty()
            && self.link.is_none()
            && self.full.is_empty()
            && self.phrase.is_none()
            && self.config.is_none()
    }
}

struct Shared<const D: usize> {
    inbox: Mutex<Inbox<D>>,
    wake: Condvar,
    phrase: Mutex<String>,
}

impl<const D: usize> Shared<D> {
    fn inbox(&self) -> std::sync::MutexGuard<'_, Inbox<D>> {
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

struct Channels {
    /// The context the channels and sinks live in (dropping it would close them).
    _context: Arc<Context>,
    layers: Vec<(Layer, Arc<RawChannel>)>,
    legend: Arc<RawChannel>,
    status: Arc<RawChannel>,
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

struct Worker<const D: usize, const K: usize> {
    shared: Arc<Shared<D>>,
    channels: Channels,
    interval: Duration,
    vocab: Option<(Vec<String>, Codebook<D, K>)>,
    phrases: Option<super::PhraseEncoder<D, K>>,
    map: Option<GlobalMap<D>>,
    scene: Option<Scene<D, K>>,
    query: Option<Codebook<D, K>>,
    /// Voxels in the scene when its colour ranges were last fixed.
    fixed_at: usize,
    summary: ViewerSummary,
    /// The last link status sent (a new subscriber gets it at once).
    last_status: Option<Vec<u8>>,
    mcap: Option<McapWriterHandle<BufWriter<File>>>,
    refused_at_start: u64,
}

impl<const D: usize, const K: usize> Worker<D, K> {
    fn run(mut self) -> ViewerSummary {
        let started = Instant::now();
        let mut last = Instant::now() - self.interval;
        loop {
            // At most one update per interval.
            let since = last.elapsed();
            if since < self.interval {
                std::thread::sleep(self.interval - since);
            }
            let batch = {
                let mut inbox = self.shared.inbox();
                while inbox.is_empty() && !inbox.stop {
                    inbox = self
                        .shared
                        .wake
                        .wait(inbox)
                        .unwrap_or_else(PoisonError::into_inner);
                }
                let stop = inbox.stop;
                std::mem::replace(
                    &mut *inbox,
                    Inbox {
                        config: None,
                        voxels: HashMap::new(),
                        link: None,
                        arrivals: Vec::new(),
                        full: Vec::new(),
                        phrase: None,
                        stop,
                    },
                )
            };
            last = Instant::now();
            self.update(batch.config, batch.voxels, batch.phrase);
            if let Some((stats, sessions)) = batch.link {
                let status = self.status(&stats, &sessions);
                self.send(&self.channels.status.clone(), &status, None);
                self.last_status = Some(status);
            }
            for (sink, topic) in batch.full {
                self.full_to(sink, &topic);
            }
            let done = Instant::now();
            for a in batch.arrivals {
                if self.summary.latencies.len() < MAX_SAMPLES {
                    self.summary.latencies.push(done.duration_since(a));
                }
            }
            if batch.stop {
                break;
            }
        }
        self.summary.voxels = self.scene.as_ref().map_or(0, Scene::len);
        self.summary.elapsed = started.elapsed();
        self.summary.refused = guard::refused() - self.refused_at_start;
        if let Some(m) = self.mcap.take() {
            let _ = m.close();
        }
        self.summary
    }

    fn send(&mut self, ch: &Arc<RawChannel>, bytes: &[u8], sink: Option<SinkId>) {
        ch.log_to_sink(bytes, sink);
        self.summary.messages += 1;
        self.summary.bytes += bytes.len() as u64;
    }

    fn send_scene(&mut self, layer: Layer, buf: &[u8], sink: Option<SinkId>) {
        let ch = self.channels.layers[layer as usize].1.clone();
        self.send(&ch, buf, sink);
    }

    fn update(
        &mut self,
        config: Option<SessionConfig>,
        voxels: HashMap<VoxelKey, GlobalVoxel<D>>,
        phrase: Option<String>,
    ) {
        let mut full = false;
        if let (None, Some(c)) = (&self.map, config) {
            if let Ok(m) = GlobalMap::new(c) {
                self.scene = Some(Scene::new(m.map_config().voxel_size()));
                self.map = Some(m);
                full = true;
            }
        }
        let mut heat_full = false;
        if let Some(p) = phrase {
            self.query = match (&self.phrases, p.is_empty()) {
                (_, true) | (None, _) => None,
                (Some(enc), false) => match enc(&p) {
                    Ok(q) => Some(q),
                    Err(e) => {
                        self.summary.phrase_errors.push(e);
                        None
                    }
                },
            };
            if let Some(s) = &mut self.scene {
                s.set_query(self.query.as_ref());
            }
            heat_full = true;
            let legend = self.legend(&p);
            self.send(&self.channels.legend.clone(), &legend, None);
        }
        let (Some(map), Some(scene)) = (&mut self.map, &mut self.scene) else {
            return;
        };
        let changed: Vec<VoxelKey> = voxels.keys().copied().collect();
        for (k, v) in voxels {
            map.insert_raw(k, v);
        }
        let affected = Scene::<D, K>::affected(map, changed);
        let dirty = scene.update(
            map,
            &affected,
            self.vocab.as_ref().map(|v| &v.1),
            self.query.as_ref(),
        );
        // Colour ranges are fixed at a full scene and again each time the map has doubled since.
        if full || scene.len() >= 2 * self.fixed_at.max(32) {
            scene.fix_ranges();
            self.fixed_at = scene.len();
            full = true;
        }
        let time = Timestamp::now();
        self.summary.updates += 1;
        for layer in Layer::ALL {
            let scene = self.scene.as_mut().expect("set above");
            let buf = if full || (heat_full && layer == Layer::Heat) {
                scene.full_bytes(layer, time)
            } else if !dirty.is_empty() {
                scene.update_bytes(layer, &dirty, time)
            } else {
                continue;
            };
            self.send_scene(layer, &buf, None);
        }
    }

    fn full_to(&mut self, sink: SinkId, topic: &str) {
        if topic == LEGEND_TOPIC {
            let legend = self.legend(&self.shared.phrase());
            self.send(&self.channels.legend.clone(), &legend, Some(sink));
            return;
        }
        if topic == STATUS_TOPIC {
            if let Some(status) = self.last_status.clone() {
                self.send(&self.channels.status.clone(), &status, Some(sink));
            }
            return;
        }
        let Some(&(layer, _)) = self
            .channels
            .layers
            .iter()
            .find(|(l, _)| l.topic() == topic)
        else {
            return;
        };
        let time = Timestamp::now();
        let buf = match &mut self.scene {
            Some(s) => s.full_bytes(layer, time),
            None => Scene::<D, K>::new(1.0).full_bytes(layer, time),
        };
        self.send_scene(layer, &buf, Some(sink));
    }

    fn legend(&self, phrase: &str) -> Vec<u8> {
        let classes: Vec<_> = self.vocab.as_ref().map_or(Vec::new(), |(names, _)| {
            names
                .iter()
                .enumerate()
                .map(|(i, n)| serde_json::json!({"index": i, "name": n, "rgb": label_colour(i)}))
                .collect()
        });
        serde_json::to_vec(&serde_json::json!({
            "classes": classes,
            "unclassified_rgb": [128, 128, 128],
            "query": phrase,
            "query_error": self.summary.phrase_errors.last(),
            "robots": "palette by robot id (the class palette); white: several robots",
            "heat": "viridis over the cosine scores when the phrase was set; exact score in metadata",
            "uncertainty": "viridis over log E-optimality (authors' t_var, lambda > 2); grey: undefined",
        }))
        .expect("JSON")
    }

    fn status(&self, s: &ReceiveStats, sessions: &BTreeMap<(u16, u32), SessionState>) -> Vec<u8> {
        let sessions: Vec<_> = sessions
            .iter()
            .map(|((robot, session), st)| {
                serde_json::json!({
                    "robot": robot, "session": session, "received": st.seq.received,
                    "lost": st.seq.lost, "late": st.seq.late,
                    "robot_frames_sent": st.link.map(|l| l.frames_sent),
                    "robot_refused": st.link.map(|l| l.refused),
                })
            })
            .collect();
        let r = &s.rejected;
        let d = &s.decoder;
        serde_json::to_vec(&serde_json::json!({
            "frames": s.frames, "merged": s.merged, "live": s.updated, "ignored": s.ignored,
            "lost": s.lost, "late": s.late, "duplicates": r.duplicate_frames,
            "refused": d.crc_errors + d.cobs_errors + d.too_short + d.overflows + r.version
                + r.malformed + r.wrong_config + r.invalid_voxel + r.too_old,
            "viewer_clients_refused": guard::refused() - self.refused_at_start,
            "sessions": sessions,
        }))
        .expect("JSON")
    }
}
