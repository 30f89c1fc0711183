//! The demo's radio: the on-device map's evicted voxels → the core's `FrameEncoder` → a simulated faulty
//! serial link → the base station, exactly as a robot's UART would carry them.
//!
//! The evaluation hands every evicted voxel to a `VoxelSink`; this one queues it in the robot's encoder,
//! drains the encoder in byte-budgeted ticks through a `FaultyLink`, and feeds what arrives to a
//! `BaseStation`. The state is shared (`Arc<Mutex<…>>`) so that the demo can drain the last frames and
//! report after the run.

use crate::base_station::BaseStation;
use crate::eval::methods::{Decoder, VoxelSink};
use crate::link::{split_frames, ByteLog, Faults, FaultyLink};
use crate::ObsMap;
use latentbki::frame::EncoderSettings;
use latentbki::wire::{SessionConfig, SummaryCodec, NO_FEATURE_SPACE};
use latentbki::{
    frame::FrameEncoder, key::VoxelKey, obs::ObsStats, sink::Evicted, sink::EvictionSink, MapConfig,
};
use std::sync::{Arc, Mutex};

const D: usize = 64;
/// The robot's transmit queue and frame size (as on the firmware).
type Encoder = FrameEncoder<D, { 16 * 1024 }, 512>;
/// Bytes the robot may send per tick (a 115,200 baud UART at ~10 ticks per second).
const BUDGET: usize = 11_520;

/// Robot side, link and base station, shared with the demo.
pub struct DemoLink {
    encoder: Box<Encoder>,
    uart: ByteLog,
    link: FaultyLink,
    base: BaseStation<D>,
    /// Voxels handed to the encoder and the kernel mass they carry.
    pub sent_voxels: u64,
    /// Σλ of the voxels handed to the encoder.
    pub sent_points: f64,
    /// Bytes put on the wire.
    pub bytes: u64,
    /// Points handed to the encoder per voxel (its distinct voxels).
    pub sent_keys: std::collections::HashMap<VoxelKey, f64>,
    /// At the end: the base station's posteriors against the robot's own map.
    pub agreement: Option<Agreement>,
    /// The live view / recording of the base station, if asked for.
    viewer: Option<crate::base_station::view::Viewer<D>>,
}

/// Argmax agreement of the base station's map with the robot's own map.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Agreement {
    /// Voxels both answer.
    pub voxels: usize,
    /// Fraction of them that decode to the same category.
    pub all: f64,
    /// Voxels none of whose neighbourhood lost a summary on the link.
    pub complete: usize,
    /// Agreement over those: what the codec alone costs.
    pub codec_only: f64,
}

impl DemoLink {
    /// A robot (id 1) streaming maps of `map` with the default summary codec over a link with byte error
    /// rate `ber` (plus the fault mix of the streaming tests), seeded.
    pub fn new(map: &MapConfig, ber: f64, seed: u64) -> anyhow::Result<Arc<Mutex<Self>>> {
        let config = SessionConfig::new(map, D, SummaryCodec::DEFAULT, NO_FEATURE_SPACE);
        let encoder = Box::new(
            Encoder::new(config, EncoderSettings::new(1, 1))
                .map_err(|e| anyhow::anyhow!("encoder: {e:?}"))?,
        );
        let base = BaseStation::new(config).map_err(|e| anyhow::anyhow!("base station: {e:?}"))?;
        Ok(Arc::new(Mutex::new(Self {
            encoder,
            uart: ByteLog::default(),
            link: FaultyLink::new(Faults::everything(ber), seed),
            base,
            sent_voxels: 0,
            sent_points: 0.0,
            bytes: 0,
            sent_keys: Default::default(),
            agreement: None,
            viewer: None,
        })))
    }

    /// Show the base station's map in `viewer` as frames arrive.
    pub fn attach_viewer(&mut self, viewer: crate::base_station::view::Viewer<D>) {
        self.base.watch();
        self.viewer = Some(viewer);
    }

    /// Stop the viewer (after [`DemoLink::finish`]) and summarise what it sent.
    pub fn finish_viewer(&mut self) -> Option<crate::base_station::view::ViewerSummary> {
        self.viewer.take().map(|v| v.finish())
    }

