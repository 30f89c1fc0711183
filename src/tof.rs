//! Multizone time-of-flight sensors (ST's VL53L5CX and its 8×8 siblings): where each zone looks, as a
//! fixed-point table, so a firmware turns a zone's range into a point with integer arithmetic.
//!
//! A multizone ToF reports one range per zone, along the zone's centre ray. The rays never change, so they
//! are a table here rather than float math per point (a division and a square root: soft-float on an MCU
//! without an FPU). With [`ZoneGrid::point_mm`] and [`crate::SensorFrame::add_point_mm_i8`], a zone's range
//! reaches its voxel with no float operation at all.
//!
//! Sensor frame: x right, y down, z forward (the sensor's optical axis); zones row by row from the top left
//! as the sensor reports them; a range is the distance along the zone's centre ray. Each ray is a unit
//! vector in Q2.14 (`i16`, 2¹⁴ = 1.0), so a point is within 0.5 mm + 3·10⁻⁵ of the range of exact.

/// One fixed point unit of a ray component: 2¹⁴.
pub const RAY_ONE: i32 = 1 << 14;

/// The centre rays of a sensor's `Z` zones, unit vectors in Q2.14.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ZoneGrid<const Z: usize> {
    /// Zone z's centre-ray direction × 2¹⁴ (x right, y down, z forward), zones row by row.
    pub rays_q14: [[i16; 3]; Z],
}

impl<const Z: usize> ZoneGrid<Z> {
    /// Zone `zone`'s point in millimetres in the sensor frame, at `range_mm` along its centre ray
    /// (rounded to the millimetre; integer only), or `None` past the last zone.
    pub fn point_mm(&self, zone: usize, range_mm: u16) -> Option<[i32; 3]> {
        let ray = self.rays_q14.get(zone)?;
        let r = i32::from(range_mm);
        // |ray| ≤ 2¹⁴ and r < 2¹⁶: the product stays below 2³⁰.
        Some(ray.map(|c| (i32::from(c) * r + (RAY_ONE >> 1)) >> 14))
    }

    /// Zone `zone`'s centre-ray direction as f32 (the table's value), or `None` past the last zone.
    pub fn ray(&self, zone: usize) -> Option<[f32; 3]> {
        let ray = self.rays_q14.get(zone)?;
        Some(ray.map(|c| f32::from(c) / RAY_ONE as f32))
    }
}

/// A VL53L5CX (or VL53L7CX/VL53L8CX-style sensor) in 8×8 mode: a 45° × 45° field of view (63° diagonal)
/// split evenly into 8 × 8 zones. Generated from tan 22.5° (tested against the f64 geometry).
pub const VL53L5CX_8X8: ZoneGrid<64> = ZoneGrid {
    rays_q14: [
        [-5284, -5284, 14580],
        [-3875, -5424, 14967],
        [-2368, -5524, 15242],
        [-797, -5576, 15385],
        [797, -5576, 15385],
        [2368, -5524, 15242],
        [3875, -5424, 14967],
        [5284, -5284, 14580],
        [-5424, -3875, 14967],
        [-3983, -3983, 15385],
        [-2436, -4061, 15685],
        [-820, -4101, 15841],
        [820, -4101, 15841],
        [2436, -4061, 15685],
        [3983, -3983, 15385],
        [5424, -3875, 14967],
        [-5524, -2368, 15242],
        [-4061, -2436, 15685],
        [-2486, -2486, 16002],
        [-837, -2511, 16169],
        [837, -2511, 16169],
        [2486, -2486, 16002],
        [4061, -2436, 15685],
        [5524, -2368, 15242],
        [-5576, -797, 15385],
        [-4101, -820, 15841],
        [-2511, -837, 16169],
        [-846, -846, 16340],
        [846, -846, 16340],
        [2511, -837, 16169],
        [4101, -820, 15841],
        [5576, -797, 15385],
        [-5576, 797, 15385],
        [-4101, 820, 15841],
        [-2511, 837, 16169],
        [-846, 846, 16340],
        [846, 846, 16340],
        [2511, 837, 16169],
        [4101, 820, 15841],
        [5576, 797, 15385],
        [-5524, 2368, 15242],
        [-4061, 2436, 15685],
        [-2486, 2486, 16002],
        [-837, 2511, 16169],
        [837, 2511, 16169],
        [2486, 2486, 16002],
        [4061, 2436, 15685],
        [5524, 2368, 15242],
        [-5424, 3875, 14967],
        [-3983, 3983, 15385],
        [-2436, 4061, 15685],
        [-820, 4101, 15841],
        [820, 4101, 15841],
        [2436, 4061, 15685],
        [3983, 3983, 15385],
        [5424, 3875, 14967],
        [-5284, 5284, 14580],
        [-3875, 5424, 14967],
        [-2368, 5524, 15242],
        [-797, 5576, 15385],
        [797, 5576, 15385],
        [2368, 5524, 15242],
        [3875, 5424, 14967],
        [5284, 5284, 14580],
    ],
};

