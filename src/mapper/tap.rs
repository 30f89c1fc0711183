//! The tap through which a program sees every voxel the map hands to the link (exact statistics, e.g. for
//! an evaluation) without assembling a second robot.

use crate::sink::{Evicted, EvictedStored, EvictionSink, SinkFull};

/// Sees every voxel the map hands to the link, with its exact statistics (the map evicted it and the
/// encoder took it). An evaluation or a log taps evictions here; a firmware needs none ([`NoTap`]).
pub trait EvictionTap<const D: usize> {
    /// One voxel handed to the link.
    fn evicted(&mut self, voxel: &Evicted<'_, D>);

    /// Whether the tap looks at voxels at all: voxels a link takes as stored codes are decoded for it only
    /// if so. True unless the tap says otherwise ([`NoTap`]).
    #[inline(always)]
    fn sees(&self) -> bool {
        true
    }
}

/// No tap (what [`super::Mapper::begin_frame`] and [`super::Mapper::drain`] use).
#[derive(Clone, Copy, Debug, Default)]
pub struct NoTap;

impl<const D: usize> EvictionTap<D> for NoTap {
    #[inline(always)]
    fn evicted(&mut self, _: &Evicted<'_, D>) {}

    #[inline(always)]
    fn sees(&self) -> bool {
        false
    }
}

impl<const D: usize, F: FnMut(&Evicted<'_, D>)> EvictionTap<D> for F {
    fn evicted(&mut self, voxel: &Evicted<'_, D>) {
        self(voxel)
    }
}

/// The encoder as the map's sink, with a tap on what it takes.
pub(super) struct Tapped<'a, S, T> {
    pub(super) sink: &'a mut S,
    pub(super) tap: &'a mut T,
}

impl<const D: usize, S: EvictionSink<D>, T: EvictionTap<D>> EvictionSink<D> for Tapped<'_, S, T> {
    #[inline(always)]
    fn evict(&mut self, voxel: Evicted<'_, D>) -> Result<(), SinkFull> {
        self.sink.evict(voxel)?;
        self.tap.evicted(&voxel);
        Ok(())
    }

    /// The codes go to the sink undecoded when it takes them; a tap that sees voxels gets them decoded
    /// (what the link sent: the codes, a hot voxel's points cooled into them).
    #[inline(always)]
    fn wants_stored(&self) -> bool {
        self.sink.wants_stored()
    }

    #[inline(always)]
    fn evict_stored(&mut self, voxel: EvictedStored<'_>) -> Result<(), SinkFull> {
        self.sink.evict_stored(voxel)?;
        if self.tap.sees() {
            let mut obs = crate::obs::ObsStats::EMPTY;
            if voxel.decode_into(&mut obs).is_some() {
                self.tap.evicted(&Evicted {
                    key: voxel.key,
                    obs: &obs,
                    residency: voxel.residency,
                    time: voxel.time,
                });
            }
        }
        Ok(())
    }
}
