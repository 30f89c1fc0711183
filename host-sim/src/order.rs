//! Spatial ordering of a point batch before it enters the on-device map.
//!
//! `LocalMap` groups points by voxel in a small scratch and re-encodes each touched voxel once per scratch
//! flush. A sensor delivers points in scan order, so consecutive points share voxels and a flush covers a
//! compact region. An unordered cloud (a recorded file, a random sample) makes every flush touch scattered
//! voxels, and each voxel is then re-encoded up to f³ times. Sorting the batch along a Morton (Z-order) curve
//! of its voxel keys restores the locality; on the host this costs one sort.

use latentbki::VoxelKey;

/// Interleave the low 21 bits of three coordinates (offset to be non-negative) into a Morton code.
fn morton(k: VoxelKey) -> u64 {
    fn spread(v: i32) -> u64 {
        let mut x = (v as i64 + (1 << 20)) as u64 & 0x1F_FFFF;
        x = (x | x << 32) & 0x001F_0000_0000_FFFF;
        x = (x | x << 16) & 0x001F_0000_FF00_00FF;
        x = (x | x << 8) & 0x100F_00F0_0F00_F00F;
        x = (x | x << 4) & 0x10C3_0C30_C30C_30C3;
        (x | x << 2) & 0x1249_2492_4924_9249
    }
    spread(k.x) | spread(k.y) << 1 | spread(k.z) << 2
}

/// The permutation that orders map-frame `points` along the Morton curve of their voxels (`voxel_size`
/// metres). Non-finite points sort last; the map rejects and counts them as usual.
pub fn morton_order(points: &[[f32; 3]], voxel_size: f32) -> Vec<u32> {
    let inv = 1.0 / voxel_size;
    let mut keyed: Vec<(u64, u32)> = points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            (
                VoxelKey::from_position(*p, inv).map_or(u64::MAX, morton),
                i as u32,
            )
        })
        .collect();
    keyed.sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn neighbours_stay_close_and_every_point_is_kept() {
        // A 4×4×4 block of voxels: Morton order visits each 2×2×2 sub-block contiguously.
        let mut pts = Vec::new();
        for z in 0..4 {
            for y in 0..4 {
                for x in 0..4 {
                    pts.push([x as f32 + 0.5, y as f32 + 0.5, z as f32 + 0.5]);
                }
            }
        }
        pts.push([f32::NAN, 0.0, 0.0]);
        let order = morton_order(&pts, 1.0);
        let mut seen = order.clone();
        seen.sort_unstable();
        assert_eq!(seen, (0..pts.len() as u32).collect::<Vec<_>>());
        assert_eq!(*order.last().unwrap(), 64, "the non-finite point goes last");
        for block in order[..64].chunks(8) {
            let first = pts[block[0] as usize];
            let corner = [
                (first[0] as i32) / 2,
                (first[1] as i32) / 2,
                (first[2] as i32) / 2,
            ];
            for &i in block {
                let p = pts[i as usize];
                assert_eq!(
                    [(p[0] as i32) / 2, (p[1] as i32) / 2, (p[2] as i32) / 2],
                    corner
                );
            }
        }
    }
}
