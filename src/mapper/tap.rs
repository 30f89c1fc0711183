//! What a [`super::Mapper`] adds around its map and encoder: live updates' settings, and the tap through
//! which a program sees every voxel the map hands to the link (exact statistics, e.g. for an evaluation)
//! without assembling a second robot.

use crate::sink::{Evicted, EvictionSink, SinkFull};

/// Live updates: each tick streams the held voxels that changed since they were last streamed, in ring
/// order over the map's slots (each gets its turn), after the tick's final voxels and within its own share
/// of the tick's bytes. The base station replaces a live copy by the next one and by the final one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LiveUpdates {
    /// Bytes per tick at most spent on live updates (0 = off). Final voxels go first; live updates use
    /// what they leave, up to this.
    pub bytes_per_tick: u32,
    /// Stream live updates every this many ticks (1 = every tick).
    pub every_ticks: u32,
}

impl LiveUpdates {
    /// Only final voxels.
    pub const OFF: Self = Self {
        bytes_per_tick: 0,
        every_ticks: 1,
    };
    /// Up to `bytes_per_tick` per tick, every tick.
    pub const fn new(bytes_per_tick: u32) -> Self {
        Self {
            bytes_per_tick,
            every_ticks: 1,
        }
    }
}

/// Sees every voxel the map hands to the link, with its exact statistics (the map evicted it and the
/// encoder took it). An evaluation or a log taps evictions here; a firmware needs none ([`NoTap`]).
pub trait EvictionTap<const D: usize> {
    /// One voxel handed to the link.
    fn evicted(&mut self, voxel: &Evicted<'_, D>);
}

/// No tap (what [`Mapper::begin_frame`] and [`Mapper::drain`] use).
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
