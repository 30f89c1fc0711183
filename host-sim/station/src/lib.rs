//! The base station: bytes from any number of robots in, one global map out.
//!
//! [`BaseStation::receive`] takes bytes in whatever chunks the port delivers; [`BaseStation::receive_on`]
//! takes them from one of many *links* (serial ports, ptys, TCP connections, recordings), each with its own
//! decoder state, counters and acknowledgements, all feeding the one map. The core's
//! [`latentbki::receiver::Receiver`] checks each frame layer by layer — COBS and CRC, protocol version and
//! parse, configuration id, every summary in it, sequence number per `(robot, session)` — and a frame is
//! applied to the [`GlobalMap`] only if all of it passes; every refusal is counted by reason, every gap in
//! sequence numbers is counted as lost. Each accepted (or repeated) frame is acknowledged on the link it
//! came in on ([`BaseStation::take_acks_on`]; protocol 3; a link without a back channel ignores them):
//! at once ([`AckPolicy::Immediate`]), or — a base station with a database — only once a commit made the
//! frame durable ([`AckPolicy::AfterCommit`]), so a crash never loses a frame its robot was told is safe.
//! What changed since the last commit (voxels touched, sessions whose frames touched them) is tracked so
//! that [`BaseStation::changes`] hands a [`store::MapStore`] exactly that, at frame boundaries only: a
//! frame's summaries and the sequence state that marks it merged are always in the same change set.
//! Storage, queries and exports live in the submodules.
//!
//! This crate is what a deployed base station builds: the core, SQLite and PNG, and none of the desktop
//! twin's simulator, evaluation or command line (those stay in `host-sim`, which also holds the
//! `base-station`, `map-info` and `map-query` commands built on this crate).
#![forbid(unsafe_code)]

pub mod export;
pub mod global_map;
mod merge;
pub mod obs_map;
pub mod png_io;
pub mod store;
#[cfg(feature = "view")]
pub mod view;

pub use global_map::{
    Applied, ContributionId, GlobalMap, GlobalVoxel, MergeError, MergeReport, RecordError,
    Uncertainty, VOCAB_CAP,
};
pub use obs_map::ObsMap;

use latentbki::frame::{Ack, DecoderStats, SeqTracker};
use latentbki::key::VoxelKey;
use latentbki::receiver::{Receipt, Receiver, SessionTable};
use latentbki::wire::{LinkStats, Message, SessionConfig, Summary, WireError};
use std::collections::{BTreeMap, HashSet};
use store::{Changes, MapStore, Snapshot, StoreError};

/// Largest encoded frame the base station accepts (bytes between delimiters).
pub const MAX_FRAME: usize = 4096;

/// Frames refused after COBS/CRC, by reason (the core receiver's counters).
pub use latentbki::receiver::Refusals as Rejections;

/// What the base station has seen.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ReceiveStats {
    /// Runs of bytes refused by the frame layer (COBS, length, CRC, overflow).
    pub decoder: DecoderStats,
    /// Refusals after the frame layer.
    pub rejected: Rejections,
    /// Frames applied.
    pub frames: u32,
    /// Final summaries merged.
    pub merged: u32,
    /// Live summaries applied.
    pub updated: u32,
    /// Summaries ignored as stale or duplicate copies.
    pub ignored: u32,
    /// Frames lost: sum over sessions of sequence numbers never received.
    pub lost: u32,
    /// Frames that arrived late (after a newer one) and were still used.
    pub late: u32,
    /// Applied summaries whose μ scale was at the codec's ceiling (clamped at ≈ 6.0e4, or within 1/8
    /// octave below it).
    pub clamped_mean_scale: u32,
    /// Applied summaries whose largest Ψ was at the codec's ceiling (clamped at ≈ 9.6e5, or within 1/8
    /// octave below it).
    pub clamped_psi: u32,
}

/// What the base station knows about one `(robot, session)`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct SessionState {
    /// Its sequence numbers.
    pub seq: SeqTracker,
    /// Whether its session header arrived.
    pub header_seen: bool,
    /// The last link statistics it reported.
    pub link: Option<LinkStats>,
}

