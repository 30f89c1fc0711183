//! A deterministic synthetic room and depth sensor, for firmware self-tests and their host twin.
//!
//! Firmware has no camera in CI, yet it must run the real loop — sense, integrate, stream — and the host
//! must be able to recompute, bit for bit, what the device did. So the scene is generated *on the device*
//! by code both sides share: a furnished room (floor, walls, ceiling, a table, a cabinet, a chair), a
//! depth sensor on a circular trajectory (an 8×8 multizone ToF like the VL53L5CX, or a 64×64 subsampled
//! depth camera for 4,096-point frames), and per-point features drawn from a compiled-in codebook (one
//! random unit vector per category) plus noise.
//!
//! Why it is shaped so:
//! - **Random access, no state**: every number is a hash of (seed, frame, zone, component), so points can
//!   be generated in chunks of any size (a few kilobytes of RAM on the device) and the host twin needs no
//!   replay; nothing depends on call order.
//! - **f32 only, explicit libm**: the same inputs give the same bits on a Cortex-M4F and on a desktop.
//!   Only IEEE-exact operations (+ − × ÷ √, floor) are used (sin and cos by a short f32 polynomial), and a
//!   point's sensor-frame coordinates are `range × ray`, so no rotation round-off enters the input.
//! - **Same loop on both sides**: [`run`] drives the core's [`Mapper`] (the one integrate-and-stream loop
//!   every firmware uses) on the firmware and in the twin; a [`Probe`] brackets the map's work so the
//!   firmware can count instructions around exactly that.
//!
//! It is an application of the core, not part of it: its own crate, used by the QEMU firmware, the host
//! twin (`host-sim/tests/firmware_qemu.rs`) and host-sim's examples.
#![no_std]
#![deny(missing_docs)]
#![forbid(unsafe_code)]
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use latentbki::batch::RejectionCounts;
use latentbki::config::{ConfigError, KernelMode, MapConfig, Prior};
use latentbki::f32math::sin_cos;
use latentbki::frame::{EncoderSettings, Resend};
use latentbki::local_map::{Counters, LocalMap};
use latentbki::mapper::{DrainError, Mapper, Setup, SetupError};
use latentbki::nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion};
use latentbki::wire::LinkStats;

pub mod loopback;

/// Number of categories in the room (and vectors in the codebook).
pub const CATEGORIES: usize = 6;

/// Category names, by index.
pub const CATEGORY_NAMES: [&str; CATEGORIES] =
    ["floor", "wall", "ceiling", "table", "cabinet", "chair"];

const FLOOR: u8 = 0;
const WALL: u8 = 1;
const CEILING: u8 = 2;

/// Seed of the compiled-in codebook.
pub const CODEBOOK_SEED: u32 = 0xC0DE_B00C;

/// One 32-bit hash step (murmur3's finaliser over a multiply-add mix): well mixed, cheap, deterministic.
#[inline]
pub const fn hash(a: u32, b: u32) -> u32 {
    let mut h = a.wrapping_mul(0x9E37_79B1) ^ b.wrapping_mul(0x85EB_CA77).rotate_left(13);
    h ^= h >> 16;
    h = h.wrapping_mul(0x85EB_CA6B);
    h ^= h >> 13;
    h = h.wrapping_mul(0xC2B2_AE35);
    h ^ (h >> 16)
}

/// An approximately standard normal number from one hash: the sum of its four bytes (Irwin–Hall, n = 4),
/// centred and scaled to unit variance.
#[inline]
pub fn normal(h: u32) -> f32 {
    let s = (h & 0xFF) + (h >> 8 & 0xFF) + (h >> 16 & 0xFF) + (h >> 24);
    // Mean 4 · 127.5 = 510; variance 4 · (256² − 1) / 12 = 21,845, σ = 147.80.
    (s as f32 - 510.0) * (1.0 / 147.800_54)
}

/// 1/√D by Newton's method, usable in `const` context.
const fn inv_sqrt(d: usize) -> f32 {
    let x = d as f32;
    let mut y = 1.0 / x;
    let mut i = 0;
    while i < 40 {
        y = y * (1.5 - 0.5 * x * y * y);
        i += 1;
    }
    y
}

