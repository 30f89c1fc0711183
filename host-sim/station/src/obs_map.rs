//! The host's fast f32 map: per-voxel observation statistics in dense blocks, posteriors gathered on demand.
//!
//! Why this shape: a point updates only its own voxel's (n, m, S) — one Welford step of D multiply-adds —
//! and a posterior is a kernel-weighted gather of the f³ neighbours' statistics ([`latentbki::obs`], the
//! core's math: [`ObsStats::merge_scaled`] and [`ObsStats::posterior`]). Voxels live in 8³ blocks found
//! through one hash lookup; inside a block a voxel is an array index, so a gather's 27 neighbour lookups
//! cost a few integer operations instead of 27 hash probes, and "every voxel in reach" is a bitmask per
//! block. Results equal the literal paper update (host-sim's `ReferenceMap`) to f32 rounding (tests).
//!
//! Only the voxel-offset kernel can be gathered from per-voxel statistics; a sub-voxel configuration is
//! refused at construction ([`ObsMapError::SubVoxelKernel`]) — host-sim's `ReferenceMap` keeps that mode.
//! Submodule `gather`: every posterior in reach at once (`for_each_posterior`), block by block.

use latentbki::batch::locate;
use latentbki::nalgebra::Isometry3;
use latentbki::{
    forget::Forgetting, forget::Stamped, kernel::KernelLut, key::to_map_frame, key::VoxelKey,
    obs::GatherError, obs::ObsLookup, obs::ObsStats, stats::VoxelStats, ConfigError, MapConfig,
    Prior, RejectionCounts,
};
use rustc_hash::FxHashMap;

mod gather;

/// Voxels per block edge (a power of two).
const EDGE: i32 = 8;
const SHIFT: u32 = EDGE.trailing_zeros();
const MASK: i32 = EDGE - 1;
/// Voxels per block.
const VOLUME: usize = (EDGE * EDGE * EDGE) as usize;
/// 64-bit words of a block's bitmask.
const WORDS: usize = VOLUME / 64;

type BlockKey = [i32; 3];

fn block_of(key: VoxelKey) -> (BlockKey, usize) {
    let [x, y, z] = key.as_array();
    let local = (x & MASK) | ((y & MASK) << SHIFT) | ((z & MASK) << (2 * SHIFT));
    ([x >> SHIFT, y >> SHIFT, z >> SHIFT], local as usize)
}

fn voxel_of(block: BlockKey, local: usize) -> VoxelKey {
    let l = local as i32;
    VoxelKey::new(
        (block[0] << SHIFT) | (l & MASK),
        (block[1] << SHIFT) | ((l >> SHIFT) & MASK),
        (block[2] << SHIFT) | (l >> (2 * SHIFT)),
    )
}

/// The voxels a view's points fall in, with the number of points in each, sorted by key: what
/// [`latentbki::info_gain::view_score`] takes. Points without a key (non-finite, out of range) are left out.
pub fn view_hits(points: &[[f32; 3]], inv_voxel_size: f32) -> Vec<(VoxelKey, f32)> {
    let mut keys: Vec<VoxelKey> = points
        .iter()
        .filter_map(|p| VoxelKey::from_position(*p, inv_voxel_size).ok())
        .collect();
    keys.sort_unstable();
    let mut hits: Vec<(VoxelKey, f32)> = Vec::new();
    for k in keys {
        match hits.last_mut() {
            Some((last, n)) if *last == k => *n += 1.0,
            _ => hits.push((k, 1.0)),
        }
    }
    hits
}

