//! The view thread: inbox from ingest in, scene updates out to the WebSocket server and the recording.
//! This module is ingest's side ([`Viewer`]: start, push, finish); the thread's loop is `worker`, what the
//! two share is `shared`.

use super::guard::{self, QueryParameter, Subscriptions, ViewRequests};
use super::scene::Layer;
use super::shared::{Channels, Inbox, Shared, MAX_ARRIVALS};
use super::worker::{ViewerSummary, Worker};
use super::{ViewError, ViewOptions, LEGEND_TOPIC, STATUS_TOPIC};
use crate::{BaseStation, GlobalMap};
use foxglove::messages::SceneUpdate;
use foxglove::{Context, Encode, RawChannel, Schema, WebSocketServerHandle};
use latentbki::key::VoxelKey;
use std::collections::HashMap;
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How long [`Viewer::finish`] waits for the clients' connections to close.
const SHUTDOWN_GRACE: Duration = Duration::from_secs(2);

/// The live view and/or recording of one base station.
pub struct Viewer<const D: usize> {
    shared: Arc<Shared<D>>,
    thread: Option<JoinHandle<ViewerSummary>>,
    server: Option<WebSocketServerHandle>,
    port: Option<u16>,
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
            // A graceful close waits until every client has taken its close frame; a client that stopped
            // reading (its socket full) would hold that forever, and with it the base station's exit. Wait
            // at most SHUTDOWN_GRACE on a helper thread; past it, go on (the helper keeps the handle and
            // ends with the stalled connection, or with the process).
            let shutdown = s.stop();
            let (done, finished) = std::sync::mpsc::channel();
            std::thread::Builder::new()
                .name("view-shutdown".into())
                .spawn(move || {
                    shutdown.wait_blocking();
                    done.send(()).ok();
                })
                .expect("the shutdown thread starts");
            if finished.recv_timeout(SHUTDOWN_GRACE).is_err() {
                tracing::warn!(
                    "view: a client did not close within {SHUTDOWN_GRACE:?}; not waiting for it"
                );
            }
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