/// The codebook: one vector per category, components ±1/√D with hashed signs (unit length; two
/// categories have cosine ≈ N(0, 1/D), so they are well apart at D = 64).
pub const fn codebook<const D: usize>(seed: u32) -> [[f32; D]; CATEGORIES] {
    let v = inv_sqrt(D);
    let mut out = [[0.0f32; D]; CATEGORIES];
    let mut c = 0;
    while c < CATEGORIES {
        let mut i = 0;
        while i < D {
            let h = hash(hash(seed, c as u32), i as u32);
            out[c][i] = if h & 1 == 0 { v } else { -v };
            i += 1;
        }
        c += 1;
    }
    out
}

/// The compiled-in codebook at dimension `D` (a `'static` table in flash).
pub struct CategoryVectors<const D: usize>;

impl<const D: usize> CategoryVectors<D> {
    /// The vectors, by category.
    pub const VECTORS: [[f32; D]; CATEGORIES] = codebook::<D>(CODEBOOK_SEED);

    /// The category whose vector has the largest cosine with `feature` (`None` for a zero vector).
    pub fn classify(feature: &[f32; D]) -> Option<u8> {
        let norm2: f32 = feature.iter().map(|v| v * v).sum();
        if !(norm2 > 0.0) {
            return None;
        }
        let mut best = (0u8, f32::NEG_INFINITY);
        for (c, v) in Self::VECTORS.iter().enumerate() {
            let dot: f32 = v.iter().zip(feature).map(|(a, b)| a * b).sum();
            if dot > best.1 {
                best = (c as u8, dot);
            }
        }
        Some(best.0)
    }
}

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
    /// A 4 m × 3 m room, 2.5 m high, with a table, a cabinet and a chair.
    pub const DEFAULT: Self = Self {
        size: [4.0, 3.0, 2.5],
        blocks: [
            Block {
                lo: [0.9, 0.4, 0.0],
                hi: [1.9, 1.2, 0.75],
                category: 3,
            },
            Block {
                lo: [3.4, 0.2, 0.0],
                hi: [3.95, 1.3, 1.8],
                category: 4,
            },
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
            Block {
                lo: [0.9, 0.4, 0.0],
                hi: [1.9, 1.2, 0.75],
                category: 3,
            },
            Block {
                lo: [3.4, 0.2, 0.0],
                hi: [3.95, 1.3, 1.8],
                category: 4,
            },
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

/// Brackets the map's work inside [`integrate_frame`] (the firmware counts instructions between the two
/// calls; the host does nothing).
pub trait Probe {
    /// The map's work begins.
    fn start(&mut self) {}
    /// The map's work ends.
    fn stop(&mut self) {}
}

/// A probe that does nothing.
impl Probe for () {}

/// Generation scratch for `K` points at a time (sensor-frame points and their features).
pub struct Chunk<const D: usize, const K: usize> {
    /// Map-frame points.
    pub points: [[f32; 3]; K],
    /// Their features.
    pub features: [[f32; D]; K],
    /// Their features as int8 codes (scenarios with int8 features).
    pub codes: [[i8; D]; K],
    /// The points in integer millimetres, as a range sensor reports them (scenarios with int8 features).
    pub points_mm: [[i32; 3]; K],
}

impl<const D: usize, const K: usize> Chunk<D, K> {
    /// All zero (a `static` initialiser that lands in `.bss`).
    pub const ZERO: Self = Self {
        points: [[0.0; 3]; K],
        features: [[0.0; D]; K],
        codes: [[0; D]; K],
        points_mm: [[0; 3]; K],
    };
}

/// int8 codes of a feature at `scale` (what an accelerator with that output scale hands the map): each
/// component rounded to the nearest code, clamped to ±127.
pub fn quantize<const D: usize>(feature: &[f32; D], scale: f32, codes: &mut [i8; D]) {
    let inv = 1.0 / scale;
    for (c, &v) in codes.iter_mut().zip(feature) {
        *c = libm::roundf(v * inv).clamp(-127.0, 127.0) as i8;
    }
}

/// What [`integrate_frame`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FrameReport {
    /// Sensor returns generated (zones in range).
    pub points: u32,
    /// Points the map integrated (its `counters().points` went up by this much).
    pub integrated: u32,
}

/// Generate frame `frame` of `scene` in chunks of `K` points and integrate it into `mapper` as one sensor
/// frame, as f32 features or (`int8_scale` > 0) as int8 codes of that scale with the points in integer
/// millimetres (the all-integer path, [`latentbki::mapper::SensorFrame::add_points_mm_i8`]) ([`Mapper::begin_frame`], then each chunk). The map's work — and only it — runs between
/// `probe.start()` and `probe.stop()` (once for the window move, once per chunk).
pub fn integrate_frame<
    const D: usize,
    const CAP: usize,
    const P: usize,
    const QB: usize,
    const N: usize,
    const H: usize,
    const K: usize,
    M: Probe,
>(
    scene: &Scene,
    frame: u32,
    int8_scale: f32,
    mapper: &mut Mapper<D, CAP, P, QB, N, H>,
    chunk: &mut Chunk<D, K>,
    probe: &mut M,
) -> FrameReport {
    let view = scene.view(frame);
    let mut report = FrameReport::default();
    let before = mapper.map().counters().points;
    probe.start();
    let mut batch = mapper.begin_frame(&view.pose());
    probe.stop();
    let zones = scene.sensor.zones();
    let mut zone = 0;
    while zone < zones {
        let mut n = 0;
        while n < K && zone < zones {
            if let Some(o) = scene.observe(&view, frame, zone, &mut chunk.features[n]) {
                chunk.points[n] = o.point;
                if int8_scale > 0.0 {
                    quantize(&chunk.features[n], int8_scale, &mut chunk.codes[n]);
                    chunk.points_mm[n] = o.point.map(|v| libm::roundf(v * 1000.0) as i32);
                }
                n += 1;
            }
            zone += 1;
        }
        report.points += n as u32;
        probe.start();
        // Refusals are counted by the map (`rejections`).
        if int8_scale > 0.0 {
            // An integer sensor and an int8 accelerator: no float operation per point.
            batch.add_points_mm_i8(&chunk.points_mm[..n], &chunk.codes[..n]);
        } else {
            batch.add_points(&chunk.points[..n], &chunk.features[..n]);
        }
        probe.stop();
    }
    report.integrated = batch.map().counters().points.wrapping_sub(before);
    report
}

/// One self-test run: a scene, how many frames, the map and the link.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scenario {
    /// What it measures, for reports (one word, no spaces).
    pub name: &'static str,
    /// What the sensor sees.
    pub scene: Scene,
    /// Frames integrated.
    pub frames: u32,
    /// Filter size f of the map (0.1 m voxels, ℓ = 0.5 m, default prior, voxel-offset kernel).
    pub filter_size: u8,
    /// Window radius around the sensor (m).
    pub window_radius: f32,
    /// Session id on the wire (robot [`SELF_TEST_ROBOT`]).
    pub session: u32,
    /// Link bytes per frame (e.g. 2,048 B: 460,800 Bd at 20 frames/s).
    pub tick_budget: usize,
    /// Scale of int8 features ([`Setup::with_int8_features`]); 0 = f32 features.
    pub int8_scale: f32,
}

