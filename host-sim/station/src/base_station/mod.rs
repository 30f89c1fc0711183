//! The base station's state: its links, the global map, the sessions and their sequence numbers, and the
//! acknowledgements — bytes in, checked by the core's receiver, applied to the map whole or refused.

use crate::global_map::{Applied, GlobalMap};
use crate::session::SessionState;
use latentbki::frame::{Ack, DecoderStats, SeqTracker};
use latentbki::key::VoxelKey;
use latentbki::receiver::{Receipt, Receiver, Refusals, SessionTable};
use latentbki::wire::{Message, SessionConfig, Summary, WireError};
use std::collections::{BTreeMap, HashSet};

mod merge;
mod persist;

/// Largest encoded frame the base station accepts (bytes between delimiters).
pub const MAX_FRAME: usize = 4096;

/// What the base station has seen.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ReceiveStats {
    /// Runs of bytes refused by the frame layer (COBS, length, CRC, overflow).
    pub decoder: DecoderStats,
    /// Frames refused after the frame layer.
    pub refused: Refusals,
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
        receive.refused = l.receiver.refusals();
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
            s.refused += l.receiver.refusals();
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