/// Version of [`SessionState::to_record`]'s layout.
pub const SESSION_RECORD_VERSION: u8 = 1;

impl SessionState {
    /// The session's state as a versioned byte record (version byte, then postcard).
    pub fn to_record(&self) -> Vec<u8> {
        let mut out = vec![SESSION_RECORD_VERSION];
        out.extend(postcard::to_stdvec(self).expect("a session state serializes"));
        out
    }
    /// Read a record written by [`SessionState::to_record`].
    pub fn from_record(bytes: &[u8]) -> Result<Self, RestoreError> {
        match bytes.split_first() {
            Some((&SESSION_RECORD_VERSION, rest)) => match postcard::take_from_bytes(rest) {
                Ok((s, [])) => Ok(s),
                _ => Err(RestoreError::Invalid("a session record is malformed".into())),
            },
            Some((v, _)) => Err(RestoreError::Invalid(format!(
                "session record version {v} is not supported (this build reads version {SESSION_RECORD_VERSION})"
            ))),
            None => Err(RestoreError::Invalid("an empty session record".into())),
        }
    }
}

/// Why a stored map could not be restored.
#[derive(Debug, thiserror::Error)]
pub enum RestoreError {
    /// The store failed.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// The stored map is for another feature dimension.
    #[error(
        "the map database holds {found}-dimensional voxels; this build is {expected}-dimensional"
    )]
    Dimension {
        /// Stored.
        found: u32,
        /// This build's D.
        expected: usize,
    },
    /// A record could not be read.
    #[error("map database invalid: {0}")]
    Invalid(String),
}

/// Which of a base station's links bytes came in on; link 0 is [`BaseStation::receive`]'s.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct LinkId(pub u32);

/// When a base station releases acknowledgements.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum AckPolicy {
    /// As soon as the frames are handled (a map in memory only: nothing gets more durable than that).
    #[default]
    Immediate,
    /// After the commit that made them durable ([`BaseStation::commit`]): what a robot is told is safe
    /// survives a crash of the base station.
    AfterCommit,
}

/// One link: its own decoder state (a frame cut on one link never glues to another's bytes), counters and
/// acknowledgements.
struct Link<const D: usize> {
    receiver: Box<Receiver<D, MAX_FRAME>>,
    /// Frames applied, summaries merged / live / ignored, ceilings (the decoder's and receiver's
    /// counters are the receiver's).
    stats: ReceiveStats,
    /// Sessions whose frames arrived on this link since its last acknowledgements were released.
    to_ack: std::collections::BTreeSet<(u16, u32)>,
    /// Acknowledgements on the wire, waiting for [`BaseStation::take_acks_on`].
    ack_bytes: Vec<u8>,
    /// Acknowledgements released.
    acks: u64,
    /// Bytes received.
    bytes: u64,
}

impl<const D: usize> Link<D> {
    fn new(config: Option<SessionConfig>) -> Self {
        Self {
            receiver: Box::new(Receiver::new(config)),
            stats: ReceiveStats::default(),
            to_ack: Default::default(),
            ack_bytes: Vec::new(),
            acks: 0,
            bytes: 0,
        }
    }
}

/// What one link delivered ([`BaseStation::link_stats`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LinkCounters {
    /// Bytes received.
    pub bytes: u64,
    /// Frames and summaries as [`ReceiveStats`] counts them (`lost` and `late` are per session, not per
    /// link: 0 here).
    pub receive: ReceiveStats,
    /// Acknowledgements released for this link.
    pub acks: u64,
}

/// One accepted frame, for audits (enabled with [`BaseStation::keep_journal`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct JournalEntry {
    /// Robot.
    pub robot: u16,
    /// Session.
    pub session: u32,
    /// Sequence number.
    pub seq: u32,
    /// The frame body as accepted.
    pub body: Vec<u8>,
}

/// Receives frames and keeps the global map.
pub struct BaseStation<const D: usize> {
    links: Vec<Link<D>>,
    ack_policy: AckPolicy,
    map: Option<GlobalMap<D>>,
    sessions: BTreeMap<(u16, u32), SessionState>,
    journal: Option<Vec<JournalEntry>>,
    /// Changed since the last commit.
    dirty_voxels: HashSet<VoxelKey>,
    dirty_sessions: HashSet<(u16, u32)>,
    config_dirty: bool,
    /// Changed since the last [`BaseStation::take_watched`] (a live view's hook), if watched.
    watched: Option<HashSet<VoxelKey>>,
}

