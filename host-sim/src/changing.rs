//! A house whose furniture changes class mid-run, mapped with and without forgetting
//! ([`latentbki::forget`]); `host-sim eval --scene changing` runs it.
//!
//! Why this scene: a static map keeps voting for what a place *was*. The robot drives the scripted loop of
//! the house; after three loops every piece of furniture in the first room the loop visits (where the
//! second loop starts) takes another class (a table becomes a chair, …: geometry unchanged, labels
//! swapped); it keeps looping the changed house. The clock ticks once per frame; the half-life is four
//! loops unless given (shorter ones relearn in fewer frames but forget more of what did not change: the
//! README's table).
//!
//! Reported two half-lives after the change, on the ground-truth voxels of the house (every surface voxel
//! the loop sees, majority class, as `explore`): the changed region (voxels whose class changed) with
//! forgetting and in a map built only from the post-change frames, and the unchanged rest with and without
//! forgetting. A voxel the map cannot answer counts as wrong.

use crate::eval::experiment::{decoding, ExperimentSettings};
use crate::eval::methods::D;
use crate::explore::Truth;
use crate::sim::indoor::{self, IndoorRun, IndoorScene, INDOOR_CLASSES};
use crate::sim::sensor::DepthCamera;
use crate::sim::vocab::TextEmbeddings;
use crate::sim::{mix_all, Sequence};
use crate::ObsMap;
use anyhow::{ensure, Result};
use latentbki::forget::Forgetting;
use latentbki::nalgebra::Isometry3;
use rand_xoshiro::rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

/// Loops of the house before the change: a map with a history.
const LOOPS_BEFORE: usize = 3;

/// Classes that are not furniture (walls, floor, ceiling, door, window) keep theirs.
const FIXED_CLASSES: u16 = 5;

/// The house after the change: furniture in room `room` takes the next-but-six furniture class.
pub fn changed(scene: &IndoorScene, room: usize) -> IndoorScene {
    let mut after = scene.clone();
    let r = scene.rooms[room];
    let furniture = INDOOR_CLASSES.len() as u16 - FIXED_CLASSES;
    for b in &mut after.boxes {
        let centre = [(b.min[0] + b.max[0]) / 2.0, (b.min[1] + b.max[1]) / 2.0];
        let inside = (0..2).all(|a| centre[a] > r.min[a] && centre[a] < r.max[a]);
        if inside && b.class >= FIXED_CLASSES {
            b.class = FIXED_CLASSES + (b.class - FIXED_CLASSES + 7) % furniture;
        }
    }
    after
}

/// What the run measured.
#[derive(Clone, Copy, Debug)]
pub struct Outcome {
    /// Changed region, forgetting map.
    pub changed: f64,
    /// Changed region, map of the post-change frames only.
    pub changed_post_only: f64,
    /// Unchanged region, forgetting map.
    pub unchanged: f64,
    /// Unchanged region, map without forgetting.
    pub unchanged_static: f64,
    /// Changed region, map without forgetting.
    pub changed_static: f64,
    /// Ground-truth voxels changed / unchanged.
    pub regions: (usize, usize),
    /// Frames per loop and the half-life, in frames.
    pub loop_frames: usize,
    /// The half-life used, frames.
    pub half_life: u32,
}

