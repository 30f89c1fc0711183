//! A procedural indoor scene: a house of 2 × 2 rooms with walls, doors, windows and furniture, named with the
//! paper's Matterport-style categories, generated from a seed.
//!
//! Everything is an axis-aligned box (so ray casting is an exact slab test and the scene stays readable):
//! walls with door openings and lintels, floors, ceilings, windows proud of the outer walls, and furniture
//! by room type (living room, bedroom, kitchen, bathroom). Every box belongs to an object instance; the
//! simulated encoder mislabels parts of instances. The robot carries a forward camera on a loop that goes
//! through every room and door, sweeping its gaze from side to side.

mod furniture;

use super::sensor::{DepthCamera, MultizoneTof, RayScene};
use super::trajectory::{along_polyline, camera_pose};
use super::{mix_all, unit, ScanFrame, Sequence};
use latentbki::{KernelMode, MapConfig, Prior};
use rand_xoshiro::rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

/// The indoor categories (all in the committed vocabulary).
pub const INDOOR_CLASSES: [&str; 23] = [
    "wall", "floor", "ceiling", "door", "window", "table", "chair", "sofa", "bed", "cabinet",
    "shelf", "toilet", "sink", "bathtub", "plant", "lamp", "tv", "counter", "picture", "cushion",
    "towel", "curtain", "mirror",
];

fn class(name: &str) -> u16 {
    INDOOR_CLASSES
        .iter()
        .position(|c| *c == name)
        .expect("indoor class is listed") as u16
}

/// An axis-aligned box of one class, part of one object instance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Minimum corner, metres.
    pub min: [f32; 3],
    /// Maximum corner, metres.
    pub max: [f32; 3],
    /// Class index into [`INDOOR_CLASSES`].
    pub class: u16,
    /// Object instance.
    pub instance: u32,
}

impl Aabb {
    /// Ray–box slab test: entry distance of a ray starting outside the box, if it hits within `max_t`.
    pub fn hit(&self, o: [f32; 3], d: [f32; 3], max_t: f32) -> Option<f32> {
        let (mut t0, mut t1) = (0.0f32, max_t);
        for a in 0..3 {
            if d[a].abs() < 1e-12 {
                if o[a] < self.min[a] || o[a] > self.max[a] {
                    return None;
                }
                continue;
            }
            let inv = 1.0 / d[a];
            let (mut ta, mut tb) = ((self.min[a] - o[a]) * inv, (self.max[a] - o[a]) * inv);
            if ta > tb {
                std::mem::swap(&mut ta, &mut tb);
            }
            t0 = t0.max(ta);
            t1 = t1.min(tb);
            if t0 > t1 {
                return None;
            }
        }
        // A ray starting inside the box (the robot's path crossing furniture) does not see it.
        (t0 > 0.0).then_some(t0)
    }
}

/// One room: its floor rectangle and type.
#[derive(Clone, Copy, Debug)]
pub struct RoomPlan {
    /// Minimum xy corner (inner face of the walls).
    pub min: [f32; 2],
    /// Maximum xy corner.
    pub max: [f32; 2],
    /// "living room", "bedroom", "kitchen" or "bathroom".
    pub kind: &'static str,
}

/// The generated house.
#[derive(Clone, Debug)]
pub struct IndoorScene {
    /// All boxes.
    pub boxes: Vec<Aabb>,
    /// The four rooms (row-major: (0,0), (1,0), (0,1), (1,1)).
    pub rooms: Vec<RoomPlan>,
    /// Door centres (xy) in the order the loop passes them.
    pub doors: Vec<[f32; 2]>,
    /// Ceiling height above the floor, metres.
    pub height: f32,
    /// Height of the floor surface in the map, metres.
    pub floor: f32,
}

impl RayScene for IndoorScene {
    fn cast(&self, o: [f32; 3], d: [f32; 3], max_t: f32) -> Option<(f32, u16, u32)> {
        let mut best: Option<(f32, u16, u32)> = None;
        for b in &self.boxes {
            let limit = best.map_or(max_t, |x| x.0);
            if let Some(t) = b.hit(o, d, limit) {
                if best.is_none_or(|x| t < x.0) {
                    best = Some((t, b.class, b.instance));
                }
            }
        }
        best
    }
}

