//! The receiving end of the link: bytes in, frames that may be applied out — the spec's acceptance rules in
//! one place, so that the base station, a gateway microcontroller or anyone's Rust receiver apply exactly
//! the same ones.
//!
//! Each run of bytes goes through every check before anything may use it: COBS and CRC
//! ([`FrameDecoder`]), protocol version and a complete parse ([`parse_body`]), the configuration-id gate,
//! every summary of a voxel frame, and the sequence number of its `(robot, session)` ([`SeqTracker`]).
//! A frame is accepted whole or refused whole, and every refusal is counted by reason. Accepted frames,
//! and duplicates, come with the [`Ack`] to send back (protocol 3): the robot frees what it was
//! acknowledged and re-sends what was not.
//!
//! No heap: the decoder's buffer is inline (`N` bytes, 4,096 at the base station) and sequence state lives
//! in a [`SessionTable`] the caller provides — [`Sessions`] holds a fixed number in place; the base station
//! keeps its own (persisted) map of them.
//!
//! ```
//! use latentbki::frame::{EncoderSettings, FrameEncoder, Resend};
//! use latentbki::receiver::{Receiver, Sessions, Step};
//! use latentbki::wire::{Message, SessionConfig, SummaryCodec, NO_FEATURE_SPACE};
//! use latentbki::{key::VoxelKey, obs::ObsStats, sink::EvictionSink, MapConfig};
//! const D: usize = 8;
//! let config = SessionConfig::new(&MapConfig::DEFAULT, D, SummaryCodec::DEFAULT, NO_FEATURE_SPACE);
//! // A robot (id 1, session 7) that keeps frames until they are acknowledged.
//! let settings = EncoderSettings::new(1, 7).with_resend(Resend::new(600, 4));
//! let mut robot = FrameEncoder::<D, 1024, 256>::new(config, settings).unwrap();
//! let obs = ObsStats { count: 2.0, mean: [0.25; D], scatter: [0.01; D] };
//! let voxel = latentbki::frame::live(VoxelKey::new(1, 2, 3), &obs, 0);
//! robot.evict(voxel).unwrap();
//! let mut wire = [0u8; 512];
//! let mut out: &mut [u8] = &mut wire;
//! robot.tick(&mut out, 512, core::iter::empty()).unwrap(); // header, then the voxel
//! let sent = 512 - out.len();
//! assert_eq!(robot.unacknowledged(), 2);
//!
//! // The receiver knows the configuration; it tracks up to 4 sessions.
//! let mut rx = Receiver::<D, 512>::new(Some(config));
//! let mut sessions = Sessions::<4>::new();
//! let mut input = &wire[..sent];
//! let mut voxels = 0;
//! while let Step::Accepted { frame, rest } = rx.feed(input, &mut sessions).into_step() {
//!     if let Some(f) = frame {
//!         if let Message::Voxels(batch) = f.message {
//!             voxels += batch.count;
//!         }
//!         robot.acknowledge(&f.ack.unwrap()); // over the back channel in real life
//!     }
//!     input = rest;
//! }
//! assert_eq!(voxels, 1);
//! assert_eq!(robot.unacknowledged(), 0);
//! ```

use crate::frame::{Ack, DecoderStats, Feed, FrameDecoder, FrameError, SeqTracker, SeqVerdict};
use crate::wire::{parse_body, FrameHeader, Message, SessionConfig, WireError};

/// Why a frame was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Refusal {
    /// The frame layer refused the bytes (COBS, length, CRC, longer than the buffer).
    Frame(FrameError),
    /// Another protocol version.
    Version(u8),
    /// Did not parse, or bytes after the message.
    Malformed,
    /// Not the receiver's configuration, or no configuration known yet (frames before the first session
    /// header of a receiver that adopts one).
    WrongConfig,
    /// A summary in the frame is invalid: the whole frame is refused.
    InvalidVoxel,
    /// Received before (its acknowledgement is repeated).
    Duplicate,
    /// Older than the 64-frame sequence window.
    TooOld,
    /// The session table is full: a new `(robot, session)` cannot be tracked.
    NoSessionRoom,
}

/// Refusals after the frame layer, by reason.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Refusals {
    /// Unknown protocol version.
    pub version: u32,
    /// Did not parse (or trailing bytes).
    pub malformed: u32,
    /// Configuration id is not the map's, a session header with another configuration, or no
    /// configuration yet.
    pub wrong_config: u32,
    /// A summary in the frame was invalid (bad key, count, weight; stamped in a session that does not forget
    /// or unstamped in one that does): the whole frame was refused.
    pub invalid_voxel: u32,
    /// Frame received before (by sequence number).
    pub duplicate_frames: u32,
    /// Frame older than the sequence window.
    pub too_old: u32,
    /// No room to track another session.
    pub no_session_room: u32,
}