/// Run three loops before the change and loops after it until two half-lives have passed; `half_life` in
/// frames (default four loops).
pub fn run(layout_seed: u64, seed: u64, pixels: usize, half_life: Option<u32>) -> Result<Outcome> {
    let before = IndoorScene::generate(layout_seed);
    let after = changed(&before, 0);
    let camera = IndoorRun {
        layout_seed,
        seed,
        sensor: indoor::IndoorSensor::Camera(DepthCamera {
            pixels_per_frame: pixels,
            ..DepthCamera::default()
        }),
        ..IndoorRun::default()
    };
    let first = indoor::sequence(&before, &camera);
    let before_frames: Vec<_> = (0..LOOPS_BEFORE as u64)
        .flat_map(|i| {
            indoor::sequence(
                &before,
                &IndoorRun {
                    seed: mix_all(&[seed, 100 + i]),
                    ..camera
                },
            )
            .frames
        })
        .collect();
    let config = first.config;
    let loop_frames = first.frames.len();
    let half_life = half_life.unwrap_or(4 * loop_frames as u32);
    ensure!(half_life > 0, "--half-life must be at least one frame");
    // After the change, loops of the changed house (each with its own pixel sampling) for 2 half-lives.
    let loops_after = (2 * half_life as usize).div_ceil(loop_frames);
    let after_frames: Vec<_> = (0..loops_after as u64)
        .flat_map(|i| {
            indoor::sequence(
                &after,
                &IndoorRun {
                    seed: mix_all(&[seed, 2 + i]),
                    ..camera
                },
            )
            .frames
        })
        .collect();
    let forgetting = Forgetting::new(half_life as f32).expect("positive half-life");

    let training = IndoorScene::generate(mix_all(&[layout_seed, 0x7EA1]));
    let train: Sequence = indoor::sequence(
        &training,
        &IndoorRun {
            seed: mix_all(&[seed, 0x7EA1]),
            ..camera
        },
    );
    let setup = ExperimentSettings {
        seed,
        ..ExperimentSettings::default()
    };
    let dec = decoding(&TextEmbeddings::builtin(), &train, &setup)?;

    // Ground truth after the change, split by whether the class changed.
    let truth_before = Truth::from_loop(&before, &config);
    let truth_after = Truth::from_loop(&after, &config);
    let (changed_truth, unchanged_truth) = truth_after.split(&truth_before);
    ensure!(
        !changed_truth.is_empty(),
        "the change touched no ground-truth voxel (layout seed {layout_seed})"
    );

    let mut forgetful = ObsMap::<D>::new(config)?;
    forgetful.set_forgetting(Some(forgetting));
    let mut plain = ObsMap::<D>::new(config)?;
    let mut post_only = ObsMap::<D>::new(config)?;
    let change = before_frames.len();
    let until = change + 2 * half_life as usize;
    let frames = before_frames.iter().chain(&after_frames).take(until);
    for (t, f) in frames.enumerate() {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(mix_all(&[seed, t as u64, 0xC4A]));
        let features = dec
            .encoder
            .encode_compressed(&f.points, t as u32, &dec.projected, &mut rng);
        let positions: Vec<[f32; 3]> = f.points.iter().map(|p| p.position).collect();
        let id = Isometry3::identity();
        forgetful.set_time(t as u32);
        forgetful.integrate(&id, &positions, &features);
        plain.integrate(&id, &positions, &features);
        if t >= change {
            post_only.integrate(&id, &positions, &features);
        }
    }
    let acc = |truth: &Truth, map: &ObsMap<D>| truth.score(map, &dec.decoder).0;
    Ok(Outcome {
        changed: acc(&changed_truth, &forgetful),
        changed_post_only: acc(&changed_truth, &post_only),
        unchanged: acc(&unchanged_truth, &forgetful),
        unchanged_static: acc(&unchanged_truth, &plain),
        changed_static: acc(&changed_truth, &plain),
        regions: (changed_truth.len(), unchanged_truth.len()),
        loop_frames,
        half_life,
    })
}

/// Print the headline and its context.
pub fn report(o: &Outcome) {
    println!(
        "changing house: {} frames per loop, change after loop 3, half-life {} frames, measured 2 half-lives after the change; {} changed / {} unchanged ground-truth voxels; changed region without forgetting {:.1} %",
        o.loop_frames,
        o.half_life,
        o.regions.0,
        o.regions.1,
        100.0 * o.changed_static
    );
    println!(
        "forgetting: changed region {:.1} % (post-change map {:.1} %), unchanged region {:.1} % (without forgetting {:.1} %)",
        100.0 * o.changed,
        100.0 * o.changed_post_only,
        100.0 * o.unchanged,
        100.0 * o.unchanged_static
    );
}