impl<const D: usize> BaseStation<D> {
    /// A base station whose map has this configuration; sessions of any other are refused.
    pub fn new(config: SessionConfig) -> Result<Self, WireError> {
        let map = GlobalMap::new(config)?;
        Ok(Self::with(Some(config), Some(map)))
    }

    /// A base station that adopts the configuration of the first valid session header it receives (with
    /// dimension D); frames before it are refused as `wrong_config`.
    pub fn adopting() -> Self {
        Self::with(None, None)
    }

    /// Continue an existing (e.g. loaded) map.
    pub fn from_map(map: GlobalMap<D>) -> Self {
        Self::with(Some(*map.config()), Some(map))
    }

    fn with(expected: Option<SessionConfig>, map: Option<GlobalMap<D>>) -> Self {
        // A map handed in is new to any store: all of it is a change.
        let config_dirty = map.is_some();
        let dirty_voxels = map
            .as_ref()
            .map_or_else(HashSet::new, |m| m.voxels().map(|(k, _)| *k).collect());
        Self {
            links: vec![Link::new(expected)],
            ack_policy: AckPolicy::Immediate,
            map,
            sessions: BTreeMap::new(),
            journal: None,
            dirty_voxels,
            dirty_sessions: HashSet::new(),
            config_dirty,
            watched: None,
        }
    }

    /// Continue the map a store holds (sessions and their sequence state included); an empty store gives
    /// a base station that adopts the first valid session header's configuration.
    pub fn restore(snapshot: Snapshot) -> Result<Self, RestoreError> {
        let Some(bytes) = &snapshot.config else {
            if let Some(found) = snapshot.dim.filter(|&d| d as usize != D) {
                return Err(RestoreError::Dimension { found, expected: D });
            }
            return Ok(Self::adopting());
        };
        let dim = snapshot.dim.unwrap_or(0);
        if dim as usize != D {
            return Err(RestoreError::Dimension {
                found: dim,
                expected: D,
            });
        }
        let config = config_from_bytes(bytes)
            .map_err(|e| RestoreError::Invalid(format!("session configuration: {e}")))?;
        let mut map = GlobalMap::new(config)
            .map_err(|e| RestoreError::Invalid(format!("session configuration: {e:?}")))?;
        for (key, rec) in &snapshot.voxels {
            if !key.in_range() {
                return Err(RestoreError::Invalid(format!(
                    "voxel key {key:?} out of range"
                )));
            }
            let v = GlobalVoxel::from_record(rec, map.forgetting().as_ref())
                .map_err(|e| RestoreError::Invalid(format!("voxel {key:?}: {e}")))?;
            map.insert_raw(*key, v);
        }
        let mut base = Self::with(Some(config), Some(map));
        base.committed(); // as stored
        for (id, rec) in &snapshot.sessions {
            base.sessions.insert(*id, SessionState::from_record(rec)?);
        }
        Ok(base)
    }

    /// Open a store and continue its map.
    pub fn open(store: &mut dyn MapStore) -> Result<Self, RestoreError> {
        Self::restore(store.snapshot()?)
    }

    /// Everything changed since the last [`BaseStation::committed`], at a frame boundary.
    pub fn changes(&self) -> Changes {
        let config = match (&self.map, self.config_dirty) {
            (Some(m), true) => Some((D as u32, config_to_bytes(m.config()))),
            _ => None,
        };
        let voxels = match &self.map {
            Some(m) => self
                .dirty_voxels
                .iter()
                .filter_map(|k| Some((*k, m.voxel(k)?.to_record())))
                .collect(),
            None => Vec::new(),
        };
        let sessions = self
            .dirty_sessions
            .iter()
            .filter_map(|id| Some((*id, self.sessions.get(id)?.to_record())))
            .collect();
        Changes {
            config,
            voxels,
            sessions,
        }
    }