/// Robot id the self-test streams as.
pub const SELF_TEST_ROBOT: u16 = 6;
/// RAM the self-test gives the map's voxels (slots and index): 192 KiB less 16 KiB of stack and 32 KiB
/// for the rest (the map's batch scratch and kernel table, the encoder, the point chunk).
pub const SELF_TEST_MAP_BUDGET: usize = 144 * 1024;
/// Voxels the self-test map holds at D = 64: what [`SELF_TEST_MAP_BUDGET`] buys at the current bytes per
/// voxel.
pub const SELF_TEST_CAPACITY: usize =
    SELF_TEST_MAP_BUDGET / LocalMap::<64, 1, { latentbki::quant::packed_len(64) }>::BYTES_PER_VOXEL;
/// Bytes of the encoder's queue of evicted voxels.
pub const SELF_TEST_QUEUE_BYTES: usize = 4096;
/// Of the queue budget: bytes that keep frames until the loopback acknowledges them.
pub const SELF_TEST_RESEND_BYTES: usize = 2048;
/// Largest frame on the wire.
pub const SELF_TEST_FRAME_BYTES: usize = 512;

/// The firmware self-test: the 8×8 ToF for three turns (f = 1), then 4,096-point depth frames at f = 1
/// and f = 3 (the instruction-count benchmark), then half a turn of depth frames with a window that holds
/// the whole room (f = 3): the map fills, so the run measures how many voxels a full map answers; then the
/// sensor patterns at f = 3 for the instruction counts: the depth frames with int8 features, the 8×8 ToF,
/// and a 2D scanning LiDAR (360 beams per revolution, 240 revolutions: 24 s at 10 Hz) driving through a room
/// and down a corridor.
pub const SELF_TEST: [Scenario; 7] = [
    Scenario {
        name: "tof_f1",
        scene: Scene::new(DepthSensor::TOF_8X8, 0x70F),
        frames: 144,
        filter_size: 1,
        window_radius: 2.0,
        session: 1,
        tick_budget: 2048,
        int8_scale: 0.0,
    },
    Scenario {
        name: "depth_f1",
        scene: Scene::new(DepthSensor::DEPTH_64X64, 0xD1),
        frames: 8,
        filter_size: 1,
        window_radius: 2.5,
        session: 2,
        tick_budget: 8192,
        int8_scale: 0.0,
    },
    Scenario {
        name: "depth_f3",
        scene: Scene::new(DepthSensor::DEPTH_64X64, 0xD3),
        frames: 8,
        filter_size: 3,
        window_radius: 2.5,
        session: 3,
        tick_budget: 8192,
        int8_scale: 0.0,
    },
    Scenario {
        name: "full_map",
        scene: Scene::new(DepthSensor::DEPTH_64X64, 0xD4),
        frames: 24,
        filter_size: 3,
        window_radius: 4.0,
        session: 4,
        tick_budget: 8192,
        int8_scale: 0.0,
    },
    Scenario {
        name: "depth_f3_i8",
        scene: Scene::new(DepthSensor::DEPTH_64X64, 0xD3),
        frames: 8,
        filter_size: 3,
        window_radius: 2.5,
        session: 5,
        tick_budget: 8192,
        int8_scale: SELF_TEST_INT8_SCALE,
    },
    Scenario {
        name: "tof_f3",
        scene: Scene::new(DepthSensor::TOF_8X8, 0x70F),
        frames: 144,
        filter_size: 3,
        window_radius: 2.0,
        session: 6,
        tick_budget: 2048,
        int8_scale: 0.0,
    },
    Scenario {
        name: "lidar_f3",
        scene: Scene::room_and_corridor(DepthSensor::LIDAR_360, 0x11DA, 240),
        frames: 240,
        filter_size: 3,
        window_radius: 4.0,
        session: 7,
        tick_budget: 2048,
        int8_scale: 0.0,
    },
];

