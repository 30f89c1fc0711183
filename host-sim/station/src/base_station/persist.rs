//! A base station and its map database: restored from what a store holds, and handing the store exactly
//! what changed since the last commit, at frame boundaries only.

use super::BaseStation;
use crate::global_map::{GlobalMap, GlobalVoxel};
use crate::session::{config_from_bytes, config_to_bytes, RestoreError, SessionState};
use crate::store::{Changes, MapStore, Snapshot, StoreError};

impl<const D: usize> BaseStation<D> {
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
    /// [`AckPolicy::AfterCommit`](super::AckPolicy::AfterCommit)) release the acknowledgements of every frame handled so far, now durable.
    pub fn commit(&mut self, store: &mut dyn MapStore) -> Result<(), StoreError> {
        if self.has_changes() {
            store.commit(&self.changes())?;
            self.committed();
        }
        self.release_acks();
        Ok(())
    }
}
