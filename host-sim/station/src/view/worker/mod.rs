//! The view thread's loop ([`Worker`]): wait for ingest's inbox, fold it into the scene at most once per
//! interval, and send what changed (scene layers, legend, link status, the map's centre frame) to the
//! WebSocket server, and whole scenes to the recording ([`super::recording`]); a new subscriber gets the
//! whole scene. Apart from [`super::live`], the handle ingest holds, because this side owns the scene and
//! never blocks ingest.

use super::cloud::heat_cloud_bytes;
use super::guard;
use super::recording::Recording;
use super::scene::{DecodedMap, Layer};
use super::shared::{Channels, Inbox, RecordingSummary, Shared, MAX_SAMPLES};
use super::{Vocabulary, CENTRE_FRAME, FRAME_TOPIC, HEAT_CLOUD_TOPIC, LEGEND_TOPIC, STATUS_TOPIC};
use crate::base_station::ReceiveStats;
use crate::export::class_colour;
use crate::global_map::{GlobalMap, GlobalVoxel};
use crate::session::SessionState;
use foxglove::messages::{FrameTransform, FrameTransforms, Quaternion, Timestamp, Vector3};
use foxglove::{RawChannel, SinkId};
use latentbki::wire::{SessionConfig, NO_FEATURE_SPACE};
use latentbki::{decode::Codebook, key::VoxelKey};
use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, PoisonError};
use std::time::{Duration, Instant};

mod panels;

/// The centre frame is recomputed at most this often (three sorts of the scene's coordinates).
const CENTRE_EVERY: Duration = Duration::from_secs(1);
/// ... and sent again when it moved at least this far (metres).
const CENTRE_MOVE: f32 = 0.5;
/// The heat cloud goes out whole at most this often as the map changes (at once for a new phrase).
const CLOUD_EVERY: Duration = Duration::from_secs(1);

/// What the view sent, for the summary line and the figures.
#[derive(Clone, Debug, Default)]
pub struct ViewerSummary {
    /// Voxels in the last scene.
    pub voxels: usize,
    /// Messages published to the live view (broadcast, or to one late joiner).
    pub messages: u64,
    /// Their bytes (encoded payloads).
    pub bytes: u64,
    /// View updates sent.
    pub updates: u64,
    /// For each chunk of frames: its arrival at ingest to the end of the view update that showed it.
    pub latencies: Vec<Duration>,
    /// For each phrase a client set: from its arrival to the heat layer re-sent whole.
    pub query_latencies: Vec<Duration>,
    /// Client messages the server refused (garbage, oversized, unknown channels).
    pub refused: u64,
    /// Phrases that could not be encoded.
    pub phrase_errors: Vec<String>,
    /// From the view's start to its finish.
    pub elapsed: Duration,
    /// The recording, if there was one (closed).
    pub recording: Option<RecordingSummary>,
}

pub(super) struct Worker<const D: usize, const K: usize> {
    pub(super) shared: Arc<Shared<D, K>>,
    /// The live server's channels (None without a server).
    pub(super) live: Option<Channels>,
    pub(super) recording: Option<Recording>,
    pub(super) interval: Duration,
    pub(super) vocabulary: Option<Vocabulary<D, K>>,
    /// Why the vocabulary may not decode this map (another feature space), if so.
    pub(super) mismatch: Option<String>,
    pub(super) map: Option<GlobalMap<D>>,
    pub(super) scene: Option<DecodedMap<D, K>>,
    pub(super) query: Option<Codebook<D, K>>,
    /// The phrase in force, and why it could not be encoded (if so).
    pub(super) phrase: (String, Option<String>),
    /// Voxels in the scene when its colour ranges were last fixed.
    pub(super) fixed_at: usize,
    pub(super) summary: ViewerSummary,
    /// The last link status, legend and centre frame sent (a new subscriber gets them at once).
    pub(super) last_status: Option<Vec<u8>>,
    pub(super) last_legend: Option<Vec<u8>>,
    pub(super) last_frame: Option<(Instant, [f32; 3], Vec<u8>)>,
    /// When the heat cloud was last sent, and whether the heat changed since.
    pub(super) cloud: (Option<Instant>, bool),
    pub(super) refused_at_start: u64,
}

