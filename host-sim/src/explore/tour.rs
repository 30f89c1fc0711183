//! Information gain over a horizon (`--horizon N`): the next view is the first stop of the best short tour,
//! not the best single view.
//!
//! Why: a greedy score / (path + offset) is a rate, and once the first rooms are seen the best rate can be a
//! short hop to a view of voxels seen once, again and again, while the surfaces not yet seen wait behind a
//! long drive. A tour of a few views pays the drive once for several stops: a room with much unseen surface
//! is worth its drive, a corner of leftovers is not. Each tour is grown greedily from its first stop, every
//! later stop scored as if the earlier ones had been taken (their kernel weights added to λ), so two stops
//! onto the same surfaces count them once. Measured in `docs/numbers.md` (exploration): it is not the
//! default, because it did not win on the held-out houses.

use super::world::{Footprint, Viewpoint};
use super::Robot;
use latentbki::info_gain::voxel_gain;
use latentbki::key::VoxelKey;
use rustc_hash::FxHashMap;

/// First stops tried: the best this many by the single-view utility.
const FIRST: usize = 12;
/// Later stops are drawn from this many candidates of highest score (wherever they are), and the first
/// stops.
const POOL: usize = 48;

/// A candidate: its view, what it would see, its driving distance from here.
pub(super) type Candidate<'a> = (Viewpoint, &'a Footprint, f32);

impl Robot<'_> {
    /// Score of a footprint given the kernel weight already planned for (`planned`, added to λ).
    fn score_after(&self, fp: &Footprint, planned: &FxHashMap<VoxelKey, f32>) -> f32 {
        fp.weights
            .iter()
            .map(|&(k, w)| voxel_gain(self.lambda(k) + planned.get(&k).copied().unwrap_or(0.0), w))
            .sum()
    }

    /// The first stop of the tour of `self.horizon` stops of highest Σ score / Σ (path + offset), among
    /// `options` (all within the remaining budget `left`).
    pub(super) fn choose_tour(&self, options: &[Candidate], left: f32) -> Option<Viewpoint> {
        let offset = self.utility_offset;
        let scores: Vec<f32> = options.iter().map(|o| self.score(o.1)).collect();
        let rate = |i: usize| scores[i] / (options[i].2 + offset);
        let mut first: Vec<usize> = (0..options.len()).collect();
        first.sort_by(|&a, &b| rate(b).total_cmp(&rate(a)));
        first.truncate(FIRST);
        let mut pool: Vec<usize> = (0..options.len()).collect();
        pool.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]));
        pool.truncate(POOL);
        for &f in &first {
            if !pool.contains(&f) {
                pool.push(f);
            }
        }
        // Driving distances from each stop, computed once per choice.
        let mut distances: FxHashMap<usize, Vec<f32>> = FxHashMap::default();
        let mut best: Option<(f32, Viewpoint)> = None;
        for &f in &first {
            let (view, fp, d0) = options[f];
            let mut planned: FxHashMap<VoxelKey, f32> = FxHashMap::default();
            add(&mut planned, fp);
            let (mut gain, mut driven, mut cost) = (scores[f], d0, d0 + offset);
            let mut at = view.cell;
            for _ in 1..self.horizon {
                let dist = distances
                    .entry(at)
                    .or_insert_with(|| self.world.distances(at).0);
                let next = pool
                    .iter()
                    .filter(|&&p| {
                        options[p].0.cell != at && driven + dist[options[p].0.cell] <= left
                    })
                    .map(|&p| {
                        (
                            p,
                            self.score_after(options[p].1, &planned),
                            dist[options[p].0.cell],
                        )
                    })
                    .max_by(|a, b| (a.1 / (a.2 + offset)).total_cmp(&(b.1 / (b.2 + offset))));
                let Some((p, g, d)) = next else { break };
                add(&mut planned, options[p].1);
                gain += g;
                driven += d;
                cost += d + offset;
                at = options[p].0.cell;
            }
            let utility = gain / cost;
            if best.is_none_or(|(u, _)| utility > u) {
                best = Some((utility, view));
            }
        }
        best.map(|(_, v)| v)
    }
}

/// Add a footprint's kernel weights to the planned ones.
fn add(planned: &mut FxHashMap<VoxelKey, f32>, fp: &Footprint) {
    for &(k, w) in &fp.weights {
        *planned.entry(k).or_default() += w;
    }
}