/// Scale of the self-test's int8 features: codes of ±127 reach ±0.635, beyond the codebook's ±1/8 plus
/// five standard deviations of its 0.1 noise.
pub const SELF_TEST_INT8_SCALE: f32 = 0.005;

impl Scenario {
    /// The map configuration.
    pub fn map_config(&self) -> Result<MapConfig, ConfigError> {
        MapConfig::new(
            0.1,
            0.5,
            self.filter_size,
            Prior::default(),
            KernelMode::VoxelOffset,
        )
    }

    /// The mapper's setup: this map, robot [`SELF_TEST_ROBOT`] with the scenario's session, default codec,
    /// no PCA, the int8 scale if any, and a back channel (half the queue budget keeps unacknowledged
    /// frames; [`run`] loops the acknowledgements back).
    pub fn setup(&self) -> Result<Setup, ConfigError> {
        let setup = Setup::new(
            self.map_config()?,
            self.window_radius,
            EncoderSettings::new(SELF_TEST_ROBOT, self.session)
                .with_resend(Resend::new(SELF_TEST_RESEND_BYTES as u32, 4)),
        );
        Ok(if self.int8_scale > 0.0 {
            setup.with_int8_features(self.int8_scale)
        } else {
            setup
        })
    }

    /// Clear `mapper` and configure it for this scenario (in place).
    pub fn configure<
        const D: usize,
        const CAP: usize,
        const P: usize,
        const QB: usize,
        const N: usize,
        const H: usize,
    >(
        &self,
        mapper: &mut Mapper<D, CAP, P, QB, N, H>,
    ) -> Result<(), SetupError> {
        mapper.configure(&self.setup().map_err(SetupError::Map)?)
    }
}

