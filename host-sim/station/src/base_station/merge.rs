//! Two base stations' maps and sessions as one (`host-sim map-merge`): the map one base station would hold
//! had it received every frame of both ([`GlobalMap::merge`]), and each session's sequence state as the
//! union of what the two received, so the merged database continues either stream without applying a
//! frame twice.

use super::BaseStation;
use crate::global_map::GlobalMap;
use crate::global_map::{MergeError, MergeReport};
use crate::session::SessionState;

impl<const D: usize> BaseStation<D> {
    /// Merge `other`'s map and sessions into this base station's. Everything it holds afterwards is a
    /// change for the store (a fresh database takes all of it in one commit).
    pub fn merge_from(&mut self, other: &BaseStation<D>) -> Result<MergeReport, MergeError> {
        let mut report = MergeReport::default();
        if let Some(theirs) = other.map() {
            match &mut self.map {
                Some(ours) => report = ours.merge(theirs)?,
                None => {
                    let mut fresh = GlobalMap::new(*theirs.config())
                        .map_err(|e| MergeError::Config(format!("{e:?}")))?;
                    report = fresh.merge(theirs)?;
                    for l in &mut self.links {
                        l.receiver.adopt(*theirs.config());
                    }
                    self.map = Some(fresh);
                }
            }
        }
        for (id, theirs) in other.sessions() {
            let ours = self.sessions.entry(*id).or_default();
            *ours = SessionState {
                seq: ours.seq.union(&theirs.seq),
                header_seen: ours.header_seen || theirs.header_seen,
                link: match (ours.link, theirs.link) {
                    // The later report (more frames sent) of the robot's own counters.
                    (Some(a), Some(b)) => Some(if b.frames_sent > a.frames_sent { b } else { a }),
                    (a, b) => a.or(b),
                },
            };
        }
        self.config_dirty = self.map.is_some();
        if let Some(m) = &self.map {
            self.dirty_voxels.extend(m.voxels().map(|(k, _)| *k));
        }
        self.dirty_sessions.extend(self.sessions.keys().copied());
        Ok(report)
    }
}
