//! What every explorer knows before it starts: where the robot can drive, how far apart two places are,
//! and which voxels each candidate view would see.
//!
//! The explorers compare *choices* of views, not mapping of geometry: all three know the house's floor plan
//! and surfaces (as a robot with a geometric SLAM map would) and learn only the semantics. A candidate view
//! is a free place on a 0.5 m lattice and one of eight headings; its predicted view is a coarse grid of the
//! camera's rays cast against the surfaces, turned into the kernel weight each voxel would receive
//! ([`Footprint`]) with the map's own kernel table.

use crate::sim::indoor::IndoorScene;
use crate::sim::sensor::{DepthCamera, RayScene};
use crate::sim::trajectory::camera_pose;
use latentbki::batch::spread;
use latentbki::nalgebra::{Isometry3, Vector3};
use latentbki::{kernel::KernelLut, key::VoxelKey, MapConfig};
use rustc_hash::FxHashMap;
use std::collections::BinaryHeap;

/// Navigation grid cell size, metres.
pub const CELL: f32 = 0.25;
/// The robot's radius, metres: a cell is free if nothing stands within it.
const RADIUS: f32 = 0.2;
/// Heights (above the floor) the robot's body occupies.
const BODY: (f32, f32) = (0.1, 1.5);
/// Camera height above the floor, and its downward pitch (those of the scripted loop).
pub const CAMERA_HEIGHT: f32 = 1.3;
const PITCH: f32 = 0.25;
/// Candidate places: every `LATTICE`-th free cell per axis (0.5 m).
const LATTICE: usize = 2;
/// Headings per candidate place.
pub const HEADINGS: usize = 8;
/// Rays per predicted view (a 24 × 18 grid over the camera's field of view). Each ray deposits its share of
/// the frame's points in the voxel it hits, so the grid must be fine enough that a view's footprint grows
/// with the surface it covers: with 12 × 9 rays every ray of a view onto unseen surface fell in a voxel of
/// its own and every such view scored the same (≈ 108 × 27 voxels at the unseen gain), whatever it covered,
/// and information gain degenerated into "the nearest view onto anything unseen" (docs/numbers.md).
pub const RAYS: (u32, u32) = (24, 18);

/// A candidate view: a place and a heading.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Viewpoint {
    /// Grid cell index of the place.
    pub cell: usize,
    /// Heading, radians.
    pub yaw: f32,
}

/// Kernel weight per voxel a view would deposit, sorted by key; and the voxels its rays hit.
#[derive(Clone, Debug, Default)]
pub struct Footprint {
    /// (voxel, kernel weight it would receive).
    pub weights: Vec<(VoxelKey, f32)>,
    /// The voxels the predicted points fall in.
    pub hits: Vec<VoxelKey>,
    /// `weights` with each voxel as its slot in [`World::slots`] (scoring reads an array, not a hash map).
    pub slot_weights: Vec<(u32, f32)>,
    /// `hits` as slots.
    pub hit_slots: Vec<u32>,
}

/// The house as the explorers see it.
pub struct World {
    /// The scene (ray casting for the real sensor and the predictions).
    pub scene: IndoorScene,
    origin: [f32; 2],
    dims: [usize; 2],
    free: Vec<bool>,
    /// Candidate views and what each would see.
    pub views: Vec<(Viewpoint, Footprint)>,
    /// A dense index of every voxel some candidate view would reach.
    pub slots: FxHashMap<VoxelKey, u32>,
    /// By slot: whether some candidate view's rays hit the voxel (it holds a surface the views can see).
    pub surface: Vec<bool>,
}

