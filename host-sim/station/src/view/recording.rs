//! The MCAP recording: a sequence of whole scenes, so that a reader that seeks rebuilds the map as it was.
//!
//! The live view sends only the blocks that changed; a reader that starts mid-file would see only those.
//! Foxglove and Lichtblick seek by taking **the last message of each topic** before the seek time (their
//! "backfill"), so every message the recording holds on a layer's topic is that layer **whole** (a
//! delete-all, then every block: the cached block bytes joined, ≈ 1 ms per 100k voxels). The last message
//! of each topic at any time is then the whole scene as the recording had it, and a reader that seeks
//! sees exactly what one that read from the start sees. The file begins with the first scene that holds
//! voxels (never an empty panel at the start), and [`FRAME_TOPIC`](super::FRAME_TOPIC), the legend and the
//! link status ride along with each snapshot, the heat cloud with each heat layer.
//!
//! Cost: a layer is written whole at most every [`MIN_INTERVAL`], and the interval stretches so that the
//! snapshots' payload stays under [`BYTES_PER_SECOND`] (a 100k-voxel map's four layers, ≈ 48 MB, go at
//! most every 6 s). Only layers that changed since their last snapshot are written. Chunks are LZ4
//! compressed (the cubes' repeated sizes, orientations and colours shrink ≈ 9×).

use super::cloud::heat_cloud_bytes;
use super::scene::{DecodedMap, Layer};
use super::shared::{Channels, RecordingSummary};
use super::ViewError;
use foxglove::messages::Timestamp;
use foxglove::{
    Context, McapCompression, McapWriteOptions, McapWriterHandle, PartialMetadata, RawChannel,
};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Snapshots of a layer are at least this far apart (the last one, at the end, excepted).
pub const MIN_INTERVAL: Duration = Duration::from_secs(1);
/// The snapshots' payload per second of recording, at most (before compression).
pub const BYTES_PER_SECOND: f64 = 8e6;

pub(super) struct Recording {
    channels: Channels,
    mcap: McapWriterHandle<BufWriter<File>>,
    path: PathBuf,
    /// When the last snapshot was written, and how long to wait after it.
    last: Option<(Instant, Duration)>,
    /// Layers changed since their last snapshot.
    dirty: [bool; 4],
    /// The legend, if it changed since it was last written.
    legend: Option<Vec<u8>>,
    summary: RecordingSummary,
}

impl Recording {
    /// A new file (an existing one is not overwritten).
    pub(super) fn create(path: &Path) -> Result<Self, ViewError> {
        let ctx = Context::new();
        let channels = Channels::new(&ctx);
        let options = McapWriteOptions::default().compression(Some(McapCompression::Lz4));
        let mcap = ctx
            .mcap_writer_with_options(options)
            .create_new_buffered_file(path)
            .map_err(|error| ViewError::Record {
                path: path.display().to_string(),
                error,
            })?;
        Ok(Self {
            channels,
            mcap,
            path: path.to_path_buf(),
            last: None,
            dirty: [true; 4],
            legend: None,
            summary: RecordingSummary::default(),
        })
    }

    /// A layer changed.
    pub(super) fn mark(&mut self, layer: Layer) {
        self.dirty[layer as usize] = true;
    }

    /// The legend changed.
    pub(super) fn legend(&mut self, legend: &[u8]) {
        self.legend = Some(legend.to_vec());
    }

    /// How long until a pending snapshot is due (None: nothing pending).
    pub(super) fn due(&self) -> Option<Duration> {
        if !self.dirty.iter().any(|d| *d) {
            return None;
        }
        Some(self.last.map_or(Duration::ZERO, |(at, wait)| {
            wait.saturating_sub(at.elapsed())
        }))
    }

    /// Write the changed layers whole if one is due (or `now`), with the frame, legend and status.
    pub(super) fn snapshot<const D: usize, const K: usize>(
        &mut self,
        scene: Option<&mut DecodedMap<D, K>>,
        frame: Option<&[u8]>,
        status: Option<&[u8]>,
        now: bool,
    ) {
        let Some(scene) = scene.filter(|s| !s.is_empty()) else {
            return;
        };
        if !now && self.due().is_none_or(|d| !d.is_zero()) {
            return;
        }
        if !self.dirty.iter().any(|d| *d) && self.legend.is_none() {
            return;
        }
        let first = self.last.is_none();
        let time = Timestamp::now();
        let mut bytes = 0usize;
        // One log time for the whole snapshot: a reader that seeks to it (the file's start, for the
        // first) gets every topic of it.
        let at = PartialMetadata::with_log_time(time);
        if let Some(f) = frame {
            self.write(&self.channels.frame.clone(), f, at);
        }
        for layer in Layer::ALL {
            if std::mem::take(&mut self.dirty[layer as usize]) || first {
                let buf = scene.full_bytes(layer, time);
                bytes += buf.len();
                self.write(&self.channels.layer(layer).clone(), &buf, at);
                if layer == Layer::Heat {
                    let cloud = heat_cloud_bytes(scene, time);
                    bytes += cloud.len();
                    self.write(&self.channels.heat_cloud.clone(), &cloud, at);
                }
            }
        }
        if let Some(l) = self.legend.take() {
            self.write(&self.channels.legend.clone(), &l, at);
        }
        if let Some(s) = status {
            self.write(&self.channels.status.clone(), s, at);
        }
        let stretch = Duration::from_secs_f64(bytes as f64 / BYTES_PER_SECOND);
        self.last = Some((Instant::now(), stretch.max(MIN_INTERVAL)));
        self.summary.snapshots += 1;
        self.summary.voxels = scene.len();
    }

    fn write(&mut self, ch: &std::sync::Arc<RawChannel>, bytes: &[u8], at: PartialMetadata) {
        ch.log_with_meta(bytes, at);
        self.summary.messages += 1;
        self.summary.bytes += bytes.len() as u64;
    }

    /// Close the file; what it holds.
    pub(super) fn close(self) -> RecordingSummary {
        let mut summary = self.summary;
        let _ = self.mcap.close();
        summary.file_bytes = std::fs::metadata(&self.path).map_or(0, |m| m.len());
        summary
    }
}