const WALL: f32 = 0.1;
/// Where the house's corner (and floor) sits in the map. Not on voxel boundaries: real surfaces are not
/// aligned with the voxel grid, and a floor exactly at a boundary would straddle two voxel layers.
const HOUSE_OFFSET: [f32; 3] = [0.013, 0.021, 0.017];
const DOOR_W: f32 = 0.9;
const DOOR_H: f32 = 2.1;

struct Builder {
    boxes: Vec<Aabb>,
    next_instance: u32,
    seed: u64,
    draws: u64,
}

impl Builder {
    pub(super) fn rand(&mut self) -> f32 {
        self.draws += 1;
        unit(mix_all(&[self.seed, self.draws]))
    }
    pub(super) fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.rand()
    }
    pub(super) fn instance(&mut self) -> u32 {
        self.next_instance += 1;
        self.next_instance
    }
    pub(super) fn push(&mut self, min: [f32; 3], max: [f32; 3], class_name: &str, instance: u32) {
        self.boxes.push(Aabb {
            min,
            max,
            class: class(class_name),
            instance,
        });
    }
    pub(super) fn free(
        &self,
        min: [f32; 2],
        max: [f32; 2],
        placed: &[([f32; 2], [f32; 2])],
    ) -> bool {
        placed
            .iter()
            .all(|(a, b)| max[0] <= a[0] || min[0] >= b[0] || max[1] <= a[1] || min[1] >= b[1])
    }
}

