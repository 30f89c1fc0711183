//! What ingest's side ([`super::live`]) and the view thread ([`super::worker`]) share: the inbox ingest
//! fills under a short lock, the wake-up, the query phrase in force, and the channels the view publishes
//! on. Its own module so that neither side reaches into the other.

use super::guard::ViewRequests;
use super::scene::Layer;
use crate::{GlobalVoxel, ReceiveStats, SessionState};
use foxglove::{Context, RawChannel, SinkId};
use latentbki::key::VoxelKey;
use latentbki::wire::SessionConfig;
use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::time::Instant;

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

/// The channels the view publishes on.
pub(super) struct Channels {
    /// The context the channels and sinks live in (dropping it would close them).
    pub(super) _context: Arc<Context>,
    pub(super) layers: Vec<(Layer, Arc<RawChannel>)>,
    pub(super) legend: Arc<RawChannel>,
    pub(super) status: Arc<RawChannel>,
}