/// What [`run`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RunReport {
    /// Sensor returns generated.
    pub points: u32,
    /// Points the map accepted.
    pub integrated: u32,
    /// Points refused, by reason.
    pub rejections: RejectionCounts,
    /// The map's counters.
    pub counters: Counters,
    /// Most voxels held at the end of a frame.
    pub peak_voxels: u32,
    /// Voxels flushed at the end.
    pub flushed: u32,
    /// The encoder's link statistics at the end.
    pub link: LinkStats,
}

/// Run a scenario on a mapper freshly configured for it ([`Scenario::configure`]): integrate every frame
/// (the map's work bracketed by `probe`), after each frame let the mapper spend the scenario's byte budget
/// on `w`, and at the end drain it ([`Mapper::drain`]: every voxel, then a link-statistics frame).
/// `on_frame` sees each frame's report (the firmware logs it and marks the end of the frame for the
/// instruction counter).
pub fn run<
    const D: usize,
    const CAP: usize,
    const P: usize,
    const QB: usize,
    const N: usize,
    const H: usize,
    const K: usize,
    W,
    M,
>(
    scenario: &Scenario,
    mapper: &mut Mapper<D, CAP, P, QB, N, H>,
    chunk: &mut Chunk<D, K>,
    w: &mut W,
    probe: &mut M,
    mut on_frame: impl FnMut(u32, &FrameReport, &LocalMap<D, CAP, P, H>),
) -> Result<RunReport, RunError<W::Error>>
where
    W: embedded_io::Write,
    M: Probe,
{
    let config = scenario.map_config().map_err(RunError::Config)?;
    let map = mapper.map();
    let fresh = map.config() == &config && map.is_empty() && map.counters() == Counters::default();
    if !fresh || !mapper.encoder().is_configured() || mapper.encoder().next_seq() != 0 {
        return Err(RunError::NotConfigured);
    }
    let mut report = RunReport::default();
    // The frames go to the UART; the loopback acknowledges them as a base station on a perfect link would.
    let mut back = loopback::Loopback::new();
    let (robot, session) = (SELF_TEST_ROBOT, scenario.session);
    for frame in 0..scenario.frames {
        let f = integrate_frame(
            &scenario.scene,
            frame,
            scenario.int8_scale,
            mapper,
            chunk,
            probe,
        );
        report.points += f.points;
        report.integrated += f.integrated;
        report.peak_voxels = report.peak_voxels.max(mapper.map().len() as u32);
        on_frame(frame, &f, mapper.map());
        mapper
            .tick(w, scenario.tick_budget)
            .map_err(|latentbki::frame::TickError::Write(e, _)| RunError::Write(e))?;
        back.acknowledge_all(robot, session, mapper.encoder().next_seq());
        let Ok(_) = mapper.poll_acks(&mut back);
    }
    // Drain: a full re-send buffer waits for acknowledgements.
    let before = mapper.map().counters().evicted;
    loop {
        let done = match mapper.drain(w) {
            Ok(_) => true,
            Err(DrainError::Write(e)) => return Err(RunError::Write(e)),
            Err(DrainError::Stuck) => false,
        };
        back.acknowledge_all(robot, session, mapper.encoder().next_seq());
        let Ok(read) = mapper.poll_acks(&mut back);
        if done {
            break;
        }
        if read == 0 {
            return Err(RunError::Stuck);
        }
    }
    if !mapper.is_drained() {
        return Err(RunError::Stuck);
    }
    report.flushed = mapper.map().counters().evicted.wrapping_sub(before);
    report.rejections = mapper.map().rejections();
    report.counters = mapper.map().counters();
    report.link = mapper.encoder().stats();
    Ok(report)
}

/// Why [`run`] stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RunError<E> {
    /// The scenario's map configuration is invalid.
    Config(ConfigError),
    /// The mapper was not freshly configured for this scenario.
    NotConfigured,
    /// The writer failed.
    Write(E),
    /// The encoder could not send a queued voxel (its frame size is too small for one summary).
    Stuck,
}

#[cfg(test)]
mod tests {
    use super::*;
    use latentbki::key::to_map_frame;
    use latentbki::quant::packed_len;