impl core::ops::AddAssign for Refusals {
    /// Sum two receivers' counters (saturating): a base station's links together.
    fn add_assign(&mut self, o: Self) {
        let add = |a: &mut u32, b: u32| *a = a.saturating_add(b);
        add(&mut self.version, o.version);
        add(&mut self.malformed, o.malformed);
        add(&mut self.wrong_config, o.wrong_config);
        add(&mut self.invalid_voxel, o.invalid_voxel);
        add(&mut self.duplicate_frames, o.duplicate_frames);
        add(&mut self.too_old, o.too_old);
        add(&mut self.no_session_room, o.no_session_room);
    }
}

impl Refusals {
    fn count(&mut self, r: Refusal) {
        let c = match r {
            Refusal::Frame(_) => return, // counted by the decoder
            Refusal::Version(_) => &mut self.version,
            Refusal::Malformed => &mut self.malformed,
            Refusal::WrongConfig => &mut self.wrong_config,
            Refusal::InvalidVoxel => &mut self.invalid_voxel,
            Refusal::Duplicate => &mut self.duplicate_frames,
            Refusal::TooOld => &mut self.too_old,
            Refusal::NoSessionRoom => &mut self.no_session_room,
        };
        *c = c.saturating_add(1);
    }
}

/// Where a receiver keeps the sequence state of each `(robot, session)`.
pub trait SessionTable {
    /// The tracker of `(robot, session)`, created if new; `None` if there is no room for it.
    fn tracker(&mut self, robot: u16, session: u32) -> Option<&mut SeqTracker>;
}

/// A fixed table of up to `S` sessions (no heap).
#[derive(Clone, Debug, Default)]
pub struct Sessions<const S: usize> {
    entries: heapless::Vec<((u16, u32), SeqTracker), S>,
}

impl<const S: usize> Sessions<S> {
    /// An empty table.
    pub const fn new() -> Self {
        Self {
            entries: heapless::Vec::new(),
        }
    }
    /// Every session tracked, with its sequence state.
    pub fn iter(&self) -> impl Iterator<Item = &((u16, u32), SeqTracker)> {
        self.entries.iter()
    }
}

impl<const S: usize> SessionTable for Sessions<S> {
    fn tracker(&mut self, robot: u16, session: u32) -> Option<&mut SeqTracker> {
        let id = (robot, session);
        let i = match self.entries.iter().position(|(k, _)| *k == id) {
            Some(i) => i,
            None => {
                self.entries.push((id, SeqTracker::default())).ok()?;
                self.entries.len() - 1
            }
        };
        self.entries.get_mut(i).map(|(_, t)| t)
    }
}

/// A frame that passed every check: apply it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Accepted<'a> {
    /// Its header.
    pub header: FrameHeader,
    /// Its message (every summary in it is valid for the receiver's configuration).
    pub message: Message<'a>,
    /// The body as received (header + message), e.g. for a journal.
    pub body: &'a [u8],
    /// The configuration it was accepted under (its codec decodes the summaries).
    pub config: SessionConfig,
    /// New, or late (an older frame not received before).
    pub verdict: SeqVerdict,
    /// What to send back to the robot.
    pub ack: Option<Ack>,
}

/// What [`Receiver::feed`] found.
#[derive(Debug, PartialEq)]
pub enum Receipt<'a, 'b> {
    /// All input consumed, no frame completed.
    NeedMore,
    /// A frame to apply; `rest` is the input not yet consumed.
    Accepted {
        /// The frame.
        frame: Accepted<'a>,
        /// Unconsumed input.
        rest: &'b [u8],
    },
    /// A run of bytes refused (and counted); `rest` is the input not yet consumed.
    Refused {
        /// Why.
        reason: Refusal,
        /// The frame's header, if it got as far as parsing.
        header: Option<FrameHeader>,
        /// For a duplicate: the acknowledgement to repeat (the robot may have missed the last one).
        ack: Option<Ack>,
        /// Unconsumed input.
        rest: &'b [u8],
    },
}

/// A [`Receipt`] seen as "maybe a frame, and the rest" (see the module's example).
#[derive(Debug, PartialEq)]
pub enum Step<'a, 'b> {
    /// All input consumed.
    Done,
    /// One run of bytes handled: a frame to apply, or `None` if it was refused.
    Accepted {
        /// The frame, if accepted.
        frame: Option<Accepted<'a>>,
        /// Unconsumed input.
        rest: &'b [u8],
    },
}

impl<'a, 'b> Receipt<'a, 'b> {
    /// Accepted frames as `Some`, refusals as `None` (counted already), end of input as `Done`.
    pub fn into_step(self) -> Step<'a, 'b> {
        match self {
            Self::NeedMore => Step::Done,
            Self::Accepted { frame, rest } => Step::Accepted {
                frame: Some(frame),
                rest,
            },
            Self::Refused { rest, .. } => Step::Accepted { frame: None, rest },
        }
    }
}

/// Whether a receiver may adopt `c`: valid for dimension `D` ([`SessionConfig::validate`]), and a kernel
/// that per-voxel statistics can be gathered through — the voxel-offset kernel (`subvoxel_cells` 0) or one
/// sub-cell per axis (1: its centre is the voxel's, so its weights are the voxel-offset kernel's, bit for
/// bit). Finer sub-cells weigh each point by where it fell inside its voxel, which a summary does not say.
pub fn receivable<const D: usize>(c: &SessionConfig) -> bool {
    c.validate(D).is_ok() && c.subvoxel_cells <= 1
}