impl World {
    /// Build the grid and every candidate's footprint; `pixels` is the real camera's pixels per frame (the
    /// predicted rays stand for that many points).
    pub fn new(scene: IndoorScene, config: &MapConfig, pixels: usize) -> anyhow::Result<Self> {
        let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
        for r in &scene.rooms {
            for a in 0..2 {
                lo[a] = lo[a].min(r.min[a]);
                hi[a] = hi[a].max(r.max[a]);
            }
        }
        let dims = [
            ((hi[0] - lo[0]) / CELL).ceil() as usize + 1,
            ((hi[1] - lo[1]) / CELL).ceil() as usize + 1,
        ];
        let (z0, z1) = (scene.floor + BODY.0, scene.floor + BODY.1);
        let mut free = vec![false; dims[0] * dims[1]];
        for (i, f) in free.iter_mut().enumerate() {
            let c = [
                lo[0] + (i % dims[0]) as f32 * CELL,
                lo[1] + (i / dims[0]) as f32 * CELL,
            ];
            let inside = scene
                .rooms
                .iter()
                .any(|r| (0..2).all(|a| c[a] > r.min[a] - 0.3 && c[a] < r.max[a] + 0.3));
            let blocked = scene.boxes.iter().any(|b| {
                (0..2).all(|a| c[a] + RADIUS > b.min[a] && c[a] - RADIUS < b.max[a])
                    && b.max[2] > z0
                    && b.min[2] < z1
            });
            *f = inside && !blocked;
        }
        let lut: KernelLut = KernelLut::new(config)?;
        let mut world = Self {
            scene,
            origin: lo,
            dims,
            free,
            views: Vec::new(),
            slots: FxHashMap::default(),
            surface: Vec::new(),
        };
        let camera = DepthCamera {
            pixels_per_frame: pixels,
            ..DepthCamera::default()
        };
        let per_ray = pixels as f32 / (RAYS.0 * RAYS.1) as f32;
        for cell in 0..world.free.len() {
            let (x, y) = (cell % dims[0], cell / dims[0]);
            if !world.free[cell] || x % LATTICE != 0 || y % LATTICE != 0 {
                continue;
            }
            for h in 0..HEADINGS {
                let view = Viewpoint {
                    cell,
                    yaw: h as f32 * std::f32::consts::TAU / HEADINGS as f32,
                };
                let points = world.predicted_points(&world.pose(view), &camera, RAYS);
                let fp = footprint(&lut, &points, per_ray);
                if !fp.hits.is_empty() {
                    world.views.push((view, fp));
                }
            }
        }
        let mut slots = FxHashMap::default();
        for (_, fp) in &mut world.views {
            let mut slot = |k: VoxelKey| {
                let n = slots.len() as u32;
                *slots.entry(k).or_insert(n)
            };
            fp.slot_weights = fp.weights.iter().map(|&(k, w)| (slot(k), w)).collect();
            fp.hit_slots = fp.hits.iter().map(|&k| slot(k)).collect();
        }
        world.surface = vec![false; slots.len()];
        for (_, fp) in &world.views {
            for &s in &fp.hit_slots {
                world.surface[s as usize] = true;
            }
        }
        world.slots = slots;
        Ok(world)
    }

    /// Centre of a cell (xy).
    pub fn centre(&self, cell: usize) -> [f32; 2] {
        [
            self.origin[0] + (cell % self.dims[0]) as f32 * CELL,
            self.origin[1] + (cell / self.dims[0]) as f32 * CELL,
        ]
    }

    /// The free cell nearest to a position.
    pub fn nearest_free(&self, p: [f32; 2]) -> Option<usize> {
        (0..self.free.len())
            .filter(|&c| self.free[c])
            .min_by(|&a, &b| {
                let d = |c: usize| {
                    let q = self.centre(c);
                    (q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2)
                };
                d(a).total_cmp(&d(b))
            })
    }

    /// The camera pose of a view.
    pub fn pose(&self, view: Viewpoint) -> Isometry3<f32> {
        let c = self.centre(view.cell);
        camera_pose(
            [c[0], c[1], self.scene.floor + CAMERA_HEIGHT],
            view.yaw,
            PITCH,
        )
    }

