//! Exploration: a robot that chooses where to look next by information gain, against random choice and
//! nearest-frontier choice, in the procedural house.
//!
//! Why: the paper motivates its uncertainty by active perception but only reports it. Here the map's own
//! posterior picks the next view: a candidate's score is the expected entropy drop of the voxels it would
//! see ([`latentbki::info_gain`]), per metre of driving to it. The comparison is fair by construction:
//!
//! - the same house, start, camera (3072 of 640 × 480 pixels, 70°, 0.1–6 m), encoder noise model, PCA and
//!   codebook for every explorer; seeds fixed, and each seed's house run by all three;
//! - the same candidate views (0.5 m lattice × 8 headings, [`world`]) and the same geometric knowledge (all
//!   know the surfaces; they learn the semantics);
//! - the same budget of driving distance, and the same sensing along the way: a frame every 0.5 m of the
//!   path (looking where it drives) and one at each chosen view.
//!
//! **Nearest frontier** goes to the nearest view of which at least a fifth of the surface voxels it would
//! hit have no point within the kernel's reach yet (the classic frontier: the edge of the known map).
//! **Random** takes any candidate within the remaining budget. **Information gain** takes the candidate of
//! highest score / (path + 3 m), or with `--horizon N` the first stop of the best tour of N views
//! (`tour.rs`). Other designs, measured and not the default (docs/numbers.md): `--discount` (score ·
//! e^(−λ·path)), `--replan` (choose again at every frame on the way), `--rooms` (`rooms.rs`), `--surface`
//! (score surface voxels only).
//!
//! Accuracy and mIoU are those of the tables, on a fixed set of ground-truth voxels: every surface voxel the
//! scripted loop of `eval --scene indoor` sees (majority class; a fixed quarter of them, spread evenly); a
//! voxel the map cannot answer is wrong.

mod rooms;
mod tour;
mod truth;
pub mod world;

pub use truth::Truth;

use crate::eval::experiment::Decoding;
use crate::eval::methods::D;
use crate::sim::sensor::DepthCamera;
use crate::sim::{mix_all, LabelledPoint};
use crate::ObsMap;
use anyhow::{Context, Result};
use latentbki::batch::spread;
use latentbki::nalgebra::Isometry3;
use latentbki::{info_gain::voxel_gain, kernel::KernelLut, key::VoxelKey, MapConfig};
use rand_xoshiro::rand_core::{RngCore, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use rustc_hash::FxHashMap;
use world::{Viewpoint, World};

/// How the next view is chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Planner {
    /// Highest information gain per metre.
    InformationGain,
    /// Any view within the budget.
    Random,
    /// The nearest view onto unknown surface.
    NearestFrontier,
}

impl Planner {
    /// All three, in table order.
    pub const ALL: [Planner; 3] = [Self::InformationGain, Self::Random, Self::NearestFrontier];
    /// Name for tables and the plot.
    pub fn name(self) -> &'static str {
        match self {
            Self::InformationGain => "information gain",
            Self::Random => "random",
            Self::NearestFrontier => "nearest frontier",
        }
    }
}

/// Metres added to the path length in the information-gain utility (a view next to the robot is not free):
/// the default of `--utility-offset`. Chosen on houses 1–6, seeds 1–3, with views predicted by 24 × 18 rays
/// (share of random's distance at 1.5 / 2.5 / 3 / 4 m: goal met on 3 / 5 / 4 / 4 of the 6 houses, but at
/// 2.5 m not on house 1, 0.7 points behind nearest-frontier; 3 m: 55 % there, 6 points ahead).
pub const UTILITY_OFFSET_M: f32 = 3.0;
/// A view is a frontier if at least this share of the voxels it would hit are unknown.
const FRONTIER_SHARE: f32 = 0.2;

/// Information gain's utility of a view of `score` at `path` metres of driving: score / (path + offset), or
/// with a distance discount (> 0, per metre) score · e^(−discount · path) (Bircher et al. 2016).
pub fn utility(score: f32, path: f32, offset: f32, discount: f32) -> f32 {
    if discount > 0.0 {
        score * (-discount * path).exp()
    } else {
        score / (path + offset)
    }
}

/// One measurement along a run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// Metres driven so far.
    pub distance: f32,
    /// Share of the ground-truth voxels labelled correctly.
    pub accuracy: f64,
    /// Mean IoU over the classes present.
    pub miou: f64,
    /// Frames integrated so far.
    pub frames: u32,
}

