//! Every posterior in reach, gathered block by block: a bitmask per block of the voxels within the kernel's
//! reach of an observed voxel, then each voxel's posterior from its 27 neighbours' statistics found by
//! array index in the blocks around it (the shape `ObsMap` has for this).

use super::{voxel_of, BlockKey, ObsMap, MASK, SHIFT, VOLUME, WORDS};
use latentbki::key::VoxelKey;
use latentbki::obs::ObsStats;
use latentbki::stats::VoxelStats;
use rustc_hash::FxHashMap;

impl<const D: usize> ObsMap<D> {
    /// Bitmask, per block, of every voxel within the kernel's reach of an observed voxel.
    fn reach_masks(&self) -> Vec<(BlockKey, [u64; WORDS])> {
        let mut index: FxHashMap<BlockKey, u32> = FxHashMap::default();
        let mut masks: Vec<(BlockKey, [u64; WORDS])> = Vec::new();
        let offsets = self.lut.offsets();
        for (bk, slots) in &self.blocks {
            // Handles of the 27 blocks around this one, made on first use.
            let mut near: [u32; 27] = [u32::MAX; 27];
            for (local, &s) in slots.iter().enumerate() {
                if s == 0 {
                    continue;
                }
                let l = local as i32;
                let (x, y, z) = (l & MASK, (l >> SHIFT) & MASK, l >> (2 * SHIFT));
                for o in offsets {
                    let (tx, ty, tz) = (
                        x + i32::from(o[0]),
                        y + i32::from(o[1]),
                        z + i32::from(o[2]),
                    );
                    let (dx, dy, dz) = (tx >> SHIFT, ty >> SHIFT, tz >> SHIFT);
                    let n = ((dz + 1) * 9 + (dy + 1) * 3 + (dx + 1)) as usize;
                    if near[n] == u32::MAX {
                        let nk = [bk[0] + dx, bk[1] + dy, bk[2] + dz];
                        let next = masks.len() as u32;
                        let m = *index.entry(nk).or_insert(next);
                        if m == next {
                            masks.push((nk, [0; WORDS]));
                        }
                        near[n] = m;
                    }
                    let t = ((tx & MASK) | ((ty & MASK) << SHIFT) | ((tz & MASK) << (2 * SHIFT)))
                        as usize;
                    masks[near[n] as usize].1[t / 64] |= 1 << (t % 64);
                }
            }
        }
        masks
    }

    /// Number of voxels within the kernel's reach of an observed voxel: every voxel the map can answer
    /// with more than the prior.
    pub fn in_reach_len(&self) -> usize {
        self.reach_masks()
            .iter()
            .map(|(_, m)| m.iter().map(|w| w.count_ones() as usize).sum::<usize>())
            .sum()
    }

    /// Call `f(key, posterior)` for every voxel within the kernel's reach of an observed voxel, in blocks
    /// sorted by key (deterministic order). Each posterior is gathered from the neighbours' statistics
    /// exactly as [`latentbki::obs::gather`] does (same operations, same order: bit-identical results).
    pub fn for_each_posterior(&self, mut f: impl FnMut(VoxelKey, &VoxelStats<D>)) {
        let mut masks = self.reach_masks();
        masks.sort_unstable_by_key(|(k, _)| *k);
        let offsets = self.lut.offsets();
        let weights = self.lut.weights(0);
        // Neighbours other than the centre, as (offset, weight), in table order.
        let ring: Vec<([i32; 3], f32)> = offsets
            .iter()
            .zip(weights)
            .filter(|(o, _)| **o != [0, 0, 0])
            .map(|(o, &k)| ([i32::from(o[0]), i32::from(o[1]), i32::from(o[2])], k))
            .collect();
        for (bk, mask) in &masks {
            // The observed blocks around this one (None where nothing was observed).
            let near: [Option<&[u32; VOLUME]>; 27] = core::array::from_fn(|n| {
                let n = n as i32;
                let nk = [
                    bk[0] + n % 3 - 1,
                    bk[1] + (n / 3) % 3 - 1,
                    bk[2] + n / 9 - 1,
                ];
                self.index.get(&nk).map(|&b| &*self.blocks[b as usize].1)
            });
            let slot_at = |tx: i32, ty: i32, tz: i32| -> u32 {
                let n = (((tz >> SHIFT) + 1) * 9 + ((ty >> SHIFT) + 1) * 3 + ((tx >> SHIFT) + 1))
                    as usize;
                match near[n] {
                    Some(slots) => {
                        slots[((tx & MASK) | ((ty & MASK) << SHIFT) | ((tz & MASK) << (2 * SHIFT)))
                            as usize]
                    }
                    None => 0,
                }
            };
            for (w, &word) in mask.iter().enumerate() {
                let mut bits = word;
                while bits != 0 {
                    let local = w * 64 + bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    let l = local as i32;
                    let (x, y, z) = (l & MASK, (l >> SHIFT) & MASK, l >> (2 * SHIFT));
                    let own = slot_at(x, y, z);
                    let mut acc = if own == 0 {
                        ObsStats::EMPTY
                    } else {
                        self.read(own as usize - 1)
                    };
                    for &(o, k) in &ring {
                        let s = slot_at(x + o[0], y + o[1], z + o[2]);
                        if s != 0 {
                            acc.merge_scaled(k, &self.read(s as usize - 1));
                        }
                    }
                    f(voxel_of(*bk, local), &acc.posterior(&self.prior));
                }
            }
        }
    }

    /// Every voxel in reach with its posterior, sorted by key.
    pub fn posteriors_sorted(&self) -> Vec<(VoxelKey, VoxelStats<D>)> {
        let mut out = Vec::new();
        self.for_each_posterior(|k, s| out.push((k, *s)));
        out.sort_unstable_by_key(|(k, _)| *k);
        out
    }
}
