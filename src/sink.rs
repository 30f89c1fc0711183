//! Where evicted voxels go: nothing leaves the local map silently.
//!
//! The on-device map is small, so voxels leave it — when the robot moves on or the pool is full. Each one
//! is handed to a caller-provided [`EvictionSink`] (typically the frame encoder that streams it to the base
//! station). A sink may refuse (a full transmit buffer: back-pressure); the map then keeps the voxel and
//! reports it, rather than dropping data.

use crate::key::VoxelKey;
use crate::obs::ObsStats;
use crate::quant::StoredCodes;

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

/// One voxel leaving the local map as its codes, not decoded ([`EvictionSink::wants_stored`]): what a
/// link that carries the map's own codes (`wire::SummaryCodec::STORED`) copies onto the wire.
#[derive(Clone, Copy, Debug)]
pub struct EvictedStored<'a> {
    /// Which voxel.
    pub key: VoxelKey,
    /// Its codes as the map holds them (n exact; the mean as the codes hold it: a map whose
    /// [`crate::quant::MeanWeights`] have shifts weighs it, see [`Self::weighed`]).
    pub codes: StoredCodes<'a>,
    /// As [`Evicted::residency`].
    pub residency: u32,
    /// As [`Evicted::time`].
    pub time: u32,
    /// Whether the codes hold a weighed mean (the map's weights have shifts): only its own map can weigh
    /// it back, so a link refuses such codes.
    pub weighed: bool,
}

impl EvictedStored<'_> {
    /// The statistics the codes stand for, decoded (`None` if they are not the codes of a valid
    /// D-dimensional voxel, or hold a weighed mean).
    pub fn decode_into<const D: usize>(&self, out: &mut ObsStats<D>) -> Option<()> {
        if self.weighed {
            return None;
        }
        self.codes.decode_into(out)
    }
}

/// The sink refused a voxel (no room right now); the map keeps it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SinkFull;

/// Receives evicted voxels.
pub trait EvictionSink<const D: usize> {
    /// Take one voxel, or refuse with [`SinkFull`] (the map then keeps it).
    fn evict(&mut self, voxel: Evicted<'_, D>) -> Result<(), SinkFull>;

    /// Whether this sink takes voxels as their codes ([`Self::evict_stored`]), so that the map need not
    /// decode them. False unless the sink says so.
    #[inline(always)]
    fn wants_stored(&self) -> bool {
        false
    }

    /// Take one voxel as its codes (the map calls this only when [`Self::wants_stored`]). By default the
    /// codes are decoded and handed to [`Self::evict`]; codes that do not decode are dropped.
    fn evict_stored(&mut self, voxel: EvictedStored<'_>) -> Result<(), SinkFull> {
        let mut obs = ObsStats::EMPTY;
        if voxel.decode_into(&mut obs).is_none() {
            return Ok(());
        }
        self.evict(Evicted {
            key: voxel.key,
            obs: &obs,
            residency: voxel.residency,
            time: voxel.time,
        })
    }
}

impl<const D: usize, F: FnMut(Evicted<'_, D>) -> Result<(), SinkFull>> EvictionSink<D> for F {
    fn evict(&mut self, voxel: Evicted<'_, D>) -> Result<(), SinkFull> {
        self(voxel)
    }
}
