//! The synthetic room, its depth sensors and their paths: every point a hash of (seed, frame, zone).

#[allow(unused_imports)]
use crate::*;
use latentbki::f32math::sin_cos;
use latentbki::nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion};

/// A solid axis-aligned box of one category.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Block {
    /// Lowest corner (m).
    pub lo: [f32; 3],
    /// Highest corner (m).
    pub hi: [f32; 3],
    /// Its category.
    pub category: u8,
}

/// A closed box-shaped room `[0, size]` with solid furniture inside.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Room {
    /// Interior extent (m): x, y, z (z up; the floor is z = 0).
    pub size: [f32; 3],
    /// Furniture.
    pub blocks: [Block; 3],
}

impl Room {
    /// The table both rooms have.
    const TABLE: Block = Block {
        lo: [0.9, 0.4, 0.0],
        hi: [1.9, 1.2, 0.75],
        category: 3,
    };
    /// The cabinet both rooms have.
    const CABINET: Block = Block {
        lo: [3.4, 0.2, 0.0],
        hi: [3.95, 1.3, 1.8],
        category: 4,
    };

    /// A 4 m × 3 m room, 2.5 m high, with a table, a cabinet and a chair.
    pub const DEFAULT: Self = Self {
        size: [4.0, 3.0, 2.5],
        blocks: [
            Self::TABLE,
            Self::CABINET,
            Block {
                lo: [2.2, 2.5, 0.0],
                hi: [2.7, 2.95, 0.45],
                category: 5,
            },
        ],
    };

    /// A 4 m × 4 m room, 2.5 m high, opening at its far side into a 1.4 m wide corridor 6 m long (the
    /// corridor's side wall is the face of a solid block), with a table and a cabinet in the room.
    pub const WITH_CORRIDOR: Self = Self {
        size: [10.0, 4.0, 2.5],
        blocks: [
            Block {
                lo: [4.0, 0.0, 0.0],
                hi: [10.0, 2.6, 2.5],
                category: WALL,
            },
            Self::TABLE,
            Self::CABINET,
        ],
    };

    /// First surface hit by the ray `origin + t·dir` (origin inside the room, not inside furniture):
    /// distance t and category.
    pub fn cast(&self, origin: [f32; 3], dir: [f32; 3]) -> (f32, u8) {
        // Leaving the room: the nearest wall ahead on each axis.
        let mut best = (f32::INFINITY, WALL);
        for axis in 0..3 {
            let d = dir[axis];
            let (t, cat) = if d > 0.0 {
                (
                    (self.size[axis] - origin[axis]) / d,
                    if axis == 2 { CEILING } else { WALL },
                )
            } else if d < 0.0 {
                (-origin[axis] / d, if axis == 2 { FLOOR } else { WALL })
            } else {
                continue;
            };
            if t < best.0 {
                best = (t, cat);
            }
        }
        // Entering a block: the slab method.
        for b in &self.blocks {
            let (mut near, mut far) = (0.0f32, f32::INFINITY);
            for axis in 0..3 {
                let d = dir[axis];
                if d == 0.0 {
                    if origin[axis] < b.lo[axis] || origin[axis] > b.hi[axis] {
                        far = -1.0;
                    }
                    continue;
                }
                let t0 = (b.lo[axis] - origin[axis]) / d;
                let t1 = (b.hi[axis] - origin[axis]) / d;
                let (t0, t1) = if t0 < t1 { (t0, t1) } else { (t1, t0) };
                near = near.max(t0);
                far = far.min(t1);
            }
            if near <= far && near > 0.0 && near < best.0 {
                best = (near, b.category);
            }
        }
        best
    }
}

/// How a sensor's zones are laid out.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// A rectangular field of view (a depth camera, a multizone ToF): `width × height` zones.
    Frustum,
    /// A 2D scanning LiDAR: `width` beams evenly over a full turn in the sensor's x–z plane (level when the
    /// sensor is), one revolution per frame.
    Revolution,
}

/// A range sensor: `width × height` zones, each returning a range along its zone's centre ray. Sensor
/// frame: x right, y down, z forward.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DepthSensor {
    /// How the zones are laid out.
    pub layout: Layout,
    /// Zones per row.
    pub width: u16,
    /// Rows.
    pub height: u16,
    /// tan(horizontal field of view / 2).
    pub tan_half_x: f32,
    /// tan(vertical field of view / 2).
    pub tan_half_y: f32,
    /// Farthest range returned (m); beyond it a zone reports nothing.
    pub max_range: f32,
    /// Standard deviation of the range noise (m).
    pub range_noise: f32,
}

