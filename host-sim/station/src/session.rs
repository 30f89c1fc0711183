//! What the base station keeps of each `(robot, session)` between runs: its sequence state and last link
//! statistics as a versioned record, the session configuration as stored, and why a stored map cannot be
//! restored.

use crate::store::StoreError;
use latentbki::frame::SeqTracker;
use latentbki::wire::{LinkStats, SessionConfig};

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

/// A session configuration as the store keeps it: its postcard encoding, then the half-life (f32
/// little-endian) when the session forgets, then the Rice byte when its summaries are Rice-coded — the
/// same bytes as the session message on the wire.
pub(crate) fn config_to_bytes(c: &SessionConfig) -> Vec<u8> {
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
pub(crate) fn config_from_bytes(bytes: &[u8]) -> Result<SessionConfig, String> {
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