    /// Whether anything changed since the last commit.
    pub fn has_changes(&self) -> bool {
        self.config_dirty || !self.dirty_voxels.is_empty() || !self.dirty_sessions.is_empty()
    }

    /// The last [`BaseStation::changes`] are stored: start tracking afresh.
    pub fn committed(&mut self) {
        self.config_dirty = false;
        self.dirty_voxels.clear();
        self.dirty_sessions.clear();
    }

    /// Write the changes since the last commit to `store` in one transaction; then (with
    /// [`AckPolicy::AfterCommit`]) release the acknowledgements of every frame handled so far, now durable.
    pub fn commit(&mut self, store: &mut dyn MapStore) -> Result<(), StoreError> {
        if self.has_changes() {
            store.commit(&self.changes())?;
            self.committed();
        }
        self.release_acks();
        Ok(())
    }

    /// When acknowledgements are released (default [`AckPolicy::Immediate`]).
    pub fn set_ack_policy(&mut self, policy: AckPolicy) {
        self.ack_policy = policy;
    }
    /// The policy in force.
    pub fn ack_policy(&self) -> AckPolicy {
        self.ack_policy
    }

    /// Acknowledgements waiting for a commit ([`AckPolicy::AfterCommit`]).
    pub fn has_unreleased_acks(&self) -> bool {
        self.links.iter().any(|l| !l.to_ack.is_empty())
    }

    /// Encode, for each link, an acknowledgement of each session whose frames arrived on it since its
    /// last release: the session's whole sequence state as it is now, in ascending `(robot, session)`
    /// order. [`Self::commit`] calls it after a commit ([`AckPolicy::AfterCommit`]); with
    /// [`AckPolicy::Immediate`] every [`Self::receive_on`] does.
    pub fn release_acks(&mut self) {
        for link in &mut self.links {
            for id in std::mem::take(&mut link.to_ack) {
                let Some(a) = self
                    .sessions
                    .get(&id)
                    .and_then(|s| Ack::of(id.0, id.1, &s.seq))
                else {
                    continue;
                };
                let mut wire = [0u8; latentbki::frame::ack::MAX_ACK_WIRE];
                if let Some(n) = a.encode(&mut wire) {
                    link.ack_bytes.extend_from_slice(&wire[..n]);
                    link.acks += 1;
                }
            }
        }
    }

    /// Add a link (its own decoder state and acknowledgements); it takes the map's configuration, or
    /// adopts the first valid session header like every link until one did.
    pub fn add_link(&mut self) -> LinkId {
        let config = self.map.as_ref().map(|m| *m.config());
        self.links.push(Link::new(config));
        LinkId(self.links.len() as u32 - 1)
    }
    /// Links so far (at least one).
    pub fn link_count(&self) -> usize {
        self.links.len()
    }
    /// What a link delivered (zeros for a link that does not exist).
    pub fn link_stats(&self, link: LinkId) -> LinkCounters {
        let Some(l) = self.links.get(link.0 as usize) else {
            return LinkCounters::default();
        };
        let mut receive = l.stats;
        receive.decoder = l.receiver.decoder_stats();
        receive.rejected = l.receiver.refusals();
        LinkCounters {
            bytes: l.bytes,
            receive,
            acks: l.acks,
        }
    }

    /// Track the voxels every frame changes for [`BaseStation::take_watched`] (a live view).
    pub fn watch(&mut self) {
        self.watched.get_or_insert_with(HashSet::new);
    }
    /// The voxels changed since the last call (empty unless [`BaseStation::watch`]ed).
    pub fn take_watched(&mut self) -> Vec<VoxelKey> {
        self.watched
            .as_mut()
            .map_or_else(Vec::new, |w| w.drain().collect())
    }

    /// Keep a copy of every accepted frame body (tests audit them against what was sent).
    pub fn keep_journal(&mut self) {
        self.journal = Some(Vec::new());
    }
    /// The accepted frames, if kept.
    pub fn journal(&self) -> &[JournalEntry] {
        self.journal.as_deref().unwrap_or(&[])
    }