impl DepthSensor {
    /// An 8×8 multizone time-of-flight sensor like the VL53L5CX: 45° × 45°, 4 m, ±1 cm.
    pub const TOF_8X8: Self = Self {
        layout: Layout::Frustum,
        width: 8,
        height: 8,
        tan_half_x: 0.414_213_57,
        tan_half_y: 0.414_213_57,
        max_range: 4.0,
        range_noise: 0.01,
    };

    /// A depth camera subsampled to 64×64 (4,096 points a frame) over the central 30° × 30° of its view,
    /// 6 m, ±5 mm.
    pub const DEPTH_64X64: Self = Self {
        layout: Layout::Frustum,
        width: 64,
        height: 64,
        tan_half_x: 0.267_949_2,
        tan_half_y: 0.267_949_2,
        max_range: 6.0,
        range_noise: 0.005,
    };

    /// A 2D scanning LiDAR (like an RPLIDAR A1 at 10 Hz): 360 beams per revolution, 8 m, ±1 cm.
    pub const LIDAR_360: Self = Self {
        layout: Layout::Revolution,
        width: 360,
        height: 1,
        tan_half_x: 0.0,
        tan_half_y: 0.0,
        max_range: 8.0,
        range_noise: 0.01,
    };

    /// Zones per frame.
    pub const fn zones(&self) -> u32 {
        self.width as u32 * self.height as u32
    }

    /// Unit direction of a zone's centre ray in the sensor frame (zones row by row).
    pub fn ray(&self, zone: u32) -> [f32; 3] {
        let (w, h) = (u32::from(self.width.max(1)), u32::from(self.height.max(1)));
        if self.layout == Layout::Revolution {
            let turn = ((zone % w) as f32 + 0.5) / w as f32;
            let (s, c) = sin_cos(2.0 * core::f32::consts::PI * turn);
            return [s, 0.0, c];
        }
        let (col, row) = (zone % w, (zone / w) % h);
        let x = ((col as f32 + 0.5) / w as f32 * 2.0 - 1.0) * self.tan_half_x;
        let y = ((row as f32 + 0.5) / h as f32 * 2.0 - 1.0) * self.tan_half_y;
        let inv = 1.0 / libm::sqrtf(x * x + y * y + 1.0);
        [x * inv, y * inv, inv]
    }
}

/// Where the sensor is for one frame: its origin and its axes (right, down, forward) in the map frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    /// Sensor origin in the map frame (m).
    pub origin: [f32; 3],
    /// Columns of the sensor → map rotation: the sensor's x (right), y (down), z (forward) axes.
    pub axes: [[f32; 3]; 3],
}

impl View {
    /// A map-frame direction from a sensor-frame one.
    pub fn to_map(&self, d: [f32; 3]) -> [f32; 3] {
        let a = &self.axes;
        core::array::from_fn(|i| a[0][i] * d[0] + a[1][i] * d[1] + a[2][i] * d[2])
    }

    /// The pose (sensor → map) the map integrates this frame with.
    pub fn pose(&self) -> Isometry3<f32> {
        let a = &self.axes;
        #[rustfmt::skip]
        let m = Matrix3::new(
            a[0][0], a[1][0], a[2][0],
            a[0][1], a[1][1], a[2][1],
            a[0][2], a[1][2], a[2][2],
        );
        let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m));
        Isometry3::from_parts(
            Translation3::new(self.origin[0], self.origin[1], self.origin[2]),
            rotation,
        )
    }
}

/// One sensor return.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation {
    /// The point in the sensor frame (m).
    pub point: [f32; 3],
    /// The category of the surface it hit (ground truth).
    pub category: u8,
}

/// Where the sensor goes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Path {
    /// Circling the room's free middle at 1.2 m height (radius 0.5 m), looking outwards and sweeping its
    /// pitch, `frames_per_turn` frames a turn ([`Room::DEFAULT`]).
    Circle,
    /// A robot base at 0.3 m height with a level sensor, driving from the room's corner across the room and
    /// down the corridor of [`Room::WITH_CORRIDOR`] in `frames_per_turn` frames (then standing still).
    RoomAndCorridor,
}

/// The room, the sensor on its trajectory, and the noise: everything a run generates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scene {
    /// The room.
    pub room: Room,
    /// The sensor.
    pub sensor: DepthSensor,
    /// Seed of every noise draw.
    pub seed: u32,
    /// Standard deviation of the feature noise, per component.
    pub feature_noise: f32,
    /// Frames per turn of the trajectory (per traversal for [`Path::RoomAndCorridor`]).
    pub frames_per_turn: u32,
    /// The trajectory.
    pub path: Path,
}