/// The receiving side of one link: a frame decoder with an `N`-byte buffer for `D`-dimensional sessions.
pub struct Receiver<const D: usize, const N: usize> {
    decoder: FrameDecoder<N>,
    config: Option<SessionConfig>,
    refusals: Refusals,
    accepted: u32,
}

impl<const D: usize, const N: usize> Receiver<D, N> {
    /// A receiver of sessions with this configuration, or (`None`) one that adopts the configuration of
    /// the first valid session header it receives and refuses every frame before it.
    pub const fn new(config: Option<SessionConfig>) -> Self {
        Self {
            decoder: FrameDecoder::new(),
            config,
            refusals: Refusals {
                version: 0,
                malformed: 0,
                wrong_config: 0,
                invalid_voxel: 0,
                duplicate_frames: 0,
                too_old: 0,
                no_session_room: 0,
            },
            accepted: 0,
        }
    }

    /// The configuration frames must have (`None` until adopted).
    pub fn config(&self) -> Option<&SessionConfig> {
        self.config.as_ref()
    }
    /// Take `config` as the receiver's if it has none yet (it is [`receivable`]): receivers that feed one
    /// map (a base station's links) share the configuration the first of them adopted. Returns whether the
    /// receiver's configuration is now `config`.
    pub fn adopt(&mut self, config: SessionConfig) -> bool {
        if self.config.is_none() && receivable::<D>(&config) {
            self.config = Some(config);
        }
        self.config == Some(config)
    }
    /// Refusals after the frame layer.
    pub fn refusals(&self) -> Refusals {
        self.refusals
    }
    /// Refusals of the frame layer (and frames that passed it).
    pub fn decoder_stats(&self) -> DecoderStats {
        self.decoder.stats()
    }
    /// Frames accepted.
    pub fn accepted(&self) -> u32 {
        self.accepted
    }

    /// Consume input up to the end of the next frame (or of the input); call again with `rest`.
    pub fn feed<'a, 'b>(
        &'a mut self,
        input: &'b [u8],
        sessions: &mut impl SessionTable,
    ) -> Receipt<'a, 'b> {
        let (body, rest) = match self.decoder.feed(input) {
            Feed::NeedMore => return Receipt::NeedMore,
            Feed::Error { error, rest } => {
                return Receipt::Refused {
                    reason: Refusal::Frame(error),
                    header: None,
                    ack: None,
                    rest,
                }
            }
            Feed::Frame { body, rest } => (body, rest),
        };
        let (header, message) = match parse_body(body) {
            Ok(x) => x,
            Err(e) => {
                let reason = match e {
                    WireError::UnknownVersion(v) => Refusal::Version(v),
                    _ => Refusal::Malformed,
                };
                self.refusals.count(reason);
                return Receipt::Refused {
                    reason,
                    header: None,
                    ack: None,
                    rest,
                };
            }
        };
        let refuse = |refusals: &mut Refusals, reason, ack| {
            refusals.count(reason);
            Receipt::Refused {
                reason,
                header: Some(header),
                ack,
                rest,
            }
        };
        if self.config.is_none() {
            if let Message::Session(c) = message {
                if c.id() == header.config_id && receivable::<D>(&c) {
                    self.config = Some(c);
                }
            }
        }
        let Some(config) = self.config else {
            return refuse(&mut self.refusals, Refusal::WrongConfig, None);
        };
        let session_ok = match message {
            Message::Session(c) => c == config,
            _ => true,
        };
        if header.config_id != config.id() || !session_ok {
            return refuse(&mut self.refusals, Refusal::WrongConfig, None);
        }
        if let Message::Voxels(batch) = message {
            // A session that forgets sends stamped summaries only, one that does not never does.
            let forgets = config.forgetting().is_some();
            if batch
                .iter::<D>(config.codec)
                .any(|s| s.map_or(true, |s| s.time.is_some() != forgets))
            {
                return refuse(&mut self.refusals, Refusal::InvalidVoxel, None);
            }
        }
        let Some(tracker) = sessions.tracker(header.robot, header.session) else {
            return refuse(&mut self.refusals, Refusal::NoSessionRoom, None);
        };
        let verdict = tracker.accept(header.seq);
        let ack = Ack::of(header.robot, header.session, tracker);
        match verdict {
            SeqVerdict::New | SeqVerdict::Late => {}
            SeqVerdict::Duplicate => return refuse(&mut self.refusals, Refusal::Duplicate, ack),
            SeqVerdict::TooOld => return refuse(&mut self.refusals, Refusal::TooOld, None),
        }
        self.accepted = self.accepted.saturating_add(1);
        Receipt::Accepted {
            frame: Accepted {
                header,
                message,
                body,
                config,
                verdict,
                ack,
            },
            rest,
        }
    }
}

#[cfg(test)]
mod tests;