impl IndoorScene {
    /// Generate a house from a seed.
    pub fn generate(seed: u64) -> Self {
        let mut b = Builder {
            boxes: Vec::new(),
            next_instance: 1000,
            seed,
            draws: 0,
        };
        let height: f32 = 2.6;
        let xs = [0.0, b.range(3.8, 5.0), 0.0];
        let xs = [xs[0], xs[1], xs[1] + WALL + b.range(3.8, 5.0)];
        let ys0 = b.range(3.8, 5.0);
        let ys = [0.0, ys0, ys0 + WALL + b.range(3.8, 5.0)];
        let mut kinds = ["living room", "bedroom", "kitchen", "bathroom"];
        // Seeded shuffle of the room types.
        for i in (1..4).rev() {
            let j = (b.rand() * (i + 1) as f32) as usize % (i + 1);
            kinds.swap(i, j);
        }
        let mut rooms = Vec::new();
        for j in 0..2 {
            for i in 0..2 {
                let min = [
                    xs[i] + if i == 1 { WALL } else { 0.0 },
                    ys[j] + if j == 1 { WALL } else { 0.0 },
                ];
                let max = [
                    if i == 0 { xs[1] } else { xs[2] },
                    if j == 0 { ys[1] } else { ys[2] },
                ];
                rooms.push(RoomPlan {
                    min,
                    max,
                    kind: kinds[j * 2 + i],
                });
            }
        }
        let (x_max, y_max) = (xs[2], ys[2]);
        // Floor and ceiling per room (separate instances, so a room's floor is its own object).
        for r in &rooms {
            let fi = b.instance();
            b.push(
                [r.min[0], r.min[1], -0.1],
                [r.max[0], r.max[1], 0.0],
                "floor",
                fi,
            );
            let ci = b.instance();
            b.push(
                [r.min[0], r.min[1], height],
                [r.max[0], r.max[1], height + 0.1],
                "ceiling",
                ci,
            );
        }
        // Outer walls.
        let outer = [
            ([-WALL, -WALL], [x_max + WALL, 0.0]),
            ([-WALL, y_max], [x_max + WALL, y_max + WALL]),
            ([-WALL, 0.0], [0.0, y_max]),
            ([x_max, 0.0], [x_max + WALL, y_max]),
        ];
        for (lo, hi) in outer {
            let w = b.instance();
            b.push([lo[0], lo[1], 0.0], [hi[0], hi[1], height], "wall", w);
        }
        // Interior walls with one door each: x = xs[1] (between columns), y = ys[1] (between rows).
        let door_y = [(0.0 + ys[1]) / 2.0, (ys[1] + WALL + y_max) / 2.0];
        let door_x = [(0.0 + xs[1]) / 2.0, (xs[1] + WALL + x_max) / 2.0];
        let mut doors = Vec::new();
        // Vertical wall segment pieces along y, for each row of rooms.
        for (row, &dy) in door_y.iter().enumerate() {
            let (y0, y1) = if row == 0 {
                (0.0, ys[1])
            } else {
                (ys[1] + WALL, y_max)
            };
            let w = b.instance();
            b.push(
                [xs[1], y0, 0.0],
                [xs[1] + WALL, dy - DOOR_W / 2.0, height],
                "wall",
                w,
            );
            b.push(
                [xs[1], dy + DOOR_W / 2.0, 0.0],
                [xs[1] + WALL, y1, height],
                "wall",
                w,
            );
            b.push(
                [xs[1], dy - DOOR_W / 2.0, DOOR_H],
                [xs[1] + WALL, dy + DOOR_W / 2.0, height],
                "wall",
                w,
            );
            // The threshold: floor under the opening.
            let t = b.instance();
            b.push(
                [xs[1], dy - DOOR_W / 2.0, -0.1],
                [xs[1] + WALL, dy + DOOR_W / 2.0, 0.0],
                "floor",
                t,
            );
            // The door leaf stands open, perpendicular to the wall at the opening's edge.
            let d = b.instance();
            b.push(
                [xs[1] + WALL, dy + DOOR_W / 2.0 - 0.04, 0.0],
                [xs[1] + WALL + DOOR_W, dy + DOOR_W / 2.0, DOOR_H],
                "door",
                d,
            );
            doors.push((row, [xs[1] + WALL / 2.0, dy]));
        }
        for (col, &dx) in door_x.iter().enumerate() {
            let (x0, x1) = if col == 0 {
                (0.0, xs[1])
            } else {
                (xs[1] + WALL, x_max)
            };
            let w = b.instance();
            b.push(
                [x0, ys[1], 0.0],
                [dx - DOOR_W / 2.0, ys[1] + WALL, height],
                "wall",
                w,
            );
            b.push(
                [dx + DOOR_W / 2.0, ys[1], 0.0],
                [x1, ys[1] + WALL, height],
                "wall",
                w,
            );
            b.push(
                [dx - DOOR_W / 2.0, ys[1], DOOR_H],
                [dx + DOOR_W / 2.0, ys[1] + WALL, height],
                "wall",
                w,
            );
            let t = b.instance();
            b.push(
                [dx - DOOR_W / 2.0, ys[1], -0.1],
                [dx + DOOR_W / 2.0, ys[1] + WALL, 0.0],
                "floor",
                t,
            );
            let d = b.instance();
            b.push(
                [dx - DOOR_W / 2.0, ys[1] - DOOR_W, 0.0],
                [dx - DOOR_W / 2.0 + 0.04, ys[1], DOOR_H],
                "door",
                d,
            );
            doors.push((2 + col, [dx, ys[1] + WALL / 2.0]));
        }
        // Loop order: room (0,0) → door to (1,0) → (1,0) → door to (1,1) → (1,1) → door to (0,1) → (0,1) → door to (0,0).
        let loop_doors = vec![doors[0].1, doors[3].1, doors[1].1, doors[2].1];
        for r in rooms.clone() {
            furniture::furnish(&mut b, &r, height, (x_max, y_max));
        }
        Self {
            boxes: b.boxes,
            rooms,
            doors: loop_doors,
            height,
            floor: 0.0,
        }
        .shifted(HOUSE_OFFSET)
    }

    /// The same house moved by `offset` metres.
    pub fn shifted(mut self, offset: [f32; 3]) -> Self {
        for b in &mut self.boxes {
            for ((lo, hi), o) in b.min.iter_mut().zip(&mut b.max).zip(offset) {
                *lo += o;
                *hi += o;
            }
        }
        for r in &mut self.rooms {
            for ((lo, hi), o) in r.min.iter_mut().zip(&mut r.max).zip(offset) {
                *lo += o;
                *hi += o;
            }
        }
        for d in &mut self.doors {
            for (v, o) in d.iter_mut().zip(offset) {
                *v += o;
            }
        }
        self.floor += offset[2];
        self
    }

    /// Centre of a room.
    pub fn room_centre(&self, i: usize) -> [f32; 2] {
        let r = &self.rooms[i];
        [(r.min[0] + r.max[0]) / 2.0, (r.min[1] + r.max[1]) / 2.0]
    }