impl Scene {
    /// The default room seen by `sensor`, 48 frames a turn, feature noise 0.1 per component.
    pub const fn new(sensor: DepthSensor, seed: u32) -> Self {
        Self {
            room: Room::DEFAULT,
            sensor,
            seed,
            feature_noise: 0.1,
            frames_per_turn: 48,
            path: Path::Circle,
        }
    }

    /// A 2D LiDAR on a robot driving through a room and down a corridor ([`Path::RoomAndCorridor`]) in
    /// `frames` revolutions.
    pub const fn room_and_corridor(sensor: DepthSensor, seed: u32, frames: u32) -> Self {
        Self {
            room: Room::WITH_CORRIDOR,
            sensor,
            seed,
            feature_noise: 0.1,
            frames_per_turn: frames,
            path: Path::RoomAndCorridor,
        }
    }

    /// The sensor's view at a frame: it circles the room's free middle at 1.2 m height (radius 0.5 m),
    /// looking outwards and sweeping its pitch between −0.55 and 0.35 rad.
    pub fn view(&self, frame: u32) -> View {
        if self.path == Path::RoomAndCorridor {
            return self.drive(frame);
        }
        let turn =
            (frame % self.frames_per_turn.max(1)) as f32 / self.frames_per_turn.max(1) as f32;
        let phase = 2.0 * core::f32::consts::PI * turn;
        let (s, c) = sin_cos(phase);
        let origin = [2.6 + 0.5 * c, 1.6 + 0.5 * s, 1.2];
        let pitch = -0.1 + 0.45 * sin_cos(3.0 * phase).0;
        let (sp, cp) = sin_cos(pitch);
        // Look outwards, 30° ahead of the radius so the view sweeps along the walls.
        let yaw = phase + 0.5;
        let (sy, cy) = sin_cos(yaw);
        let forward = [cy * cp, sy * cp, sp];
        let right = [sy, -cy, 0.0];
        // down = forward × right
        let down = [
            forward[1] * right[2] - forward[2] * right[1],
            forward[2] * right[0] - forward[0] * right[2],
            forward[0] * right[1] - forward[1] * right[0],
        ];
        View {
            origin,
            axes: [right, down, forward],
        }
    }

    /// [`Path::RoomAndCorridor`]: from (1.0, 2.0) to (3.2, 3.3), then along the corridor to (9.5, 3.3), at
    /// constant speed; the sensor level, looking along the way (x forward, y left in the map).
    fn drive(&self, frame: u32) -> View {
        const A: [f32; 2] = [1.0, 2.0];
        const B: [f32; 2] = [3.2, 3.3];
        const C: [f32; 2] = [9.5, 3.3];
        let len_ab = libm::sqrtf((B[0] - A[0]) * (B[0] - A[0]) + (B[1] - A[1]) * (B[1] - A[1]));
        let len_bc = C[0] - B[0];
        let t = (frame as f32 / self.frames_per_turn.max(1) as f32).min(1.0) * (len_ab + len_bc);
        let (origin, dir) = if t < len_ab {
            let u = [(B[0] - A[0]) / len_ab, (B[1] - A[1]) / len_ab];
            ([A[0] + u[0] * t, A[1] + u[1] * t], u)
        } else {
            ([B[0] + (t - len_ab), B[1]], [1.0, 0.0])
        };
        let forward = [dir[0], dir[1], 0.0];
        let right = [dir[1], -dir[0], 0.0];
        View {
            origin: [origin[0], origin[1], 0.3],
            axes: [right, [0.0, 0.0, -1.0], forward],
        }
    }

    /// What zone `zone` of frame `frame` returns, seen from `view` (= `self.view(frame)`): the point and
    /// its category, and the feature written to `feature`. `None` if the surface is out of range.
    pub fn observe<const D: usize>(
        &self,
        view: &View,
        frame: u32,
        zone: u32,
        feature: &mut [f32; D],
    ) -> Option<Observation> {
        let ray = self.sensor.ray(zone);
        let (t, category) = self.room.cast(view.origin, view.to_map(ray));
        let h = hash(hash(self.seed, frame), zone);
        let range = t + self.sensor.range_noise * normal(h);
        if !(range > 0.0 && range <= self.sensor.max_range) {
            return None;
        }
        let code = &CategoryVectors::<D>::VECTORS[usize::from(category) % CATEGORIES];
        for (i, (f, c)) in feature.iter_mut().zip(code).enumerate() {
            *f = c + self.feature_noise * normal(hash(h, i as u32));
        }
        Some(Observation {
            point: [ray[0] * range, ray[1] * range, ray[2] * range],
            category,
        })
    }
}
