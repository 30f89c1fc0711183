//! The base station's global map: every robot's summaries merged exactly, nothing counted twice.
//!
//! A voxel's observations arrive as *contributions*, one per `(robot, session, residency)`: each is the
//! observation statistics (n, m, S) of the points that fell in that voxel while it was resident in that
//! robot's map, so different contributions are disjoint and are merged exactly (`ObsStats::merge` — the
//! core's operation, not a second copy). Within one contribution, live updates replace each other (newest
//! frame sequence number wins) and the final (evicted) summary closes it; its id is remembered, so a
//! repeated or late copy is ignored instead of merged again.
//!
//! **Order-free, bit for bit.** Chan's merge is exact in real numbers but its f32 rounding depends on the
//! order of the merges, and frames arrive in whatever order links, losses and re-sends give them (or robots
//! on many links at once). So every closed contribution keeps its own statistics ([`Part`]), sorted by id,
//! and a voxel's settled statistics are their fold in id order: the same set of frames gives the same bits
//! whatever order it arrived in (a contribution that sorts last, the common case, is one merge; an earlier
//! one refolds the voxel). Live contributions are kept apart, sorted by id, until they close.
//!
//! **Forgetting** (a session with a half-life, `latentbki::forget`): every contribution carries the tick of
//! its last change, and merges follow the clock rule (both sides faded to the later stamp, then merged:
//! exact in any order). The map's clock is the latest tick any summary carried (or later,
//! [`GlobalMap::set_time`]); reads fade every voxel to it.
//!
//! Posteriors are gathered through the kernel when asked ([`latentbki::obs`]). The map keeps each voxel's
//! merged statistics in an [`ObsMap`] too, updated with every summary applied, so a lookup neither merges
//! nor allocates: one voxel's posterior is the core's `gather` over the block map's array-indexed
//! neighbours, and every posterior in reach is one pass over it.

use crate::obs_map::ObsMap;
use latentbki::forget::{Forgetting, Stamped};
use latentbki::wire::{SessionConfig, Summary};
use latentbki::{
    decode::Codebook, key::VoxelKey, obs::ObsLookup, obs::ObsStats, stats::VoxelStats, MapConfig,
    Prior,
};
use std::collections::HashMap;

/// Largest vocabulary the base station decodes against.
pub const VOCAB_CAP: usize = 64;

/// The origin of one contribution to a voxel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ContributionId {
    /// Robot id.
    pub robot: u16,
    /// That robot's session.
    pub session: u32,
    /// Residency number of the voxel in that session.
    pub residency: u32,
}

/// A live (not yet final) contribution.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LiveContribution<const D: usize> {
    /// Whose.
    pub id: ContributionId,
    /// Frame sequence number it came in.
    pub seq: u32,
    /// What the robot observed in the voxel during that residency so far.
    pub obs: ObsStats<D>,
    /// Tick of its last change when the session forgets (`obs` are as of it), else 0.
    pub time: u32,
}

/// A closed contribution's own statistics (its final summary).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Part<const D: usize> {
    /// Whose.
    pub id: ContributionId,
    /// What the robot observed in the voxel during that residency.
    pub obs: ObsStats<D>,
    /// Tick `obs` is as of when the session forgets, else 0.
    pub time: u32,
}

/// One voxel of the global map.
#[derive(Clone, Debug, PartialEq)]
pub struct GlobalVoxel<const D: usize> {
    /// Every closed contribution, merged: `base`, then `parts` in id order (kept in step with them).
    pub settled: ObsStats<D>,
    /// Tick `settled` is as of when the session forgets (the latest stamp merged into it), else 0.
    pub settled_time: u32,
    /// Ids of the closed contributions, sorted (their copies are ignored).
    pub closed: Vec<ContributionId>,
    /// The closed contributions' own statistics, sorted by id: what `settled` is folded from.
    pub parts: Vec<Part<D>>,
    /// Statistics settled without their parts (records before version 4 kept only the sum), folded first.
    pub base: ObsStats<D>,
    /// Tick `base` is as of (forgetting), else 0.
    pub base_time: u32,
    /// Open contributions, newest copy of each, sorted by id (the order they are merged in, so the merged
    /// statistics do not depend on the order frames arrived in).
    pub live: Vec<LiveContribution<D>>,
}

