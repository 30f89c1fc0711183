//! The view thread: inbox from ingest in, scene updates out to the WebSocket server and the recording.
//! This module is ingest's side ([`Viewer`]: start, push, finish); the thread's loop is `worker`, what the
//! two share is `shared`.

use super::front::Front;
use super::guard::{self, QueryParameter, Subscriptions, ViewRequests};
use super::recording::Recording;
use super::shared::{Channels, Inbox, RecordingSummary, Shared, MAX_ARRIVALS};
use super::worker::{ViewerSummary, Worker};
use super::{ViewError, ViewOptions, Vocabulary};
use crate::base_station::BaseStation;
use crate::global_map::GlobalMap;
use foxglove::{Context, WebSocketServerHandle};
use latentbki::key::VoxelKey;
use std::net::SocketAddr;
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How long [`Viewer::finish`] waits for the clients' connections to close.
const SHUTDOWN_GRACE: Duration = Duration::from_secs(2);

/// The live view and/or recording of one base station (`K`: the vocabulary's capacity).
pub struct Viewer<const D: usize, const K: usize> {
    shared: Arc<Shared<D, K>>,
    thread: Option<JoinHandle<ViewerSummary>>,
    server: Option<WebSocketServerHandle>,
    front: Option<Front>,
}

impl<const D: usize, const K: usize> Viewer<D, K> {
    /// Start the server and/or the recording, and the view thread.
    pub fn start(options: ViewOptions<D, K>) -> Result<Self, ViewError> {
        let phrase = options.phrase.clone().unwrap_or_default();
        let mut inbox = Inbox::new(false);
        inbox.phrase = Some((phrase.clone(), None));
        let shared = Arc::new(Shared {
            inbox: Mutex::new(inbox),
            wake: Condvar::new(),
            phrase: Mutex::new(phrase.clone()),
        });
        let (live, server, front) = match options.listen {
            Some(addr) => {
                let listen_error = |error: String| ViewError::Listen { addr, error };
                let ctx = Context::new();
                let live = Channels::new(&ctx);
                guard::install_refusal_counter();
                let requests: Arc<dyn ViewRequests> = shared.clone();
                // The SDK's server on an ephemeral loopback port, behind the front (see `front`).
                let server = ctx
                    .websocket_server()
                    .name("latentbki base station")
                    .bind("127.0.0.1", 0)
                    .message_backlog_size(options.backlog.max(1))
                    .listener(Arc::new(Subscriptions(requests.clone())))
                    .parameter_handler(Arc::new(QueryParameter(requests)))
                    .start_blocking()
                    .map_err(|e| listen_error(e.to_string()))?;
                let backend = SocketAddr::from(([127, 0, 0, 1], server.port()));
                let front = Front::start(addr, backend).map_err(|e| listen_error(e.to_string()))?;
                (Some(live), Some(server), Some(front))
            }
            None => (None, None, None),
        };
        // After the server: a server that cannot listen leaves no empty recording behind.
        let recording = match &options.record {
            Some(p) => Some(Recording::create(p)?),
            None => None,
        };
        let worker = Worker::<D, K> {
            shared: shared.clone(),
            live,
            recording,
            interval: Duration::from_secs_f64(1.0 / options.rate_hz.clamp(0.01, 1000.0)),
            vocabulary: None,
            mismatch: None,
            map: None,
            scene: None,
            query: None,
            phrase: (phrase, None),
            fixed_at: 0,
            summary: ViewerSummary::default(),
            last_status: None,
            last_legend: None,
            last_frame: None,
            cloud: (None, false),
            refused_at_start: guard::refused(),
        };
        if let Some(v) = options.vocabulary {
            shared.inbox().vocabulary = Some(v);
        }
        let thread = std::thread::Builder::new()
            .name("view".into())
            .spawn(move || worker.run())
            .expect("the view thread starts");
        Ok(Self {
            shared,
            thread: Some(thread),
            server,
            front,
        })
    }

    /// Decode the map with this vocabulary from now on (a robot's feature space became known): every
    /// voxel is decoded again and every layer re-sent whole, with the legend.
    pub fn set_vocabulary(&self, vocabulary: Vocabulary<D, K>) {
        self.shared.inbox().vocabulary = Some(vocabulary);
        self.shared.wake.notify_one();
    }

    /// Make `phrase` the query in force (as if a client had set it; clients see the new value).
    pub fn set_phrase(&self, phrase: &str) {
        *self
            .shared
            .phrase
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = phrase.to_string();
        self.shared.inbox().phrase = Some((phrase.to_string(), None));
        self.shared.wake.notify_one();
    }

    /// Write the recording's last snapshot and close its file (the live view goes on); what it holds.
    /// None without a recording (or if it was closed already).
    pub fn end_recording(&self) -> Option<RecordingSummary> {
        let (tx, rx) = std::sync::mpsc::channel();
        self.shared.inbox().end_recording = Some(tx);
        self.shared.wake.notify_one();
        rx.recv().ok().flatten()
    }

    /// The port the server listens on (None without a server).
    pub fn port(&self) -> Option<u16> {
        self.front.as_ref().map(|f| f.addr().port())
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
        if let Some(f) = self.front.take() {
            f.stop();
        }
        summary
    }
}

impl<const D: usize, const K: usize> Drop for Viewer<D, K> {
    fn drop(&mut self) {
        self.shared.inbox().stop = true;
        self.shared.wake.notify_one();
    }
}
