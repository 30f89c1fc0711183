//! The sparse kernel and its precomputed lookup table.
//!
//! A point influences the f³ voxels around its own through the sparse kernel k(d) of Melkumyan & Ramos
//! (the paper's eq. for the sparse kernel). Evaluating `cos`/`sin` per point and neighbour would dominate the
//! update on a microcontroller, yet the distances take only a few values: in the default voxel-offset mode
//! they depend on the integer offset alone (one weight per neighbour), and in sub-voxel mode on the offset
//! and the point's quantized sub-cell. So the weights are computed once, here, and the hot path only reads
//! them. Neighbours whose weight is zero in every sub-cell are left out of the table.

use crate::config::{ConfigError, KernelMode, MapConfig, MAX_FILTER_SIZE};
use crate::key::{Offset, VoxelKey};
use core::f32::consts::PI;

/// The sparse kernel k(d) for kernel length ℓ: smooth, compactly supported, k(0) = 1, k(d ≥ ℓ) = 0,
/// clamped to [0, 1].
pub fn sparse_kernel(distance: f32, kernel_length: f32) -> f32 {
    if !(distance < kernel_length) {
        return 0.0;
    }
    let r = libm::fabsf(distance) / kernel_length;
    let (sin, cos) = crate::f32math::sin_cos(2.0 * PI * r);
    let k = (2.0 + cos) / 3.0 * (1.0 - r) + sin / (2.0 * PI);
    k.clamp(0.0, 1.0)
}

/// Most neighbours a table can hold: f³ for the largest filter size.
pub const MAX_NEIGHBOURS: usize =
    MAX_FILTER_SIZE as usize * MAX_FILTER_SIZE as usize * MAX_FILTER_SIZE as usize;

/// Precomputed kernel weights of one configuration.
///
/// `CAP` bounds the number of weights (sub-cells × neighbours). The default, [`MAX_NEIGHBOURS`], fits any
/// voxel-offset configuration; sub-voxel mode with c cells per axis needs c³ × f³.
#[derive(Clone, Debug)]
pub struct KernelLut<const CAP: usize = MAX_NEIGHBOURS> {
    offsets: heapless::Vec<Offset, MAX_NEIGHBOURS>,
    /// 1 + position in `offsets` of each offset of the f³ cube (row-major z, y, x), 0 for none (all-zero
    /// when empty, so a `static` map lands in .bss, not in flash).
    dense: [u16; MAX_NEIGHBOURS],
    reach: i32,
    /// weights[cell * offsets.len() + j]
    weights: heapless::Vec<f32, CAP>,
    cells: u8,
    cell_size: f32,
    inv_voxel_size: f32,
}

impl<const CAP: usize> KernelLut<CAP> {
    /// An empty table (reaches nothing), for `const` initialisation before [`Self::new`].
    pub const EMPTY: Self = Self {
        offsets: heapless::Vec::new(),
        dense: [0; MAX_NEIGHBOURS],
        reach: 0,
        weights: heapless::Vec::new(),
        cells: 0,
        cell_size: 0.0,
        inv_voxel_size: 0.0,
    };

    /// Compute the table for `config`. Fails only if `CAP` is too small.
    pub fn new(config: &MapConfig) -> Result<Self, ConfigError> {
        let mut lut = Self::EMPTY;
        lut.rebuild(config)?;
        Ok(lut)
    }