    /// The robot's loop: room centres and the doors between them.
    pub fn waypoints(&self) -> Vec<[f32; 2]> {
        // Rooms are row-major: 0 = (0,0), 1 = (1,0), 2 = (0,1), 3 = (1,1).
        let order = [0usize, 1, 3, 2];
        let mut w = Vec::new();
        for (k, &r) in order.iter().enumerate() {
            w.push(self.room_centre(r));
            w.push(self.doors[k]);
        }
        w
    }
}

/// Which sensor the indoor robot carries.
#[derive(Clone, Copy, Debug)]
pub enum IndoorSensor {
    /// A depth camera.
    Camera(DepthCamera),
    /// A multizone ToF sensor.
    Tof(MultizoneTof),
}

/// How the robot observes the house.
#[derive(Clone, Copy, Debug)]
pub struct IndoorRun {
    /// Seed of the house layout.
    pub layout_seed: u64,
    /// Seed of the pixel subsampling.
    pub seed: u64,
    /// Metres between frames along the loop.
    pub step_m: f32,
    /// The sensor.
    pub sensor: IndoorSensor,
}

impl Default for IndoorRun {
    fn default() -> Self {
        Self {
            layout_seed: 1,
            seed: 1,
            step_m: 0.25,
            sensor: IndoorSensor::Camera(DepthCamera::default()),
        }
    }
}

/// The robot's run through a generated house, with the paper's MP3D map configuration (0.05 m voxels,
/// ℓ = 0.5 m, f = 3).
pub fn sequence(scene: &IndoorScene, run: &IndoorRun) -> Sequence {
    let path = along_polyline(&scene.waypoints(), run.step_m);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(run.seed);
    let frames = path
        .iter()
        .enumerate()
        .map(|(i, (xy, heading))| {
            // Sweep the gaze ±60° around the heading, so walls and furniture beside the path are seen.
            let yaw = heading + 1.05 * (i as f32 * 0.35).sin();
            let pose = camera_pose([xy[0], xy[1], scene.floor + 1.3], yaw, 0.25);
            let points = match run.sensor {
                IndoorSensor::Camera(cam) => cam.capture(scene, &pose, &mut rng),
                IndoorSensor::Tof(tof) => tof.capture(scene, &pose),
            };
            ScanFrame { pose, points }
        })
        .collect();
    Sequence {
        name: "indoor".into(),
        classes: INDOOR_CLASSES.iter().map(|s| s.to_string()).collect(),
        config: MapConfig::new(0.05, 0.5, 3, Prior::default(), KernelMode::VoxelOffset)
            .expect("valid indoor configuration"),
        frames,
        cutaway_height: Some(scene.floor + scene.height - 0.15),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slab_test() {
        let b = Aabb {
            min: [1.0, -1.0, -1.0],
            max: [2.0, 1.0, 1.0],
            class: 0,
            instance: 0,
        };
        assert_eq!(b.hit([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], 10.0), Some(1.0));
        assert_eq!(b.hit([0.0, 0.0, 0.0], [-1.0, 0.0, 0.0], 10.0), None);
        assert_eq!(b.hit([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], 0.5), None);
        assert_eq!(
            b.hit([1.5, 0.0, 0.0], [1.0, 0.0, 0.0], 10.0),
            None,
            "from inside"
        );
        assert_eq!(b.hit([0.0, 5.0, 0.0], [1.0, 0.0, 0.0], 10.0), None);
    }

    #[test]
    fn house_is_seeded_and_furnished() {
        let a = IndoorScene::generate(4);
        assert_eq!(a.boxes, IndoorScene::generate(4).boxes);
        assert_ne!(a.boxes, IndoorScene::generate(5).boxes);
        let classes: std::collections::BTreeSet<u16> = a.boxes.iter().map(|b| b.class).collect();
        for must in [
            "wall", "floor", "ceiling", "door", "window", "table", "chair", "bed", "toilet",
        ] {
            assert!(classes.contains(&class(must)), "{must} missing");
        }
        // The robot's waypoints are inside the house and not inside furniture (floor-level boxes).
        for w in a.waypoints() {
            for b in a.boxes.iter().filter(|b| b.class > 4) {
                let inside = (0..2).all(|k| w[k] > b.min[k] && w[k] < b.max[k])
                    && b.min[2] < a.floor + 1.3
                    && b.max[2] > a.floor + 1.3;
                assert!(
                    !inside,
                    "waypoint {w:?} inside {:?}",
                    INDOOR_CLASSES[b.class as usize]
                );
            }
        }
    }
}