    #[test]
    fn normal_has_unit_moments() {
        let n = 100_000u32;
        let (mut s, mut s2) = (0.0f64, 0.0f64);
        for i in 0..n {
            let v = f64::from(normal(hash(7, i)));
            s += v;
            s2 += v * v;
        }
        let mean = s / f64::from(n);
        let var = s2 / f64::from(n) - mean * mean;
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((var - 1.0).abs() < 0.02, "variance {var}");
    }

    #[test]
    fn codebook_is_unit_and_well_separated() {
        let cb = CategoryVectors::<64>::VECTORS;
        for (a, va) in cb.iter().enumerate() {
            let n: f32 = va.iter().map(|v| v * v).sum();
            assert!((n - 1.0).abs() < 1e-5, "norm² {n}");
            for vb in &cb[a + 1..] {
                let cos: f32 = va.iter().zip(vb).map(|(x, y)| x * y).sum();
                assert!(cos.abs() < 0.5, "cosine {cos}");
            }
            assert_eq!(CategoryVectors::<64>::classify(va), Some(a as u8));
        }
    }

    #[test]
    fn rays_are_unit_and_span_the_field_of_view() {
        let s = DepthSensor::TOF_8X8;
        for z in 0..s.zones() {
            let r = s.ray(z);
            let n = libm::sqrtf(r[0] * r[0] + r[1] * r[1] + r[2] * r[2]);
            assert!((n - 1.0).abs() < 1e-6);
            assert!(r[2] > 0.8);
        }
        // Zone 0 is top-left (x < 0, y < 0); the last is bottom-right.
        let (a, b) = (s.ray(0), s.ray(63));
        assert!(a[0] < 0.0 && a[1] < 0.0 && b[0] > 0.0 && b[1] > 0.0);
        assert!((a[0] + b[0]).abs() < 1e-7);
    }

    #[test]
    fn cast_finds_floor_walls_and_furniture() {
        let r = Room::DEFAULT;
        assert_eq!(r.cast([2.0, 1.5, 1.0], [0.0, 0.0, -1.0]), (1.0, FLOOR));
        assert_eq!(r.cast([2.0, 1.5, 1.0], [0.0, 0.0, 1.0]), (1.5, CEILING));
        assert_eq!(r.cast([2.0, 2.5, 1.0], [-1.0, 0.0, 0.0]), (2.0, WALL));
        // Straight down onto the table top at 0.75 m.
        let (t, c) = r.cast([1.4, 0.8, 1.0], [0.0, 0.0, -1.0]);
        assert_eq!(c, 3);
        assert!((t - 0.25).abs() < 1e-6);
        // Towards +x at cabinet height: the cabinet front at x = 3.4.
        let (t, c) = r.cast([2.0, 0.7, 1.0], [1.0, 0.0, 0.0]);
        assert_eq!(c, 4);
        assert!((t - 1.4).abs() < 1e-6);
    }

    #[test]
    fn observed_points_lie_on_the_surfaces() {
        let scene = Scene::new(DepthSensor::TOF_8X8, 3);
        let mut f = [0.0f32; 64];
        let mut seen = [0u32; CATEGORIES];
        for frame in 0..scene.frames_per_turn {
            let view = scene.view(frame);
            let pose = view.pose();
            for zone in 0..scene.sensor.zones() {
                let o = scene
                    .observe(&view, frame, zone, &mut f)
                    .expect("closed room: always a return");
                seen[usize::from(o.category)] += 1;
                // Back in the map frame, the point is on its surface to within the range noise (5σ).
                let p = to_map_frame(&pose, o.point);
                let d = match o.category {
                    FLOOR => p[2].abs(),
                    CEILING => (p[2] - 2.5).abs(),
                    WALL => [p[0], 4.0 - p[0], p[1], 3.0 - p[1]]
                        .iter()
                        .fold(9.0f32, |m, v| m.min(v.abs())),
                    _ => {
                        let b = scene
                            .room
                            .blocks
                            .iter()
                            .find(|b| b.category == o.category)
                            .unwrap();
                        (0..3)
                            .map(|i| (p[i] - b.lo[i]).abs().min((p[i] - b.hi[i]).abs()))
                            .fold(9.0f32, f32::min)
                    }
                };
                assert!(
                    d < 5.0 * scene.sensor.range_noise,
                    "frame {frame} zone {zone}: {d} m off its {} surface",
                    o.category
                );
                assert_eq!(CategoryVectors::<64>::classify(&f), Some(o.category));
            }
        }
        assert!(
            seen.iter().all(|&n| n > 0),
            "every category is seen: {seen:?}"
        );
    }