    /// One tick of the robot's radio: up to `BUDGET` bytes through the link to the base station.
    fn tick(&mut self) {
        // Evicted voxels only: the evaluation's sink sees evictions, not live voxels.
        let none: [Evicted<'_, D>; 0] = [];
        if self.encoder.tick(&mut self.uart, BUDGET, none).is_err() {
            return;
        }
        let bytes = std::mem::take(&mut self.uart.0);
        self.bytes += bytes.len() as u64;
        let mut received = Vec::new();
        for frame in split_frames(&bytes) {
            self.link.send(frame, &mut received);
        }
        let arrived = std::time::Instant::now();
        self.base.receive(&received);
        if let Some(v) = &self.viewer {
            let changed = self.base.take_watched();
            v.push(&self.base, changed, arrived);
        }
    }

    /// Drain the robot's queue (end of the run).
    pub fn finish(&mut self) {
        while self.encoder.queued() > 0 {
            self.tick();
        }
        self.tick();
    }

    /// Compare the base station's map with the robot's own (every voxel either answers, by argmax).
    fn compare(&mut self, robot: &ObsMap<D>, decoder: &Decoder) {
        let Some(base) = self.base.map() else { return };
        let ours: std::collections::HashMap<VoxelKey, latentbki::stats::VoxelStats<D>> =
            base.posteriors().into_iter().collect();
        // Voxels whose points did not all arrive (a frame of theirs was lost on the link).
        let damaged: std::collections::HashSet<VoxelKey> = self
            .sent_keys
            .iter()
            .filter(|(k, n)| base.observations(k).map_or(0.0, |o| f64::from(o.count)) != **n)
            .map(|(k, _)| *k)
            .collect();
        let offsets = latentbki::kernel::KernelLut::<{ latentbki::kernel::MAX_NEIGHBOURS }>::new(
            robot.config(),
        )
        .map(|l| l.offsets().to_vec())
        .unwrap_or_default();
        let (mut both, mut agree, mut complete, mut agree_complete) = (0usize, 0, 0usize, 0);
        robot.for_each_posterior(|k, r| {
            if let Some(b) = ours.get(&k) {
                both += 1;
                let label = |m: &[f32; D]| decoder.argmax(m).map(|(c, _)| c);
                let same = usize::from(label(&b.mean) == label(&r.mean));
                agree += same;
                if !offsets.iter().any(|o| damaged.contains(&k.offset(*o))) {
                    complete += 1;
                    agree_complete += same;
                }
            }
        });
        self.agreement = Some(Agreement {
            voxels: both,
            all: agree as f64 / both.max(1) as f64,
            complete,
            codec_only: agree_complete as f64 / complete.max(1) as f64,
        });
    }

    /// The link's account in a few stable lines: bytes per integrated point, summaries per voxel, what
    /// arrived, and how the base station's map agrees with the robot's.
    pub fn summary(&self) -> String {
        let s = self.base.stats();
        let l = self.link.log();
        let (voxels, points) = self
            .base
            .map()
            .map_or((0, 0.0), |m| (m.len(), m.observed_points()));
        let mut out = format!(
            "wire bytes per integrated point: {:.2} ({} B for {:.0} points)\n\
             summaries sent per global voxel: {:.2} ({} summaries for {} voxels)\n",
            self.bytes as f64 / self.sent_points.max(1.0),
            self.bytes,
            self.sent_points,
            self.sent_voxels as f64 / self.sent_keys.len().max(1) as f64,
            self.sent_voxels,
            self.sent_keys.len(),
        );
        if let Some(a) = self.agreement {
            out += &format!(
                "base station vs robot map, argmax agreement: {:.2} % of {} voxels ({:.2} % of the {} whose \
                 neighbourhood lost no summary on the link)\n",
                100.0 * a.all,
                a.voxels,
                100.0 * a.codec_only,
                a.complete
            );
        }
        out += &format!(
            "link: {} frames ({:.1} B/summary) over a faulty link (byte errors, dropped/truncated/duplicated \
             frames): {} arrived intact; the base station applied {}, refused {} damaged runs of bytes, counted \
             {} frames lost; its global map holds {voxels} voxels with {:.1} % of the points sent.",
            l.frames,
            self.bytes as f64 / self.sent_voxels.max(1) as f64,
            l.intact,
            s.frames,
            s.decoder.refused(),
            s.lost,
            100.0 * points / self.sent_points.max(f64::MIN_POSITIVE),
        );
        out
    }
}

/// The evaluation's sink: queue the voxel, ticking the radio whenever the queue is full.
pub struct DemoLinkSink(pub Arc<Mutex<DemoLink>>);

impl VoxelSink for DemoLinkSink {
    fn voxel(&mut self, key: VoxelKey, obs: &ObsStats<D>, residency: u32) {
        let Ok(mut link) = self.0.lock() else { return };
        for _ in 0..1000 {
            let v = Evicted {
                key,
                obs,
                residency,
            };
            if link.encoder.evict(v).is_ok() {
                link.sent_voxels += 1;
                link.sent_points += f64::from(obs.count);
                *link.sent_keys.entry(key).or_default() += f64::from(obs.count);
                return;
            }
            link.tick();
        }
    }

    fn finish(&mut self, robot: &ObsMap<D>, decoder: &Decoder) {
        let Ok(mut link) = self.0.lock() else { return };
        link.finish();
        link.compare(robot, decoder);
    }
}
