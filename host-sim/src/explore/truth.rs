//! The ground truth the explorers are scored on: every surface voxel the scripted indoor loop sees, with
//! its majority class (thinned evenly by the caller). Its own module because `changing` scores its maps on
//! the same truth, and because what is scored should be readable apart from how the robot explores.

use crate::eval::methods::{Decoder, D};
use crate::eval::metrics::Confusion;
use crate::sim::indoor::{self, IndoorRun, IndoorScene};
use crate::sim::mix_all;
use crate::ObsMap;
use latentbki::{key::VoxelKey, MapConfig};
use rustc_hash::FxHashMap;

/// The ground truth: voxels and their majority class.
pub struct Truth {
    voxels: Vec<(VoxelKey, u16)>,
    classes: usize,
}

impl Truth {
    /// Every voxel the scripted loop sees in `scene`, with the class most of its points have.
    pub fn from_loop(scene: &IndoorScene, config: &MapConfig) -> Self {
        let seq = indoor::sequence(scene, &IndoorRun::default());
        let mut votes: FxHashMap<VoxelKey, Vec<u32>> = FxHashMap::default();
        let classes = seq.classes.len();
        for f in &seq.frames {
            for p in &f.points {
                if let Ok(k) = VoxelKey::from_position(p.position, 1.0 / config.voxel_size()) {
                    votes.entry(k).or_insert_with(|| vec![0; classes])[usize::from(p.class)] += 1;
                }
            }
        }
        let mut voxels: Vec<(VoxelKey, u16)> = votes
            .into_iter()
            .map(|(k, v)| {
                let best = (0..classes)
                    .max_by_key(|&c| (v[c], usize::MAX - c))
                    .unwrap_or(0);
                (k, best as u16)
            })
            .collect();
        voxels.sort_unstable();
        Self { voxels, classes }
    }

    /// Number of ground-truth voxels.
    pub fn len(&self) -> usize {
        self.voxels.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.voxels.is_empty()
    }

    /// Every `n`-th voxel, chosen by a hash of its key (a fixed, spatially even subsample).
    pub fn thinned(self, n: u64) -> Self {
        let voxels = self
            .voxels
            .into_iter()
            .filter(|(k, _)| {
                let [x, y, z] = k.as_array();
                mix_all(&[x as u64, y as u64, z as u64]).is_multiple_of(n.max(1))
            })
            .collect();
        Self { voxels, ..self }
    }

    /// (voxels whose class differs in `other`, the rest): the changed and unchanged regions.
    pub fn split(&self, other: &Truth) -> (Truth, Truth) {
        let (changed, same) = self.voxels.iter().partition(|(k, c)| {
            other
                .voxels
                .binary_search_by_key(k, |v| v.0)
                .is_ok_and(|i| other.voxels[i].1 != *c)
        });
        let t = |voxels| Truth {
            voxels,
            classes: self.classes,
        };
        (t(changed), t(same))
    }

    /// (accuracy, mIoU) of `map` on these voxels; a voxel the map cannot answer is wrong.
    pub fn score(&self, map: &ObsMap<D>, decoder: &Decoder) -> (f64, f64) {
        let mut c = Confusion::new(self.classes);
        for &(k, class) in &self.voxels {
            let predicted = map
                .posterior_in_reach(k)
                .and_then(|p| decoder.argmax(&p.mean).map(|(i, _)| i));
            c.add(usize::from(class), predicted);
        }
        (c.accuracy(), c.miou())
    }
}