/// Why an [`ObsMap`] cannot be built.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ObsMapError {
    /// The map configuration is invalid.
    #[error("{0}")]
    Config(#[from] ConfigError),
    /// Sub-voxel kernels cannot be gathered from per-voxel statistics.
    #[error("{0}")]
    SubVoxelKernel(#[from] GatherError),
    /// The filter reaches farther than one block.
    #[error("filter reach {0} voxels exceeds the block edge {EDGE}")]
    ReachTooLarge(i32),
}

/// An unbounded f32 map of per-voxel observation statistics.
#[derive(Clone)]
pub struct ObsMap<const D: usize> {
    config: MapConfig,
    lut: KernelLut,
    prior: Prior,
    /// Block key → index into `blocks`.
    index: FxHashMap<BlockKey, u32>,
    /// Per block: its key and, per voxel, 1 + its slot in `stats` (0 = not observed).
    blocks: Vec<(BlockKey, Box<[u32; VOLUME]>)>,
    keys: Vec<VoxelKey>,
    stats: Vec<ObsStats<D>>,
    rejections: RejectionCounts,
    points: u64,
    /// Forgetting ([`latentbki::forget`]): off by default. When on, `times[slot]` is the tick of the slot's
    /// last change and every read decays it to `now`.
    forgetting: Option<Forgetting>,
    times: Vec<u32>,
    now: u32,
}

impl<const D: usize> ObsMap<D> {
    /// An empty map.
    pub fn new(config: MapConfig) -> Result<Self, ObsMapError> {
        let lut = KernelLut::new(&config)?;
        if !lut.is_voxel_offset() {
            return Err(GatherError::SubVoxelKernel.into());
        }
        if lut.reach() > EDGE {
            return Err(ObsMapError::ReachTooLarge(lut.reach()));
        }
        Ok(Self {
            prior: config.prior(),
            config,
            lut,
            index: FxHashMap::default(),
            blocks: Vec::new(),
            keys: Vec::new(),
            stats: Vec::new(),
            rejections: RejectionCounts::default(),
            points: 0,
            forgetting: None,
            times: Vec::new(),
            now: 0,
        })
    }

    /// Integrate one batch of sensor-frame points with their features, seen from `pose` (sensor → map).
    /// Returns how many points were integrated; the others are counted in [`Self::rejections`]. Points and
    /// features are paired in order; an unpaired tail is counted too.
    pub fn integrate(
        &mut self,
        pose: &Isometry3<f32>,
        points: &[[f32; 3]],
        features: &[[f32; D]],
    ) -> usize {
        let mut accepted = 0;
        let mut last: Option<(BlockKey, u32)> = None;
        // Two passes per chunk: first every point's slot (hash lookups, new voxels), then the Welford steps.
        // The second pass knows all its addresses up front, so the processor overlaps the cache misses of
        // a random-order batch instead of taking them one after another.
        const CHUNK: usize = 64;
        let mut slots = [(0u32, 0u32); CHUNK];
        let n = points.len().min(features.len());
        for start in (0..n).step_by(CHUNK) {
            let end = (start + CHUNK).min(n);
            let mut taken = 0;
            for i in start..end {
                let key = match locate(&self.lut, to_map_frame(pose, points[i]), &features[i]) {
                    Ok((key, _)) => key,
                    Err(r) => {
                        self.rejections.count(r);
                        continue;
                    }
                };
                let (bk, local) = block_of(key);
                let b = match last {
                    Some((k, b)) if k == bk => b,
                    _ => {
                        let b = self.block_index_or_insert(bk);
                        last = Some((bk, b));
                        b
                    }
                };
                slots[taken] = (self.slot_or_insert(b, local, key), i as u32);
                taken += 1;
            }
            if self.forgetting.is_some() {
                for &(slot, _) in &slots[..taken] {
                    self.advance(slot as usize);
                }
            }
            for &(slot, i) in &slots[..taken] {
                self.stats[slot as usize].add_point(&features[i as usize]);
            }
            accepted += taken;
        }
        let unpaired = points.len().abs_diff(features.len());
        for _ in 0..unpaired {
            self.rejections.count(latentbki::batch::Rejection::Unpaired);
        }
        self.points += accepted as u64;
        accepted
    }

    /// The slot of voxel `key` (at `local` in block `b`), made empty if it had none.
    fn slot_or_insert(&mut self, b: u32, local: usize, key: VoxelKey) -> u32 {
        let slot_ref = &mut self.blocks[b as usize].1[local];
        if *slot_ref == 0 {
            self.keys.push(key);
            self.stats.push(ObsStats::EMPTY);
            self.times.push(self.now);
            *slot_ref = self.stats.len() as u32;
        }
        *slot_ref - 1
    }

    fn block_index_or_insert(&mut self, bk: BlockKey) -> u32 {
        let next = self.blocks.len() as u32;
        let b = *self.index.entry(bk).or_insert(next);
        if b == next {
            self.blocks.push((bk, Box::new([0; VOLUME])));
        }
        b
    }

    /// Merge another voxel's observations in (e.g. from another robot or a saved map).
    pub fn merge_observations(&mut self, key: VoxelKey, obs: &ObsStats<D>) {
        if obs.is_empty() {
            return;
        }
        let (bk, local) = block_of(key);
        let b = self.block_index_or_insert(bk);
        let slot = self.slot_or_insert(b, local, key);
        self.advance(slot as usize);
        self.stats[slot as usize].merge(obs);
    }

    /// Forget with `forgetting` from now on (`None`: never, the default). Observations already held count
    /// as made at their slot's last change.
    pub fn set_forgetting(&mut self, forgetting: Option<Forgetting>) {
        self.forgetting = forgetting;
    }

    /// Set the mission clock ([`latentbki::forget`]'s clock rule): points integrated from now on are
    /// stamped `now`, and reads decay to it. Without forgetting the clock changes nothing.
    pub fn set_time(&mut self, now: u32) {
        self.now = now;
    }

    /// Bring a slot's statistics to the clock (lazily, on change).
    fn advance(&mut self, slot: usize) {
        if let Some(f) = &self.forgetting {
            let mut v = Stamped {
                obs: self.stats[slot],
                time: self.times[slot],
            };
            v.advance(f, self.now);
            (self.stats[slot], self.times[slot]) = (v.obs, v.time);
        }
    }

    /// A slot's statistics as read now: decayed to the clock when forgetting.
    #[inline]
    fn read(&self, slot: usize) -> ObsStats<D> {
        match &self.forgetting {
            None => self.stats[slot],
            Some(f) => Stamped {
                obs: self.stats[slot],
                time: self.times[slot],
            }
            .at(f, self.now),
        }
    }

    /// Replace a voxel's observations (e.g. the base station's merged statistics after a live update).
    pub fn set_observations(&mut self, key: VoxelKey, obs: &ObsStats<D>) {
        self.set_stamped(key, obs, self.now); // held as of now
    }

    /// Replace a voxel's observations by statistics as of tick `time` (a base station's merged stamped
    /// contributions): reads decay them from that tick by the clock rule.
    pub fn set_stamped(&mut self, key: VoxelKey, obs: &ObsStats<D>, time: u32) {
        let (bk, local) = block_of(key);
        if obs.is_empty() && self.observed(key).is_none() {
            return; // nothing to hold, nothing held
        }
        let b = self.block_index_or_insert(bk);
        let slot = self.slot_or_insert(b, local, key);
        self.stats[slot as usize] = *obs;
        self.times[slot as usize] = time;
    }

    /// The mission tick reads decay to.
    pub fn time(&self) -> u32 {
        self.now
    }

    /// The posterior of one voxel (the prior if nothing is in reach).
    pub fn posterior(&self, key: VoxelKey) -> VoxelStats<D> {
        // The table was checked to be voxel-offset at construction.
        latentbki::obs::gather(&self.lut, self, key)
            .unwrap_or(ObsStats::EMPTY)
            .posterior(&self.prior)
    }

    /// The posterior of a voxel within the kernel's reach of an observation; `None` beyond it.
    pub fn posterior_in_reach(&self, key: VoxelKey) -> Option<VoxelStats<D>> {
        let obs = latentbki::obs::gather(&self.lut, self, key).ok()?;
        (!obs.is_empty()).then(|| obs.posterior(&self.prior))
    }

    /// The information-gain score of a candidate view whose points would fall at `points` (map frame):
    /// [`latentbki::info_gain::view_score`] over the voxels they hit, each with its point count.
    pub fn view_score(&self, points: &[[f32; 3]]) -> f32 {
        let hits = view_hits(points, self.lut.inv_voxel_size());
        // The table was checked to be voxel-offset at construction, and `view_hits` sorts.
        latentbki::info_gain::view_score(&self.lut, self, self.prior.lambda, &hits).unwrap_or(0.0)
    }

    /// The expected information gain of one voxel if it received kernel weight `w`
    /// ([`latentbki::info_gain::voxel_gain`] at its gathered λ).
    pub fn voxel_gain(&self, key: VoxelKey, w: f32) -> f32 {
        let k = latentbki::info_gain::gathered_count(&self.lut, self, key).unwrap_or(0.0);
        latentbki::info_gain::voxel_gain(self.prior.lambda + k, w)
    }

    /// Observed voxels and their statistics (unordered).
    pub fn observed_voxels(&self) -> impl Iterator<Item = (VoxelKey, &ObsStats<D>)> {
        self.keys.iter().copied().zip(&self.stats)
    }
    /// The map's configuration.
    pub fn config(&self) -> &MapConfig {
        &self.config
    }
    /// Number of observed voxels (voxels a point fell in).
    pub fn observed_len(&self) -> usize {
        self.stats.len()
    }
    /// Points refused so far, by reason.
    pub fn rejections(&self) -> RejectionCounts {
        self.rejections
    }
    /// Points integrated so far.
    pub fn points(&self) -> u64 {
        self.points
    }
}

impl<const D: usize> core::fmt::Debug for ObsMap<D> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ObsMap")
            .field("config", &self.config)
            .field("observed_voxels", &self.stats.len())
            .field("blocks", &self.blocks.len())
            .field("points", &self.points)
            .finish_non_exhaustive()
    }
}