    /// The global map (None until a configuration is known).
    pub fn map(&self) -> Option<&GlobalMap<D>> {
        self.map.as_ref()
    }
    /// Take the global map out.
    pub fn into_map(self) -> Option<GlobalMap<D>> {
        self.map
    }
    /// Counters so far, every link together.
    pub fn stats(&self) -> ReceiveStats {
        let mut s = ReceiveStats::default();
        for l in &self.links {
            s.decoder += l.receiver.decoder_stats();
            s.rejected += l.receiver.refusals();
            s.frames += l.stats.frames;
            s.merged += l.stats.merged;
            s.updated += l.stats.updated;
            s.ignored += l.stats.ignored;
            s.clamped_mean_scale += l.stats.clamped_mean_scale;
            s.clamped_psi += l.stats.clamped_psi;
        }
        s.lost = self.sessions.values().map(|v| v.seq.lost).sum();
        s.late = self.sessions.values().map(|v| v.seq.late).sum();
        s
    }
    /// Every `(robot, session)` seen.
    pub fn sessions(&self) -> &BTreeMap<(u16, u32), SessionState> {
        &self.sessions
    }

    /// Feed received bytes (any chunking) of link 0. Acknowledgements of what they carried wait in
    /// [`Self::take_acks`].
    pub fn receive(&mut self, bytes: &[u8]) {
        self.receive_on(LinkId(0), bytes);
    }

    /// Feed bytes received on `link` (any chunking; a link not added yet is added, with every link before
    /// it). Acknowledgements of what they carried wait in [`Self::take_acks_on`] — at once, or after the
    /// next commit ([`AckPolicy`]).
    pub fn receive_on(&mut self, link: LinkId, mut bytes: &[u8]) {
        while self.links.len() <= link.0 as usize {
            self.add_link();
        }
        let li = link.0 as usize;
        self.links[li].bytes += bytes.len() as u64;
        while !bytes.is_empty() {
            let mut table = Table {
                sessions: &mut self.sessions,
                dirty: &mut self.dirty_sessions,
            };
            // This link, and the others (which share a configuration it adopts).
            let (before, from) = self.links.split_at_mut(li);
            let Some((l, after)) = from.split_first_mut() else {
                return;
            };
            let (frame, ack, rest) = match l.receiver.feed(bytes, &mut table) {
                Receipt::NeedMore => break,
                Receipt::Refused { ack, rest, .. } => (None, ack, rest),
                Receipt::Accepted { frame, rest } => (Some(frame), frame.ack, rest),
            };
            bytes = rest;
            if let Some(a) = ack {
                l.to_ack.insert((a.robot, a.session));
            }
            let Some(frame) = frame else { continue };
            if self.map.is_none() {
                // This link's receiver adopted the first valid session header's configuration: it is
                // every link's.
                self.map = GlobalMap::new(frame.config).ok();
                self.config_dirty = self.map.is_some();
                for other in before.iter_mut().chain(after.iter_mut()) {
                    other.receiver.adopt(frame.config);
                }
            }
            let header = frame.header;
            let state = self
                .sessions
                .entry((header.robot, header.session))
                .or_default();
            l.stats.frames += 1;
            match frame.message {
                Message::Session(_) => state.header_seen = true,
                Message::Stats(l) => state.link = Some(l),
                Message::Voxels(_) => {}
            }
            if let Some(j) = &mut self.journal {
                j.push(JournalEntry {
                    robot: header.robot,
                    session: header.session,
                    seq: header.seq,
                    body: frame.body.to_vec(),
                });
            }
            let Message::Voxels(batch) = frame.message else {
                continue;
            };
            let Some(map) = &mut self.map else { continue };
            // Every summary was validated by the receiver before the frame was accepted.
            for s in batch.iter::<D>(frame.config.codec).flatten() {
                Self::apply(
                    map,
                    &mut l.stats,
                    &mut self.dirty_voxels,
                    self.watched.as_mut(),
                    &header,
                    &s,
                );
            }
        }
        if self.ack_policy == AckPolicy::Immediate {
            self.release_acks();
        }
    }

    /// The acknowledgements to send back on link 0 (bytes for the link's other direction), taken.
    pub fn take_acks(&mut self) -> Vec<u8> {
        self.take_acks_on(LinkId(0))
    }

