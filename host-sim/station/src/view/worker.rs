//! The view thread's loop ([`Worker`]): wait for ingest's inbox, fold it into the scene at most once per
//! interval, and send what changed (scene layers, legend, link status) to the WebSocket server and the
//! recording; a new subscriber gets the whole scene. Apart from [`super::live`], the handle ingest holds,
//! because this side owns the scene and never blocks ingest.

use super::guard::{self, ViewRequests};
use super::scene::{Layer, Scene};
use super::shared::{Channels, Inbox, Shared, MAX_SAMPLES};
use super::{LEGEND_TOPIC, STATUS_TOPIC};
use crate::export::label_colour;
use crate::{GlobalMap, GlobalVoxel, ReceiveStats, SessionState};
use foxglove::messages::Timestamp;
use foxglove::{McapWriterHandle, RawChannel, SinkId};
use latentbki::wire::SessionConfig;
use latentbki::{decode::Codebook, key::VoxelKey};
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::sync::{Arc, PoisonError};
use std::time::{Duration, Instant};

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

pub(super) struct Worker<const D: usize, const K: usize> {
    pub(super) shared: Arc<Shared<D>>,
    pub(super) channels: Channels,
    pub(super) interval: Duration,
    pub(super) vocab: Option<(Vec<String>, Codebook<D, K>)>,
    pub(super) phrases: Option<super::PhraseEncoder<D, K>>,
    pub(super) map: Option<GlobalMap<D>>,
    pub(super) scene: Option<Scene<D, K>>,
    pub(super) query: Option<Codebook<D, K>>,
    /// Voxels in the scene when its colour ranges were last fixed.
    pub(super) fixed_at: usize,
    pub(super) summary: ViewerSummary,
    /// The last link status sent (a new subscriber gets it at once).
    pub(super) last_status: Option<Vec<u8>>,
    pub(super) mcap: Option<McapWriterHandle<BufWriter<File>>>,
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
