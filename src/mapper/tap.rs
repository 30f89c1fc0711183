//! The tap through which a program sees every voxel the map hands to the link (exact statistics, e.g. for
//! an evaluation) without assembling a second robot.

use crate::sink::{Evicted, EvictionSink, SinkFull};

/// Sees every voxel the map hands to the link, with its exact statistics (the map evicted it and the
/// encoder took it). An evaluation or a log taps evictions here; a firmware needs none ([`NoTap`]).
pub trait EvictionTap<const D: usize> {
    /// One voxel handed to the link.
    fn evicted(&mut self, voxel: &Evicted<'_, D>);
}

/// No tap (what [`super::Mapper::begin_frame`] and [`super::Mapper::drain`] use).
#[derive(Clone, Copy, Debug, Default)]
pub struct NoTap;

impl<const D: usize> EvictionTap<D> for NoTap {
    #[inline(always)]
    fn evicted(&mut self, _: &Evicted<'_, D>) {}
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
}