/// One robot's run: its map, what it knows of each voxel's confidence, and its odometer.
struct Robot<'a> {
    world: &'a World,
    dec: &'a Decoding,
    lut: KernelLut,
    prior_lambda: f32,
    camera: DepthCamera,
    map: ObsMap<D>,
    /// Kernel-weighted point count per voxel (the gathered λ above the prior), kept as frames arrive.
    counts: FxHashMap<VoxelKey, f32>,
    /// The same, by the world's voxel slots (what scoring reads).
    seen: Vec<f32>,
    rng: Xoshiro256PlusPlus,
    frame: u32,
    travelled: f32,
    utility_offset: f32,
    discount: f32,
    horizon: usize,
    rooms: bool,
    surface_only: bool,
}

impl Robot<'_> {
    fn utility(&self, score: f32, path: f32) -> f32 {
        utility(score, path, self.utility_offset, self.discount)
    }

    fn capture(&mut self, pose: &Isometry3<f32>) {
        let points: Vec<LabelledPoint> =
            self.camera.capture(&self.world.scene, pose, &mut self.rng);
        let features = self.dec.encoder.encode_compressed(
            &points,
            self.frame,
            &self.dec.projected,
            &mut self.rng,
        );
        let positions: Vec<[f32; 3]> = points.iter().map(|p| p.position).collect();
        self.map
            .integrate(&Isometry3::identity(), &positions, &features);
        for p in &positions {
            if let Ok(k) = VoxelKey::from_position(*p, self.lut.inv_voxel_size()) {
                spread(&self.lut, k, 0, |t, w| {
                    *self.counts.entry(t).or_default() += w;
                    if let Some(&s) = self.world.slots.get(&t) {
                        self.seen[s as usize] += w;
                    }
                });
            }
        }
        self.frame += 1;
    }

    fn lambda(&self, key: VoxelKey) -> f32 {
        self.prior_lambda + self.counts.get(&key).copied().unwrap_or(0.0)
    }

    /// The information-gain score of a candidate: Σ gain(λ, w) over its footprint.
    fn score(&self, fp: &world::Footprint) -> f32 {
        fp.slot_weights
            .iter()
            .filter(|&&(s, _)| !self.surface_only || self.world.surface[s as usize])
            .map(|&(s, w)| voxel_gain(self.prior_lambda + self.seen[s as usize], w))
            .sum()
    }

    fn unknown_share(&self, fp: &world::Footprint) -> f32 {
        let unknown = fp
            .hit_slots
            .iter()
            .filter(|&&s| self.seen[s as usize] < 0.5)
            .count();
        unknown as f32 / fp.hits.len().max(1) as f32
    }

    fn choose(
        &mut self,
        planner: Planner,
        dist: &[f32],
        here: usize,
        budget: f32,
    ) -> Option<Viewpoint> {
        let left = budget - self.travelled;
        let options: Vec<(Viewpoint, &world::Footprint, f32)> = self
            .world
            .views
            .iter()
            .filter(|(v, _)| v.cell != here && dist[v.cell] <= left)
            .map(|(v, fp)| (*v, fp, dist[v.cell]))
            .collect();
        if options.is_empty() {
            return None;
        }
        let best_by = |key: &dyn Fn(&(Viewpoint, &world::Footprint, f32)) -> f32| {
            options
                .iter()
                .max_by(|a, b| key(a).total_cmp(&key(b)))
                .map(|o| o.0)
        };
        match planner {
            Planner::Random => {
                Some(options[(self.rng.next_u64() % options.len() as u64) as usize].0)
            }
            Planner::InformationGain if self.rooms => self.choose_room_tour(&options),
            Planner::InformationGain if self.horizon > 1 => self.choose_tour(&options, left),
            Planner::InformationGain => best_by(&|(_, fp, d)| self.utility(self.score(fp), *d)),
            Planner::NearestFrontier => {
                let frontier = options
                    .iter()
                    .map(|o| (o, self.unknown_share(o.1)))
                    .filter(|(_, u)| *u >= FRONTIER_SHARE)
                    .min_by(|a, b| a.0 .2.total_cmp(&b.0 .2).then(b.1.total_cmp(&a.1)))
                    .map(|(o, _)| o.0);
                // No frontier left: the view onto the most unknown surface, nearest first.
                frontier.or_else(|| best_by(&|(_, fp, d)| self.unknown_share(fp) - 1e-3 * d))
            }
        }
    }
}