    #[test]
    fn lidar_drives_through_the_room_and_down_the_corridor() {
        let sc = SELF_TEST.iter().find(|s| s.name == "lidar_f3").unwrap();
        let scene = sc.scene;
        let mut f = [0.0f32; 64];
        let (first, last) = (scene.view(0), scene.view(sc.frames - 1));
        assert!(
            first.origin[0] < 1.5 && last.origin[0] > 9.0,
            "{first:?} {last:?}"
        );
        for frame in [0, sc.frames / 2, sc.frames - 1] {
            let view = scene.view(frame);
            let pose = view.pose();
            let mut returns = 0;
            for zone in 0..scene.sensor.zones() {
                // Beams down the corridor's length may reach beyond the 8 m range.
                let Some(o) = scene.observe(&view, frame, zone, &mut f) else {
                    continue;
                };
                returns += 1;
                let p = to_map_frame(&pose, o.point);
                assert!((p[2] - 0.3).abs() < 1e-4, "a level scan: {p:?}");
                assert_eq!(CategoryVectors::<64>::classify(&f), Some(o.category));
            }
            assert!(returns > 340, "frame {frame}: {returns} returns");
        }
        // In the corridor, the nearest wall is the corridor's (1.4 m wide).
        let view = scene.view(sc.frames - 10);
        let left = scene.room.cast(view.origin, [0.0, 1.0, 0.0]).0;
        let right = scene.room.cast(view.origin, [0.0, -1.0, 0.0]).0;
        assert!((left + right - 1.4).abs() < 1e-5);
    }

    #[test]
    fn quantize_rounds_and_clamps() {
        let mut c = [0i8; 4];
        quantize(&[0.0124, -0.0126, 1.0, -1.0], 0.005, &mut c);
        assert_eq!(c, [2, -3, 127, -127]);
    }

    /// Collects the link's bytes.
    struct Bytes(Vec<u8>);
    impl embedded_io::ErrorType for Bytes {
        type Error = core::convert::Infallible;
    }
    impl embedded_io::Write for Bytes {
        fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
            self.0.extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> Result<(), Self::Error> {
            Ok(())
        }
    }

    #[test]
    fn generation_is_deterministic_and_chunking_does_not_matter() {
        const P: usize = packed_len(16);
        type Small = Mapper<16, 600, P, 4096, 512>;
        let scene = Scene::new(DepthSensor::TOF_8X8, 9);
        let run = |chunk_points: usize| {
            let mut mapper = Box::new(Small::EMPTY);
            let setup = Setup::new(MapConfig::default(), 1.5, EncoderSettings::new(1, 1));
            mapper.configure(&setup).unwrap();
            let mut out = Bytes(Vec::new());
            let mut reports = Vec::new();
            for frame in 0..20 {
                reports.push(if chunk_points == 5 {
                    let mut c = Box::new(Chunk5::ZERO);
                    integrate_frame(&scene, frame, 0.0, &mut mapper, &mut c, &mut ())
                } else {
                    let mut c = Box::new(Chunk64::ZERO);
                    integrate_frame(&scene, frame, 0.0, &mut mapper, &mut c, &mut ())
                });
                mapper.tick(&mut out, 2048).unwrap();
            }
            let evicted = mapper.map().counters().evicted;
            mapper.drain(&mut out).unwrap();
            (out.0, reports, evicted)
        };
        let (a, ra, evicted) = run(5);
        let (b, rb, _) = run(64);
        assert_eq!(ra, rb);
        assert!(ra.iter().all(|r| r.points == 64), "{ra:?}");
        assert!(ra.iter().map(|r| r.integrated).sum::<u32>() > 600, "{ra:?}");
        assert!(evicted > 100, "the window and the pool evict: {evicted}");
        assert!(a.len() > 4000, "frames were sent: {} B", a.len());
        assert_eq!(a, b, "the same bytes on the link");
    }

    extern crate std;
    type Chunk5 = Chunk<16, 5>;
    type Chunk64 = Chunk<16, 64>;
    use std::boxed::Box;
    use std::vec::Vec;
}