    /// Driving distances from `from` to every cell (8-connected grid; `f32::INFINITY` where unreachable),
    /// and each cell's predecessor on a shortest path.
    pub fn distances(&self, from: usize) -> (Vec<f32>, Vec<usize>) {
        let n = self.free.len();
        let mut dist = vec![f32::INFINITY; n];
        let mut prev = vec![usize::MAX; n];
        let mut heap = BinaryHeap::new();
        dist[from] = 0.0;
        // Distances in millimetres as integers: a total order for the heap.
        heap.push(std::cmp::Reverse((0u64, from)));
        let (w, h) = (self.dims[0] as i64, self.dims[1] as i64);
        while let Some(std::cmp::Reverse((d_mm, c))) = heap.pop() {
            if d_mm as f32 / 1000.0 > dist[c] + 1e-6 {
                continue;
            }
            let (x, y) = ((c % self.dims[0]) as i64, (c / self.dims[0]) as i64);
            for (dx, dy) in [
                (1, 0),
                (-1, 0),
                (0, 1),
                (0, -1),
                (1, 1),
                (1, -1),
                (-1, 1),
                (-1, -1),
            ] {
                let (nx, ny) = (x + dx, y + dy);
                if nx < 0 || ny < 0 || nx >= w || ny >= h {
                    continue;
                }
                let nc = (ny * w + nx) as usize;
                // Diagonal moves only where both straight neighbours are free (no corner cutting).
                let corner_ok = dx == 0
                    || dy == 0
                    || (self.free[(y * w + nx) as usize] && self.free[(ny * w + x) as usize]);
                if !self.free[nc] || !corner_ok {
                    continue;
                }
                let step = if dx != 0 && dy != 0 {
                    CELL * std::f32::consts::SQRT_2
                } else {
                    CELL
                };
                let nd = dist[c] + step;
                if nd < dist[nc] - 1e-6 {
                    dist[nc] = nd;
                    prev[nc] = c;
                    heap.push(std::cmp::Reverse(((nd * 1000.0) as u64, nc)));
                }
            }
        }
        (dist, prev)
    }

    /// The cells of the shortest path to `to` (from the origin of `prev`), start excluded, in order.
    pub fn path(prev: &[usize], to: usize) -> Vec<usize> {
        let mut cells = Vec::new();
        let mut c = to;
        while prev[c] != usize::MAX {
            cells.push(c);
            c = prev[c];
        }
        cells.reverse();
        cells
    }

    /// The points a view is predicted to see (the explorers' ray grid cast against the surfaces), map frame.
    pub fn predicted(&self, view: Viewpoint) -> Vec<[f32; 3]> {
        self.predicted_grid(view, RAYS)
    }

    /// The same with another grid of (columns, rows) rays (the view-score benchmark also scores the earlier
    /// 12 × 9, to show how the cost grows with the voxels a view reaches).
    pub fn predicted_grid(&self, view: Viewpoint, rays: (u32, u32)) -> Vec<[f32; 3]> {
        self.predicted_points(&self.pose(view), &DepthCamera::default(), rays)
    }

    fn predicted_points(
        &self,
        pose: &Isometry3<f32>,
        camera: &DepthCamera,
        rays: (u32, u32),
    ) -> Vec<[f32; 3]> {
        let fx = (camera.hfov_deg.to_radians() / 2.0).tan();
        let fy = fx * camera.height as f32 / camera.width as f32;
        let mut out = Vec::new();
        for j in 0..rays.1 {
            for i in 0..rays.0 {
                let u = ((i as f32 + 0.5) / rays.0 as f32 * 2.0 - 1.0) * fx;
                let v = ((j as f32 + 0.5) / rays.1 as f32 * 2.0 - 1.0) * fy;
                let ray = Vector3::new(u, v, 1.0);
                let len = ray.norm();
                let d = pose.rotation * (ray / len);
                let o = pose.translation.vector;
                if let Some((t, _, _)) =
                    self.scene
                        .cast([o.x, o.y, o.z], [d.x, d.y, d.z], camera.max_depth * len)
                {
                    let depth = t / len;
                    if depth >= camera.min_depth {
                        let p = o + d * t;
                        out.push([p.x, p.y, p.z]);
                    }
                }
            }
        }
        out
    }
}

/// The kernel weight each voxel would receive from `points`, each standing for `per_point` real points.
pub fn footprint(lut: &KernelLut, points: &[[f32; 3]], per_point: f32) -> Footprint {
    let mut weights: FxHashMap<VoxelKey, f32> = FxHashMap::default();
    let mut hits = Vec::new();
    for p in points {
        let Ok(key) = VoxelKey::from_position(*p, lut.inv_voxel_size()) else {
            continue;
        };
        hits.push(key);
        spread(lut, key, 0, |t, k| {
            *weights.entry(t).or_default() += k * per_point
        });
    }
    hits.sort_unstable();
    hits.dedup();
    let mut weights: Vec<(VoxelKey, f32)> = weights.into_iter().collect();
    weights.sort_unstable_by_key(|(k, _)| *k);
    Footprint {
        weights,
        hits,
        ..Footprint::default()
    }
}