/// One explorer's settings.
#[derive(Clone, Copy, Debug)]
pub struct Explorer {
    /// How it chooses.
    pub planner: Planner,
    /// Seed of its camera sampling and random choices.
    pub seed: u64,
    /// Metres it may drive.
    pub budget: f32,
    /// Information gain's utility: score / (path + this many metres).
    pub utility_offset: f32,
    /// Information gain's distance discount per metre: utility score · e^(−discount · path) instead of
    /// score / (path + offset) (0: off).
    pub discount: f32,
    /// Information gain plans tours of this many views (1: the best single view).
    pub horizon: usize,
    /// Information gain chooses again at every frame on the way (not only on arrival).
    pub replan: bool,
    /// Information gain takes the best view in the first room of the best tour of rooms (`rooms.rs`).
    pub rooms: bool,
    /// Information gain scores only voxels that hold a surface some candidate view sees.
    pub surface_only: bool,
}

/// Run one explorer until its distance budget is spent; the accuracy after every frame (those along the
/// paths too: every explorer is measured as often per metre).
pub fn run(
    world: &World,
    dec: &Decoding,
    truth: &Truth,
    config: &MapConfig,
    explorer: &Explorer,
) -> Result<Vec<Sample>> {
    let Explorer {
        planner,
        seed,
        budget,
        utility_offset,
        discount,
        horizon,
        replan,
        rooms,
        surface_only,
    } = *explorer;
    let replan = replan && planner == Planner::InformationGain;
    let mut robot = Robot {
        world,
        dec,
        lut: KernelLut::new(config)?,
        prior_lambda: config.prior().lambda,
        camera: DepthCamera::default(),
        map: ObsMap::new(*config)?,
        counts: FxHashMap::default(),
        seen: vec![0.0; world.slots.len()],
        rng: Xoshiro256PlusPlus::seed_from_u64(mix_all(&[seed, 0xE7F1])),
        frame: 0,
        travelled: 0.0,
        utility_offset,
        discount,
        horizon,
        rooms,
        surface_only,
    };
    let mut here = world
        .nearest_free(world.scene.room_centre(0))
        .context("the house has no free cell")?;
    let measure = |robot: &Robot| {
        let (accuracy, miou) = truth.score(&robot.map, &dec.decoder);
        Sample {
            distance: robot.travelled,
            accuracy,
            miou,
            frames: robot.frame,
        }
    };
    robot.capture(&world.pose(Viewpoint {
        cell: here,
        yaw: 0.0,
    }));
    let mut samples = vec![measure(&robot)];
    'choice: loop {
        let (dist, prev) = world.distances(here);
        let Some(goal) = robot.choose(planner, &dist, here, budget) else {
            break;
        };
        let path = World::path(&prev, goal.cell);
        let mut from = world.centre(here);
        for (i, &c) in path.iter().enumerate() {
            let to = world.centre(c);
            robot.travelled += ((to[0] - from[0]).powi(2) + (to[1] - from[1]).powi(2)).sqrt();
            if i % 2 == 1 && c != goal.cell {
                let yaw = (to[1] - from[1]).atan2(to[0] - from[0]);
                robot.capture(&world.pose(Viewpoint { cell: c, yaw }));
                samples.push(measure(&robot));
                if replan {
                    here = c;
                    continue 'choice;
                }
            }
            from = to;
        }
        robot.capture(&world.pose(goal));
        here = goal.cell;
        samples.push(measure(&robot));
    }
    Ok(samples)
}

/// The mean over runs of "accuracy (or mIoU) after the last view within d metres", on a grid of d.
pub fn mean_curve(runs: &[Vec<Sample>], grid: &[f32], get: fn(&Sample) -> f64) -> Vec<f64> {
    grid.iter()
        .map(|&d| {
            let sum: f64 = runs
                .iter()
                .map(|r| {
                    r.iter()
                        .take_while(|s| s.distance <= d + 1e-4)
                        .last()
                        .map_or(0.0, get)
                })
                .sum();
            sum / runs.len().max(1) as f64
        })
        .collect()
}