    /// Recompute the table in place for `config` (no table-sized temporary on the stack: on a
    /// microcontroller the table lives inside a `static` map). On error the table reaches nothing.
    pub fn rebuild(&mut self, config: &MapConfig) -> Result<(), ConfigError> {
        *self = Self::EMPTY;
        let reach = config.reach();
        let cells = config.subvoxel_cells();
        let vs = config.voxel_size();
        let ell = config.kernel_length();
        let n_cells = usize::from(cells).pow(3);

        // Sub-cell centre positions in voxel units (0..1), one axis.
        let centre = |i: u8| -> f32 {
            match config.mode() {
                KernelMode::VoxelOffset => 0.5,
                KernelMode::SubVoxel { cells } => (f32::from(i) + 0.5) / f32::from(cells),
            }
        };
        let weight = |cell: usize, o: Offset| -> f32 {
            let c = usize::from(cells).max(1); // validated ≥ 1; `max` keeps a `%`-by-zero panic out
            let idx = [cell % c, (cell / c) % c, cell / (c * c)];
            let mut d2 = 0.0f32;
            for axis in 0..3 {
                // Neighbour centroid minus the point's sub-cell centre, in voxels.
                let d = f32::from(o[axis]) + 0.5 - centre(idx[axis] as u8);
                d2 += d * d;
            }
            sparse_kernel(libm::sqrtf(d2) * vs, ell)
        };

        let offsets = &mut self.offsets;
        for dz in -reach..=reach {
            for dy in -reach..=reach {
                for dx in -reach..=reach {
                    let o = [dx as i8, dy as i8, dz as i8];
                    if (0..n_cells).any(|c| weight(c, o) > 0.0) {
                        // f ≤ 7 so at most 343 offsets: cannot overflow MAX_NEIGHBOURS.
                        if offsets.push(o).is_err() {
                            *self = Self::EMPTY;
                            return Err(ConfigError::LutCapacity);
                        }
                    }
                }
            }
        }
        let f = 2 * reach + 1;
        for (j, o) in self.offsets.iter().enumerate() {
            let i = ((i32::from(o[2]) + reach) * f + (i32::from(o[1]) + reach)) * f
                + (i32::from(o[0]) + reach);
            if let Some(d) = self.dense.get_mut(i as usize) {
                *d = j as u16 + 1;
            }
        }
        let mut full = false;
        'fill: for c in 0..n_cells {
            for &o in &self.offsets {
                if self.weights.push(weight(c, o)).is_err() {
                    full = true;
                    break 'fill;
                }
            }
        }
        if full {
            *self = Self::EMPTY;
            return Err(ConfigError::LutCapacity);
        }
        self.reach = reach;
        self.cells = cells;
        self.cell_size = 1.0 / f32::from(cells);
        self.inv_voxel_size = 1.0 / vs;
        Ok(())
    }

    /// The neighbour offsets with a non-zero weight (in some sub-cell).
    pub fn offsets(&self) -> &[Offset] {
        &self.offsets
    }

    /// Weights of [`Self::offsets`] for a point in sub-cell `cell` (`cell` is always 0 in voxel-offset mode).
    /// An out-of-range cell gives an empty slice.
    pub fn weights(&self, cell: u16) -> &[f32] {
        let n = self.offsets.len();
        let start = usize::from(cell) * n;
        self.weights.get(start..start + n).unwrap_or(&[])
    }

    /// The weight from a point in sub-cell `cell` to the neighbour at integer offset `(dx, dy, dz)`;
    /// 0 beyond the filter or the kernel.
    #[inline]
    pub fn weight_at(&self, cell: u16, dx: i32, dy: i32, dz: i32) -> f32 {
        let r = self.reach;
        if dx.abs() > r || dy.abs() > r || dz.abs() > r {
            return 0.0;
        }
        let f = 2 * r + 1;
        let i = (((dz + r) * f + (dy + r)) * f + (dx + r)) as usize;
        match self.dense.get(i) {
            Some(&j) if j != 0 => {
                let n = self.offsets.len();
                self.weights
                    .get(usize::from(cell) * n + usize::from(j - 1))
                    .copied()
                    .unwrap_or(0.0)
            }
            _ => 0.0,
        }
    }

    /// Whether the weights depend on the voxel offset alone (one sub-cell): the table a gather of per-voxel
    /// observation statistics needs ([`crate::obs::gather`]).
    pub fn is_voxel_offset(&self) -> bool {
        self.cells == 1
    }

    /// Half-width of the filter in voxels.
    pub fn reach(&self) -> i32 {
        self.reach
    }

    /// 1 / voxel size, for computing keys.
    pub fn inv_voxel_size(&self) -> f32 {
        self.inv_voxel_size
    }

    /// Number of sub-cells per axis.
    pub fn cells(&self) -> u8 {
        self.cells
    }

    /// The sub-cell of a map-frame position, given the voxel it falls into.
    /// `position` must be finite (the caller validated it when computing the key).
    pub fn cell_of(&self, position: [f32; 3], key: VoxelKey) -> u16 {
        if self.cells == 1 {
            return 0;
        }
        let c = i32::from(self.cells);
        let mut cell = 0i32;
        let k = key.as_array();
        for axis in (0..3).rev() {
            let frac = position[axis] * self.inv_voxel_size - k[axis] as f32;
            // max/min rather than `clamp`, whose min ≤ max assertion would link a panic.
            let i = ((frac / self.cell_size) as i32).max(0).min(c - 1);
            cell = cell * c + i;
        }
        cell as u16
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Prior;

    fn round4(x: f32) -> f32 {
        libm::roundf(x * 1e4) / 1e4
    }

    #[test]
    fn kernel_shape() {
        assert_eq!(sparse_kernel(0.0, 0.5), 1.0);
        assert_eq!(sparse_kernel(0.5, 0.5), 0.0);
        assert_eq!(sparse_kernel(0.7, 0.5), 0.0);
        assert_eq!(sparse_kernel(f32::NAN, 0.5), 0.0);
        let mut prev = 1.0;
        for i in 1..50 {
            let k = sparse_kernel(i as f32 * 0.01, 0.5);
            assert!(
                k < prev && k >= 0.0,
                "kernel must decrease monotonically on [0, l)"
            );
            prev = k;
        }
    }

    /// The reference values: 0.1 m voxels, ℓ = 0.5, f = 3.
    #[test]
    fn offset_table_matches_reference_values() {
        let lut: KernelLut = KernelLut::new(&MapConfig::default()).unwrap();
        assert_eq!(lut.offsets().len(), 27);
        let w = lut.weights(0);
        for (o, &k) in lut.offsets().iter().zip(w) {
            let n = o.iter().filter(|&&c| c != 0).count();
            let expected = [1.0, 0.7671, 0.5849, 0.4425][n];
            assert_eq!(round4(k), expected, "offset {o:?}");
        }
    }

    #[test]
    fn zero_weight_neighbours_are_dropped() {
        // f = 7 at 0.1 m reaches 0.52 m diagonally: beyond ℓ = 0.3, so many offsets vanish.
        let cfg = MapConfig::new(0.1, 0.3, 7, Prior::default(), KernelMode::VoxelOffset).unwrap();
        let lut: KernelLut = KernelLut::new(&cfg).unwrap();
        assert!(lut.offsets().len() < 343);
        assert!(lut.weights(0).iter().all(|&k| k > 0.0));
    }

    #[test]
    fn subvoxel_table_uses_centroid_distances() {
        let cfg = MapConfig::new(
            0.1,
            0.5,
            3,
            Prior::default(),
            KernelMode::SubVoxel { cells: 3 },
        )
        .unwrap();
        let lut: KernelLut<{ 27 * 27 }> = KernelLut::new(&cfg).unwrap();
        // The middle sub-cell (1,1,1) = index 13 sits on the centroid: same as offset mode.
        let own = lut.offsets().iter().position(|o| *o == [0, 0, 0]).unwrap();
        assert_eq!(lut.weights(13)[own], 1.0);
        // Corner sub-cell (0,0,0): 1/3 voxel from the centroid on each axis.
        let d = libm::sqrtf(3.0) * (1.0 / 3.0) * 0.1;
        assert!((lut.weights(0)[own] - sparse_kernel(d, 0.5)).abs() < 1e-6);
        // It is closer to the (-1,-1,-1) neighbour than to (+1,+1,+1).
        let m = lut
            .offsets()
            .iter()
            .position(|o| *o == [-1, -1, -1])
            .unwrap();
        let p = lut.offsets().iter().position(|o| *o == [1, 1, 1]).unwrap();
        assert!(lut.weights(0)[m] > lut.weights(0)[p]);
        // Too small a capacity is an error, not a panic.
        assert_eq!(
            KernelLut::<100>::new(&cfg).unwrap_err(),
            ConfigError::LutCapacity
        );
        assert!(lut.weights(27).is_empty());
        // The dense lookup agrees with the list.
        for (j, o) in lut.offsets().iter().enumerate() {
            let w = lut.weight_at(5, i32::from(o[0]), i32::from(o[1]), i32::from(o[2]));
            assert_eq!(w, lut.weights(5)[j]);
        }
        assert_eq!(lut.weight_at(5, 2, 0, 0), 0.0);
    }
}
