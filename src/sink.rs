//! Where evicted voxels go: nothing leaves the local map silently.
//!
//! The on-device map is small, so voxels leave it — when the robot moves on or the pool is full. Each one
//! is handed to a caller-provided [`EvictionSink`] (typically the frame encoder that streams it to the base
//! station). A sink may refuse (a full transmit buffer: back-pressure); the map then keeps the voxel and
//! reports it, rather than dropping data.

use crate::key::VoxelKey;
use crate::obs::ObsStats;

/// One voxel leaving the local map.
#[derive(Clone, Copy, Debug)]
pub struct Evicted<'a, const D: usize> {
    /// Which voxel.
    pub key: VoxelKey,
    /// What was observed in it while it was resident: point count, mean and scatter (no prior).
    pub obs: &'a ObsStats<D>,
    /// Residency number: increases every time any voxel enters the map, so the same key evicted twice
    /// (observed, forgotten, observed again) carries two different numbers. Observations of different
    /// residencies are disjoint and must be merged, not replaced.
    pub residency: u32,
    /// Tick of the voxel's last change when its map forgets ([`crate::forget`]): `obs` are as of then. 0
    /// in a map that never forgets.
    pub time: u32,
}

/// The sink refused a voxel (no room right now); the map keeps it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SinkFull;

/// Receives evicted voxels.
pub trait EvictionSink<const D: usize> {
    /// Take one voxel, or refuse with [`SinkFull`] (the map then keeps it).
    fn evict(&mut self, voxel: Evicted<'_, D>) -> Result<(), SinkFull>;
}

impl<const D: usize, F: FnMut(Evicted<'_, D>) -> Result<(), SinkFull>> EvictionSink<D> for F {
    fn evict(&mut self, voxel: Evicted<'_, D>) -> Result<(), SinkFull> {
        self(voxel)
    }
}