/// The same sensor in 4×4 mode (16 zones over the same field of view).
pub const VL53L5CX_4X4: ZoneGrid<16> = ZoneGrid {
    rays_q14: [
        [-4660, -4660, 15000],
        [-1612, -4837, 15570],
        [1612, -4837, 15570],
        [4660, -4660, 15000],
        [-4837, -1612, 15570],
        [-1679, -1679, 16211],
        [1679, -1679, 16211],
        [4837, -1612, 15570],
        [-4837, 1612, 15570],
        [-1679, 1679, 16211],
        [1679, 1679, 16211],
        [4837, 1612, 15570],
        [-4660, 4660, 15000],
        [-1612, 4837, 15570],
        [1612, 4837, 15570],
        [4660, 4660, 15000],
    ],
};

#[cfg(test)]
mod tests {
    use super::*;

    /// The f64 geometry: zone centres evenly over ±tan 22.5° in x and y, normalised.
    fn exact(w: usize, zone: usize) -> [f64; 3] {
        let t = (22.5f64).to_radians().tan();
        let (col, row) = ((zone % w) as f64, (zone / w) as f64);
        let x = ((col + 0.5) / w as f64 * 2.0 - 1.0) * t;
        let y = ((row + 0.5) / w as f64 * 2.0 - 1.0) * t;
        let inv = 1.0 / (x * x + y * y + 1.0).sqrt();
        [x * inv, y * inv, inv]
    }

    fn check<const Z: usize>(grid: &ZoneGrid<Z>, w: usize) {
        for zone in 0..Z {
            let e = exact(w, zone);
            for a in 0..3 {
                let q = f64::from(grid.rays_q14[zone][a]) / f64::from(RAY_ONE);
                assert!(
                    (q - e[a]).abs() <= 0.5 / f64::from(RAY_ONE),
                    "zone {zone} axis {a}"
                );
            }
            // A point at 4 m is the exact one to the millimetre.
            let p = grid.point_mm(zone, 4000).unwrap();
            for a in 0..3 {
                assert!((f64::from(p[a]) - 4000.0 * e[a]).abs() <= 0.5 + 4000.0 * 0.5 / 16384.0);
            }
        }
        assert_eq!(grid.point_mm(Z, 1000), None);
    }

    #[test]
    fn the_tables_are_the_geometry() {
        check(&VL53L5CX_8X8, 8);
        check(&VL53L5CX_4X4, 4);
    }

    #[test]
    fn the_largest_range_does_not_overflow() {
        for zone in 0..64 {
            let p = VL53L5CX_8X8.point_mm(zone, u16::MAX).unwrap();
            let r = VL53L5CX_8X8.ray(zone).unwrap();
            for a in 0..3 {
                assert!((p[a] as f32 - r[a] * 65535.0).abs() <= 1.0);
            }
        }
    }
}
