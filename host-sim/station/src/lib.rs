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

mod base_station;
pub mod export;
pub mod global_map;
pub mod obs_map;
pub mod png_io;
mod session;
pub mod store;
#[cfg(feature = "view")]
pub mod view;

pub use base_station::{
    AckPolicy, BaseStation, JournalEntry, LinkCounters, LinkId, ReceiveStats, MAX_FRAME,
};
pub use global_map::{
    Applied, ContributionId, GlobalMap, GlobalVoxel, MergeError, MergeReport, RecordError,
    Uncertainty, VOCAB_CAP,
};
/// Frames refused after COBS/CRC, by reason (the core receiver's counters; a refused point is a
/// `latentbki::Rejection`, counted on the robot).
pub use latentbki::receiver::Refusals;
pub use obs_map::ObsMap;
pub use session::{RestoreError, SessionState, SESSION_RECORD_VERSION};