impl<const D: usize> GlobalVoxel<D> {
    /// A voxel nothing contributed to yet.
    pub const EMPTY: Self = Self {
        settled: ObsStats::EMPTY,
        settled_time: 0,
        closed: Vec::new(),
        parts: Vec::new(),
        base: ObsStats::EMPTY,
        base_time: 0,
        live: Vec::new(),
    };

    /// Recompute `settled` from `base` and `parts` in id order (the canonical fold).
    pub fn refold(&mut self, forgetting: Option<&Forgetting>) {
        let mut s = Stamped {
            obs: self.base,
            time: self.base_time,
        };
        for p in &self.parts {
            fold(&mut s, forgetting, p);
        }
        (self.settled, self.settled_time) = (s.obs, s.time);
    }

    /// Close contribution `part.id` with its final statistics (the caller checked it is not closed yet):
    /// it takes its place in id order, and `settled` becomes the fold it would be had the parts arrived in
    /// that order.
    fn close(&mut self, part: Part<D>, forgetting: Option<&Forgetting>) {
        let at = self.closed.binary_search(&part.id).unwrap_or_else(|i| i);
        self.closed.insert(at, part.id);
        let at = self
            .parts
            .binary_search_by_key(&part.id, |p| p.id)
            .unwrap_or_else(|i| i);
        self.parts.insert(at, part);
        if at + 1 == self.parts.len() {
            // Last in id order: one more step of the same fold.
            let mut s = Stamped {
                obs: self.settled,
                time: self.settled_time,
            };
            fold(&mut s, forgetting, &part);
            (self.settled, self.settled_time) = (s.obs, s.time);
        } else {
            self.refold(forgetting);
        }
    }

    /// What was observed in the voxel: settled ⊕ every live contribution, in id order.
    pub fn merged(&self) -> ObsStats<D> {
        self.merged_stamped(None).obs
    }

    /// [`Self::merged`] of a session that forgets with `forgetting`: every contribution faded to the
    /// latest stamp and merged (the clock rule), as of that stamp.
    pub fn merged_stamped(&self, forgetting: Option<&Forgetting>) -> Stamped<D> {
        let mut p = Stamped {
            obs: self.settled,
            time: self.settled_time,
        };
        for c in &self.live {
            let v = Stamped {
                obs: c.obs,
                time: c.time,
            };
            match forgetting {
                Some(f) => p.merge(f, &v),
                None => p.obs.merge(&c.obs),
            }
        }
        p
    }
}

/// One step of the settled fold: merge `part` (at the later stamp when the session forgets).
fn fold<const D: usize>(s: &mut Stamped<D>, forgetting: Option<&Forgetting>, part: &Part<D>) {
    let p = Stamped {
        obs: part.obs,
        time: part.time,
    };
    fold_stamped(s, forgetting, &p);
}

/// `s` ⊕ `other` (at the later stamp when the session forgets).
fn fold_stamped<const D: usize>(
    s: &mut Stamped<D>,
    forgetting: Option<&Forgetting>,
    other: &Stamped<D>,
) {
    match forgetting {
        Some(f) => s.merge(f, other),
        None => s.obs.merge(&other.obs),
    }
}

/// What applying one summary did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Applied {
    /// A final summary closed its contribution and was merged.
    Merged,
    /// A live summary opened or replaced its contribution.
    Updated,
    /// An older copy than the one held, or a live copy of a closed contribution: ignored.
    Stale,
    /// A second final copy of a closed contribution: ignored.
    DuplicateFinal,
}

/// Per-voxel uncertainty of the merged posterior (§III-D).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Uncertainty {
    /// Largest predictive variance (λ > 2).
    pub e_optimality: Option<f32>,
    /// Geometric mean of the predictive variances (λ > 2).
    pub d_optimality: Option<f32>,
}

/// The global sparse map.
#[derive(Clone, Debug)]
pub struct GlobalMap<const D: usize> {
    config: SessionConfig,
    map_config: MapConfig,
    voxels: HashMap<VoxelKey, GlobalVoxel<D>>,
    /// Every voxel's [`GlobalVoxel::merged`], kept in step with `voxels`: what lookups gather from.
    merged: ObsMap<D>,
    /// The session's forgetting (from its half-life).
    forgetting: Option<Forgetting>,
}

impl<const D: usize> PartialEq for GlobalMap<D> {
    fn eq(&self, other: &Self) -> bool {
        // The kernel table and the merged statistics follow from the configuration and the voxels.
        self.config == other.config && self.voxels == other.voxels
    }
}