impl<const D: usize> ObsLookup<D> for ObsMap<D> {
    fn observed(&self, key: VoxelKey) -> Option<ObsStats<D>> {
        let (bk, local) = block_of(key);
        let b = *self.index.get(&bk)?;
        match self.blocks[b as usize].1[local] {
            0 => None,
            s => Some(self.read(s as usize - 1)),
        }
    }

    fn observed_count(&self, key: VoxelKey) -> f32 {
        let (bk, local) = block_of(key);
        let Some(&b) = self.index.get(&bk) else {
            return 0.0;
        };
        match self.blocks[b as usize].1[local] {
            0 => 0.0,
            s => {
                let slot = s as usize - 1;
                let n = self.stats[slot].count;
                match &self.forgetting {
                    None => n,
                    Some(f) => n * f.factor(self.now.saturating_sub(self.times[slot])),
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use latentbki::KernelMode;

    #[test]
    fn block_coordinates_round_trip_for_negative_keys() {
        for key in [
            VoxelKey::new(0, 0, 0),
            VoxelKey::new(-1, -8, -9),
            VoxelKey::new(7, 8, -1_000_003),
            VoxelKey::new(1 << 29, -(1 << 29), 5),
        ] {
            let (b, l) = block_of(key);
            assert_eq!(voxel_of(b, l), key);
        }
    }

    #[test]
    fn one_point_reaches_the_filter_cube() {
        let mut map = ObsMap::<2>::new(MapConfig::default()).unwrap();
        // Across a block corner, so the reach spans 8 blocks.
        let n = map.integrate(
            &Isometry3::identity(),
            &[[-0.05, -0.05, -0.05]],
            &[[1.0, 2.0]],
        );
        assert_eq!((n, map.observed_len(), map.in_reach_len()), (1, 1, 27));
        let mut seen = 0;
        map.for_each_posterior(|k, s| {
            seen += 1;
            assert_eq!(s.lambda, map.posterior(k).lambda);
        });
        assert_eq!(seen, 27);
        let corner = map.posterior(VoxelKey::new(0, 0, 0));
        assert!((corner.lambda - 0.4425).abs() < 1e-4);
        assert_eq!(map.posterior(VoxelKey::new(5, 0, 0)).lambda, 0.0);
    }

    #[test]
    fn sub_voxel_configurations_are_refused() {
        let config = MapConfig::new(
            0.1,
            0.5,
            3,
            Prior::default(),
            KernelMode::SubVoxel { cells: 2 },
        )
        .unwrap();
        assert!(matches!(
            ObsMap::<2>::new(config),
            Err(ObsMapError::SubVoxelKernel(_))
        ));
    }
}