impl<const D: usize, const K: usize> Worker<D, K> {
    pub(super) fn run(mut self) -> ViewerSummary {
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
                    // A snapshot or a heat cloud waiting for its interval wakes the thread when due.
                    let due = [
                        self.recording.as_ref().and_then(Recording::due),
                        self.cloud_due(),
                    ]
                    .into_iter()
                    .flatten()
                    .min();
                    match due {
                        Some(due) if self.scene.as_ref().is_some_and(|s| !s.is_empty()) => {
                            if due.is_zero() {
                                break;
                            }
                            inbox = self
                                .shared
                                .wake
                                .wait_timeout(inbox, due)
                                .unwrap_or_else(PoisonError::into_inner)
                                .0;
                        }
                        _ => {
                            inbox = self
                                .shared
                                .wake
                                .wait(inbox)
                                .unwrap_or_else(PoisonError::into_inner);
                        }
                    }
                }
                let stop = inbox.stop;
                std::mem::replace(&mut *inbox, Inbox::new(stop))
            };
            last = Instant::now();
            let renamed = batch.vocabulary.is_some();
            if let Some(v) = batch.vocabulary {
                self.set_vocabulary(v);
            }
            let phrase = batch.phrase.or_else(|| {
                // A new vocabulary brings a new phrase encoder: encode the phrase in force again.
                renamed.then(|| (self.phrase.0.clone(), None))
            });
            self.update(batch.config, batch.voxels, phrase, renamed);
            if let Some((stats, sessions)) = batch.link {
                let status = self.status(&stats, &sessions);
                self.send_live(|c| &c.status, &status, None);
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
            self.send_cloud(false);
            self.snapshot(false);
            if let Some(reply) = batch.end_recording {
                let _ = reply.send(self.close_recording());
            }
            if batch.stop {
                break;
            }
        }
        self.summary.voxels = self.scene.as_ref().map_or(0, DecodedMap::len);
        self.summary.elapsed = started.elapsed();
        self.summary.refused = guard::refused() - self.refused_at_start;
        if let Some(r) = self.close_recording() {
            self.summary.recording = Some(r);
        }
        self.summary
    }

    /// Publish on a live channel (to every client, or to one).
    fn send_live(
        &mut self,
        which: impl Fn(&Channels) -> &Arc<RawChannel>,
        bytes: &[u8],
        sink: Option<SinkId>,
    ) {
        if let Some(ch) = &self.live {
            which(ch).log_to_sink(bytes, sink);
            self.summary.messages += 1;
            self.summary.bytes += bytes.len() as u64;
        }
    }

    /// How long until a changed heat cloud is due (None: unchanged).
    fn cloud_due(&self) -> Option<Duration> {
        self.cloud.1.then(|| {
            self.cloud.0.map_or(Duration::ZERO, |at| {
                CLOUD_EVERY.saturating_sub(at.elapsed())
            })
        })
    }

    /// Send the heat cloud whole if it changed and is due (or `now`), to the clients that watch it.
    fn send_cloud(&mut self, now: bool) {
        if !now && self.cloud_due().is_none_or(|d| !d.is_zero()) {
            return;
        }
        self.cloud = (Some(Instant::now()), false);
        let watched = self.live.as_ref().is_some_and(|c| c.heat_cloud.has_sinks());
        if let (true, Some(scene)) = (watched, &self.scene) {
            let bytes = heat_cloud_bytes(scene, Timestamp::now());
            self.send_live(|c| &c.heat_cloud, &bytes, None);
        }
    }

    /// The recording's snapshot, if one is due (or `now`).
    fn snapshot(&mut self, now: bool) {
        if let Some(r) = &mut self.recording {
            r.snapshot(
                self.scene.as_mut(),
                self.last_frame.as_ref().map(|f| f.2.as_slice()),
                self.last_status.as_deref(),
                now,
            );
        }
    }

    /// The last snapshot, and the file closed.
    fn close_recording(&mut self) -> Option<RecordingSummary> {
        self.snapshot(true);
        let r = self.recording.take()?.close();
        self.summary.recording = Some(r.clone());
        Some(r)
    }

    /// Check the vocabulary against the map's feature space (when both are known): a PCA other than the
    /// robots' decodes nothing, and the legend says why.
    fn check_feature_space(&mut self) {
        let want = self.vocabulary.as_ref().and_then(|v| v.feature_space);
        let have = self.map.as_ref().map(|m| m.config().feature_space);
        self.mismatch = match (want, have) {
            (Some(want), Some(have)) if have != NO_FEATURE_SPACE && have != want => Some(format!(
                "the PCA's feature space {want:#010x} is not the robots' ({have:#010x}): the map is not decoded"
            )),
            _ => None,
        };
    }

    fn set_vocabulary(&mut self, v: Vocabulary<D, K>) {
        let colours = v
            .names
            .iter()
            .enumerate()
            .map(|(i, n)| class_colour(n, i))
            .collect();
        if let Some(s) = &mut self.scene {
            s.set_palette(colours);
        }
        self.vocabulary = Some(v);
        self.check_feature_space();
    }

    fn update(
        &mut self,
        config: Option<SessionConfig>,
        voxels: HashMap<VoxelKey, GlobalVoxel<D>>,
        phrase: Option<(String, Option<Instant>)>,
        decode_all: bool,
    ) {
        let mut full = decode_all;
        if let (None, Some(c)) = (&self.map, config) {
            if let Ok(m) = GlobalMap::new(c) {
                let mut scene = DecodedMap::new(m.map_config().voxel_size());
                if let Some(v) = &self.vocabulary {
                    scene.set_palette(
                        v.names
                            .iter()
                            .enumerate()
                            .map(|(i, n)| class_colour(n, i))
                            .collect(),
                    );
                }
                self.scene = Some(scene);
                self.map = Some(m);
                self.check_feature_space();
                full = true;
            }
        }
        let mut heat_full = false;
        let mut asked_at = None;
        if let Some((p, at)) = phrase {
            self.set_phrase(p);
            asked_at = at;
            heat_full = true;
            // The cloud first: it is what a viewer repaints fastest (see `cloud`).
            self.send_cloud(true);
        }
        if let (Some(map), Some(scene)) = (&mut self.map, &mut self.scene) {
            let changed: Vec<VoxelKey> = voxels.keys().copied().collect();
            for (k, v) in voxels {
                map.insert_raw(k, v);
            }
            let keys = if decode_all {
                map.sorted_keys()
            } else {
                DecodedMap::<D, K>::affected(map, changed)
            };
            let codebook = match (&self.vocabulary, self.mismatch.is_some()) {
                (Some(v), false) => Some(&v.codebook),
                _ => None,
            };
            let dirty = scene.update(map, &keys, codebook, self.query.as_ref());
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
                let whole = full || (heat_full && layer == Layer::Heat);
                if !whole && dirty.is_empty() {
                    continue;
                }
                if let Some(r) = &mut self.recording {
                    r.mark(layer);
                }
                if layer == Layer::Heat {
                    self.cloud.1 = true;
                }
                // Nobody watches this layer live: build nothing (a later subscriber gets it whole).
                if !self
                    .live
                    .as_ref()
                    .is_some_and(|c| c.layer(layer).has_sinks())
                {
                    continue;
                }
                let buf = if whole {
                    scene.full_bytes(layer, time)
                } else {
                    scene.update_bytes(layer, &dirty, time)
                };
                self.send_live(|c| c.layer(layer), &buf, None);
            }
            self.centre(full);
        }
        if let Some(at) = asked_at {
            if self.summary.query_latencies.len() < MAX_SAMPLES {
                self.summary.query_latencies.push(at.elapsed());
            }
        }
        let legend = self.legend();
        if self.last_legend.as_ref() != Some(&legend) {
            self.send_live(|c| &c.legend, &legend, None);
            if let Some(r) = &mut self.recording {
                r.legend(&legend);
            }
            self.last_legend = Some(legend);
        }
    }

    /// Encode a new phrase and score every voxel with it.
    fn set_phrase(&mut self, p: String) {
        let encoder = self.vocabulary.as_ref().and_then(|v| v.phrases.as_ref());
        let (query, error) = match (encoder, p.is_empty()) {
            (_, true) => (None, None),
            (Some(_), false) if self.mismatch.is_some() => (None, self.mismatch.clone()),
            (None, false) => (
                None,
                Some(format!(
                    "\"{p}\": the view has no feature space to encode phrases with yet"
                )),
            ),
            (Some(enc), false) => match enc(&p) {
                Ok(q) => (Some(q), None),
                Err(e) => (None, Some(e)),
            },
        };
        if let Some(e) = &error {
            self.summary.phrase_errors.push(e.clone());
        }
        self.query = query;
        self.phrase = (p, error);
        if let Some(s) = &mut self.scene {
            s.set_query(self.query.as_ref());
        }
    }

    fn full_to(&mut self, sink: SinkId, topic: &str) {
        let last = match topic {
            LEGEND_TOPIC => Some(self.last_legend.clone().unwrap_or_else(|| self.legend())),
            STATUS_TOPIC => self.last_status.clone(),
            FRAME_TOPIC => self.last_frame.as_ref().map(|f| f.2.clone()),
            _ => None,
        };
        if let Some(bytes) = last {
            let which: fn(&Channels) -> &Arc<RawChannel> = match topic {
                LEGEND_TOPIC => |c| &c.legend,
                STATUS_TOPIC => |c| &c.status,
                _ => |c| &c.frame,
            };
            self.send_live(which, &bytes, Some(sink));
            return;
        }
        if topic == HEAT_CLOUD_TOPIC {
            if let Some(scene) = &self.scene {
                let bytes = heat_cloud_bytes(scene, Timestamp::now());
                self.send_live(|c| &c.heat_cloud, &bytes, Some(sink));
            }
            return;
        }
        let Some(layer) = Layer::ALL.into_iter().find(|l| l.topic() == topic) else {
            return;
        };
        let time = Timestamp::now();
        let buf = match &mut self.scene {
            Some(s) => s.full_bytes(layer, time),
            None => DecodedMap::<D, K>::new(1.0).full_bytes(layer, time),
        };
        self.send_live(|c| c.layer(layer), &buf, Some(sink));
    }
}