    /// The acknowledgements released for `link`, taken.
    pub fn take_acks_on(&mut self, link: LinkId) -> Vec<u8> {
        self.links
            .get_mut(link.0 as usize)
            .map_or_else(Vec::new, |l| std::mem::take(&mut l.ack_bytes))
    }

    fn apply(
        map: &mut GlobalMap<D>,
        stats: &mut ReceiveStats,
        dirty: &mut HashSet<VoxelKey>,
        watched: Option<&mut HashSet<VoxelKey>>,
        header: &latentbki::wire::FrameHeader,
        s: &Summary<D>,
    ) {
        match map.apply(header.robot, header.session, header.seq, s) {
            Applied::Merged => stats.merged += 1,
            Applied::Updated => stats.updated += 1,
            Applied::Stale | Applied::DuplicateFinal => {
                stats.ignored += 1;
                return;
            }
        }
        dirty.insert(s.key);
        if let Some(w) = watched {
            w.insert(s.key);
        }
        stats.clamped_mean_scale += u32::from(s.at_ceiling.mean_scale);
        stats.clamped_psi += u32::from(s.at_ceiling.psi);
    }
}

/// The base station's sessions as the core receiver's [`SessionTable`]: unbounded, and every session the
/// receiver's sequence tracking touches is a change for the store.
struct Table<'a> {
    sessions: &'a mut BTreeMap<(u16, u32), SessionState>,
    dirty: &'a mut HashSet<(u16, u32)>,
}

impl SessionTable for Table<'_> {
    fn tracker(&mut self, robot: u16, session: u32) -> Option<&mut SeqTracker> {
        self.dirty.insert((robot, session));
        Some(&mut self.sessions.entry((robot, session)).or_default().seq)
    }
}

/// A session configuration as the store keeps it: its postcard encoding, then the half-life (f32
/// little-endian) when the session forgets, then the Rice byte when its summaries are Rice-coded — the
/// same bytes as the session message on the wire.
fn config_to_bytes(c: &SessionConfig) -> Vec<u8> {
    let mut out = postcard::to_stdvec(c).expect("a session config serializes");
    if c.half_life > 0.0 {
        out.extend_from_slice(&c.half_life.to_le_bytes());
    }
    if c.codec.rice {
        out.push(latentbki::wire::messages::RICE_EXTENSION);
    }
    out
}

/// [`config_to_bytes`] read back.
fn config_from_bytes(bytes: &[u8]) -> Result<SessionConfig, String> {
    let (mut c, mut rest): (SessionConfig, _) =
        postcard::take_from_bytes(bytes).map_err(|e| e.to_string())?;
    if let [ext @ .., latentbki::wire::messages::RICE_EXTENSION] = rest {
        if ext.is_empty() || ext.len() == 4 {
            c.codec.rice = true;
            rest = ext;
        }
    }
    match rest {
        [] => {}
        &[a, b, c2, d] => c.half_life = f32::from_le_bytes([a, b, c2, d]),
        _ => return Err(format!("{} trailing bytes", rest.len())),
    }
    Ok(c)
}

#[cfg(test)]
mod config_bytes_tests {
    use super::{config_from_bytes, config_to_bytes};
    use latentbki::wire::{SessionConfig, SummaryCodec};
    use latentbki::MapConfig;

    /// A stored configuration reads back as it was: packed or Rice-coded, forgetting or not (the fuzz
    /// target `base_station_db` found the Rice flag lost on a reopen).
    #[test]
    fn stored_configurations_read_back_with_their_coding_and_half_life() {
        for rice in [false, true] {
            for half_life in [None, latentbki::forget::Forgetting::new(50.0)] {
                let codec = SummaryCodec {
                    rice,
                    ..SummaryCodec::DEFAULT
                };
                let c = SessionConfig::new(&MapConfig::default(), 16, codec, 3)
                    .with_forgetting(half_life);
                let back = config_from_bytes(&config_to_bytes(&c)).unwrap();
                assert_eq!(back, c);
                assert_eq!(back.id(), c.id());
            }
        }
    }
}