/// `a` is newer than `b` in a wrapping u32 sequence.
fn newer(a: u32, b: u32) -> bool {
    let d = a.wrapping_sub(b);
    d != 0 && d < 1 << 31
}

impl<const D: usize> GlobalMap<D> {
    /// An empty map for sessions of this configuration.
    pub fn new(config: SessionConfig) -> Result<Self, latentbki::wire::WireError> {
        config.validate(D)?;
        let map_config = config
            .map_config()
            .map_err(|_| latentbki::wire::WireError::BadConfig)?;
        // Refuses a sub-voxel kernel: per-voxel statistics cannot express it.
        let mut merged =
            ObsMap::new(map_config).map_err(|_| latentbki::wire::WireError::BadConfig)?;
        let forgetting = config.forgetting();
        merged.set_forgetting(forgetting);
        Ok(Self {
            config,
            map_config,
            voxels: HashMap::new(),
            merged,
            forgetting,
        })
    }

    /// The session configuration every contribution shares.
    pub fn config(&self) -> &SessionConfig {
        &self.config
    }
    /// The map configuration.
    pub fn map_config(&self) -> &MapConfig {
        &self.map_config
    }
    /// The prior of an unobserved voxel.
    pub fn prior(&self) -> Prior {
        self.map_config.prior()
    }
    /// Voxels held (voxels a robot observed a point in).
    pub fn len(&self) -> usize {
        self.voxels.len()
    }
    /// Whether no voxel is held.
    pub fn is_empty(&self) -> bool {
        self.voxels.is_empty()
    }
    /// Raw access to a voxel's contributions.
    pub fn voxel(&self, key: &VoxelKey) -> Option<&GlobalVoxel<D>> {
        self.voxels.get(key)
    }
    /// All voxels (unordered).
    pub fn voxels(&self) -> impl Iterator<Item = (&VoxelKey, &GlobalVoxel<D>)> {
        self.voxels.iter()
    }
    /// Keys, sorted.
    pub fn sorted_keys(&self) -> Vec<VoxelKey> {
        let mut k: Vec<_> = self.voxels.keys().copied().collect();
        k.sort();
        k
    }

    /// Insert a voxel as stored (for loading a saved map). Its lists are put in id order and its settled
    /// statistics refolded from base and parts; a voxel given with settled statistics but neither base nor
    /// parts (settled the way records before version 4 were) keeps them as its base.
    pub fn insert_raw(&mut self, key: VoxelKey, mut voxel: GlobalVoxel<D>) {
        voxel.live.sort_by_key(|c| c.id);
        voxel.closed.sort_unstable();
        voxel.parts.sort_by_key(|p| p.id);
        if voxel.parts.is_empty() && voxel.base == ObsStats::EMPTY {
            (voxel.base, voxel.base_time) = (voxel.settled, voxel.settled_time);
        }
        voxel.refold(self.forgetting.as_ref());
        let m = voxel.merged_stamped(self.forgetting.as_ref());
        self.merged.set_stamped(key, &m.obs, m.time);
        if self.forgetting.is_some() {
            self.set_time(m.time); // the clock: the latest stamp held
        }
        self.voxels.insert(key, voxel);
    }

    /// How the session's maps forget (`None`: they do not).
    pub fn forgetting(&self) -> Option<Forgetting> {
        self.forgetting
    }

    /// Move the map's clock to tick `now` (never backwards): reads fade every voxel to it. Applying a
    /// summary moves it to the summary's stamp if that is later.
    pub fn set_time(&mut self, now: u32) {
        if now > self.merged.time() {
            self.merged.set_time(now);
        }
    }

    /// The map's clock (0 when the session does not forget).
    pub fn time(&self) -> u32 {
        self.merged.time()
    }

    /// Apply one decoded summary from `(robot, session)`'s frame `seq`.
    pub fn apply(&mut self, robot: u16, session: u32, seq: u32, s: &Summary<D>) -> Applied {
        let applied = self.apply_to_voxel(robot, session, seq, s);
        if matches!(applied, Applied::Merged | Applied::Updated) {
            let m = self.voxels[&s.key].merged_stamped(self.forgetting.as_ref());
            self.merged.set_stamped(s.key, &m.obs, m.time);
            if let Some(t) = s.time.filter(|_| self.forgetting.is_some()) {
                self.set_time(t);
            }
        }
        applied
    }

    fn apply_to_voxel(&mut self, robot: u16, session: u32, seq: u32, s: &Summary<D>) -> Applied {
        let id = ContributionId {
            robot,
            session,
            residency: s.residency,
        };
        let time = s.time.unwrap_or(0);
        let forgetting = self.forgetting;
        let v = self
            .voxels
            .entry(s.key)
            .or_insert_with(|| GlobalVoxel::EMPTY);
        if v.closed.binary_search(&id).is_ok() {
            return if s.is_final {
                Applied::DuplicateFinal
            } else {
                Applied::Stale
            };
        }
        let at = v.live.binary_search_by_key(&id, |c| c.id);
        if s.is_final {
            if let Ok(i) = at {
                v.live.remove(i);
            }
            let part = Part {
                id,
                obs: s.obs,
                time,
            };
            v.close(part, forgetting.as_ref());
            return Applied::Merged;
        }
        match at {
            Ok(i) if !newer(seq, v.live[i].seq) => Applied::Stale,
            Ok(i) => {
                v.live[i] = LiveContribution {
                    id,
                    seq,
                    obs: s.obs,
                    time,
                };
                Applied::Updated
            }
            Err(i) => {
                v.live.insert(
                    i,
                    LiveContribution {
                        id,
                        seq,
                        obs: s.obs,
                        time,
                    },
                );
                Applied::Updated
            }
        }
    }

    /// What was observed in a voxel: settled ⊕ every live contribution (faded to the map's clock when the
    /// session forgets).
    pub fn observations(&self, key: &VoxelKey) -> Option<ObsStats<D>> {
        let v = self.voxels.get(key)?;
        let m = v.merged_stamped(self.forgetting.as_ref());
        Some(match &self.forgetting {
            Some(f) => m.at(f, self.time()),
            None => m.obs,
        })
    }

    /// The posterior of any voxel, gathered through the kernel from the observed voxels in reach;
    /// `None` if nothing is in reach.
    pub fn posterior(&self, key: &VoxelKey) -> Option<VoxelStats<D>> {
        self.merged.posterior_in_reach(*key)
    }

    /// The merged observations in the host's block map, which gathers every posterior in one pass.
    pub fn observation_map(&self) -> &ObsMap<D> {
        &self.merged
    }

    /// Every voxel within the kernel's reach of an observation, with its posterior, sorted by key.
    pub fn posteriors(&self) -> Vec<(VoxelKey, VoxelStats<D>)> {
        self.merged.posteriors_sorted()
    }

    /// Σ n over voxels: the points the map holds (conserved by merging).
    pub fn observed_points(&self) -> f64 {
        self.merged
            .observed_voxels()
            .map(|(_, s)| f64::from(s.count))
            .sum()
    }

    /// The most similar category of a voxel and its cosine score.
    pub fn label<const K: usize>(
        &self,
        key: &VoxelKey,
        vocab: &Codebook<D, K>,
    ) -> Option<(usize, f32)> {
        self.posterior(key).and_then(|p| vocab.argmax(&p.mean))
    }

    /// Cosine score of one category (a text query) at a voxel.
    pub fn heat<const K: usize>(
        &self,
        key: &VoxelKey,
        query: &Codebook<D, K>,
        category: usize,
    ) -> Option<f32> {
        self.posterior(key).map(|p| query.score(&p.mean, category))
    }

    /// E- and D-optimality of a voxel's merged posterior.
    pub fn uncertainty(&self, key: &VoxelKey) -> Option<Uncertainty> {
        self.posterior(key).map(|p| Uncertainty {
            e_optimality: p.e_optimality(),
            d_optimality: p.d_optimality(),
        })
    }
    /// The information-gain score of a candidate view whose points would fall at `points` (map frame):
    /// [`latentbki::info_gain::view_score`] on the merged statistics of every robot ([`ObsMap::view_score`]).
    pub fn view_score(&self, points: &[[f32; 3]]) -> f32 {
        self.merged.view_score(points)
    }
}

impl<const D: usize> ObsLookup<D> for GlobalMap<D> {
    fn observed(&self, key: VoxelKey) -> Option<ObsStats<D>> {
        self.observations(&key)
    }
}

mod merge;
mod record;
pub use merge::{config_difference, MergeError, MergeReport};
#[cfg(test)]
use record::{put_id, put_stats};
pub use record::{RecordError, VOXEL_RECORD_VERSION};

#[cfg(test)]
mod tests;
