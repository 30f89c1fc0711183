//! Shared by the streaming tests: a labelled outdoor scene, real text embeddings folded through a PCA of
//! them, and robots that run the firmware's own `Mapper` (map, encoder, live updates), with a tap on what
//! they hand to the link.
#![allow(dead_code)]

use host_sim::base_station::{BaseStation, VOCAB_CAP};
use host_sim::link::{ByteLog, SplitMix};
use host_sim::{ObsMap, ReferenceMap};
use latentbki::frame::EncoderSettings;
use latentbki::nalgebra::{Isometry3, Translation3};
use latentbki::wire::{feature_space_id, SessionConfig, SummaryCodec};
use latentbki::{
    decode::Codebook, decode::Pca, frame::FrameEncoder, key::VoxelKey, local_map::LocalMap,
    obs::ObsStats, packed_len, sink::Evicted, stats::VoxelStats, MapConfig, Mapper, Setup,
};

pub use host_sim::sim::vocab::D;
pub const F: usize = 384;
pub const P: usize = packed_len(D);
pub const CAP: usize = 12_000;
/// Queue bytes and frame size of the robot's encoder.
pub const QB: usize = 16 * 1024;
pub const N: usize = 512;
pub type Encoder = FrameEncoder<D, QB, N>;
pub type Robot = Mapper<D, CAP, P, QB, N>;

/// The 12 ASPRS class phrases and their 384-d embeddings (host-sim/data/text-embeddings.tsv).
pub fn embeddings() -> (Vec<String>, Vec<[f32; F]>) {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/data/text-embeddings.tsv"
    ))
    .unwrap();
    let mut names = Vec::new();
    let mut vecs = Vec::new();
    for line in text.lines().filter(|l| !l.starts_with('#')) {
        let (name, rest) = line.split_once('\t').unwrap();
        let v: Vec<f32> = rest
            .split_whitespace()
            .map(|x| x.parse().unwrap())
            .collect();
        names.push(name.to_string());
        vecs.push(<[f32; F]>::try_from(v).unwrap());
    }
    (names, vecs)
}

/// A PCA whose first components span the embeddings (Gram–Schmidt of the centred embeddings), completed
/// with random orthonormal directions: features of the scene's classes survive compression exactly.
pub fn pca(all: &[[f32; F]]) -> Box<Pca<D, F>> {
    let mut mean = [0.0f32; F];
    for e in all {
        for (m, v) in mean.iter_mut().zip(e) {
            *m += v / all.len() as f32;
        }
    }
    let mut rng = SplitMix::new(77);
    let mut rows: Vec<[f64; F]> = Vec::new();
    let candidates = all
        .iter()
        .map(|e| core::array::from_fn(|i| f64::from(e[i] - mean[i])))
        .chain(std::iter::repeat_with(|| {
            core::array::from_fn(|_| rng.unit() - 0.5)
        }));
    for mut v in candidates {
        if rows.len() == D {
            break;
        }
        for _ in 0..2 {
            for r in &rows {
                let d: f64 = v.iter().zip(r).map(|(a, b)| a * b).sum();
                v.iter_mut().zip(r).for_each(|(a, b)| *a -= d * b);
            }
        }
        let n = v.iter().map(|a| a * a).sum::<f64>().sqrt();
        if n > 1e-3 {
            rows.push(v.map(|a| a / n));
        }
    }
    let mut p = Box::new(Pca {
        mean,
        components: [[0.0; F]; D],
    });
    for (d, r) in rows.iter().enumerate() {
        p.components[d] = r.map(|a| a as f32);
    }
    p
}

/// Scene classes (indices into the ASPRS vocabulary).
pub const GROUND: usize = 1;
pub const LOW_VEG: usize = 2;
pub const HIGH_VEG: usize = 4;
pub const BUILDING: usize = 5;
pub const ROAD: usize = 9;

pub struct World {
    pub names: Vec<String>,
    pub pca: Box<Pca<D, F>>,
    pub class_features: Vec<[f32; D]>,
    pub vocab: Codebook<D, VOCAB_CAP>,
    pub config: SessionConfig,
}

impl World {
    pub fn new(codec: SummaryCodec) -> Self {
        let (names, all) = embeddings();
        let pca = pca(&all);
        let asprs = &all[..12];
        let vocab = Codebook::from_pca(&pca, asprs).unwrap();
        let class_features = asprs.iter().map(|e| pca.project(e)).collect();
        let config = SessionConfig::new(&MapConfig::default(), D, codec, feature_space_id(&pca));
        Self {
            names: names[..12].to_vec(),
            pca,
            class_features,
            vocab,
            config,
        }
    }
}

/// The class of the surface at (x, y): a road along y = 0, a building block, trees, grass, ground.
pub fn class_at(x: f32, y: f32) -> usize {
    if y.abs() < 0.8 {
        ROAD
    } else if (3.0..5.0).contains(&x) && y > 1.5 {
        BUILDING
    } else if ((x - 8.0).powi(2) + (y + 2.0).powi(2)) < 1.0 {
        HIGH_VEG
    } else if y < -1.2 {
        LOW_VEG
    } else {
        GROUND
    }
}

/// One scan around (cx, cy): `n` points within `radius`, on the ground and on the building's and trees'
/// vertical surfaces, each with its class feature plus noise. Points are returned in the sensor frame.
pub fn scan(
    world: &World,
    rng: &mut SplitMix,
    cx: f32,
    cy: f32,
    n: usize,
    radius: f32,
) -> (Isometry3<f32>, Vec<[f32; 3]>, Vec<[f32; D]>) {
    let pose = Isometry3::from_parts(Translation3::new(cx, cy, 0.0), Default::default());
    let mut pts = Vec::with_capacity(n);
    let mut feats = Vec::with_capacity(n);
    while pts.len() < n {
        let a = rng.unit() as f32 * std::f32::consts::TAU;
        let r = radius * (rng.unit() as f32).sqrt();
        let (x, y) = (cx + r * a.cos(), cy + r * a.sin());
        let c = class_at(x, y);
        let z = match c {
            BUILDING | HIGH_VEG => rng.unit() as f32 * 1.5,
            _ => 0.02,
        };
        let base = &world.class_features[c];
        let f: [f32; D] = core::array::from_fn(|d| base[d] + 0.03 * gauss(rng));
        pts.push([x - cx, y - cy, z]);
        feats.push(f);
    }
    (pose, pts, feats)
}

pub fn gauss(rng: &mut SplitMix) -> f32 {
    let u = rng.unit().max(1e-12);
    let v = rng.unit();
    ((-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()) as f32
}

/// A robot: the firmware's `Mapper`, its UART, and what it handed to the link (tapped).
pub struct RobotRig {
    pub robot: Box<Robot>,
    pub uart: ByteLog,
    pub evicted: Vec<(VoxelKey, u32, ObsStats<D>)>,
    pub live_sent: u64,
}

impl RobotRig {
    pub fn new(world: &World, robot: u16, window: f32) -> Self {
        let mut r = Box::new(Robot::EMPTY);
        let setup = Setup {
            codec: world.config.codec,
            feature_space: world.config.feature_space,
            ..Setup::new(
                world.config.map_config().unwrap(),
                window,
                EncoderSettings::new(robot, 1000 + u32::from(robot)),
            )
        };
        r.configure(&setup).unwrap();
        assert_eq!(r.encoder().config(), &world.config);
        Self {
            robot: r,
            uart: ByteLog::default(),
            evicted: Vec::new(),
            live_sent: 0,
        }
    }

    pub fn map(&self) -> &LocalMap<D, CAP, P> {
        self.robot.map()
    }

    /// Integrate one scan, then spend `budget` bytes: evicted voxels first, then live updates.
    pub fn step(
        &mut self,
        pose: &Isometry3<f32>,
        pts: &[[f32; 3]],
        feats: &[[f32; D]],
        budget: usize,
    ) {
        let evicted = &mut self.evicted;
        self.robot
            .integrate_tapped(pose, pts, feats, |v: &Evicted<'_, D>| {
                evicted.push((v.key, v.residency, *v.obs))
            });
        self.tick(budget);
    }

    pub fn tick(&mut self, budget: usize) {
        // Live updates use whatever the final voxels leave.
        let report = self
            .robot
            .tick_live(&mut self.uart, budget, budget)
            .unwrap();
        self.live_sent += u64::from(report.live_sent);
    }

    /// End of run: evict everything and send it all.
    pub fn finish(&mut self) {
        let evicted = &mut self.evicted;
        self.robot
            .drain_tapped(&mut self.uart, |v: &Evicted<'_, D>| {
                evicted.push((v.key, v.residency, *v.obs))
            })
            .unwrap();
    }
}

/// Index of the best category for a mean.
pub fn label(vocab: &Codebook<D, VOCAB_CAP>, mean: &[f32; D]) -> usize {
    vocab.argmax(mean).unwrap().0
}

/// Feed bytes to a base station in pseudo-random chunks (1..=700 bytes).
pub fn feed_chunked<const DD: usize>(base: &mut BaseStation<DD>, bytes: &[u8], seed: u64) {
    let mut rng = SplitMix::new(seed);
    let mut at = 0;
    while at < bytes.len() {
        let n = (1 + rng.below(700)).min(bytes.len() - at);
        base.receive(&bytes[at..at + n]);
        at += n;
    }
}

/// Compare a global map against ground truth (sorted `(key, posterior)` of every voxel in reach): (voxels
/// compared, argmax agreement, worst relative λ error, RMS of ‖Δμ‖/‖μ‖). The map must answer exactly the
/// truth's voxels.
pub fn compare(
    world: &World,
    base: &host_sim::base_station::GlobalMap<D>,
    truth: &[(VoxelKey, VoxelStats<D>)],
) -> (usize, f64, f64, f64) {
    let got = base.posteriors();
    assert_eq!(
        got.len(),
        truth.len(),
        "the global map answers other voxels than the truth"
    );
    let mut agree = 0usize;
    let mut worst_lambda = 0.0f64;
    let mut sq = 0.0f64;
    for ((gk, b), (k, r)) in got.iter().zip(truth) {
        assert_eq!(gk, k, "voxel {k:?} missing from the global map");
        worst_lambda = worst_lambda.max(f64::from((b.lambda - r.lambda).abs() / r.lambda));
        let num: f32 = b
            .mean
            .iter()
            .zip(&r.mean)
            .map(|(x, y)| (x - y) * (x - y))
            .sum();
        let den: f32 = r.mean.iter().map(|x| x * x).sum();
        sq += f64::from(num / den.max(1e-12));
        agree += usize::from(label(&world.vocab, &b.mean) == label(&world.vocab, &r.mean));
    }
    let n = truth.len();
    (
        n,
        agree as f64 / n as f64,
        worst_lambda,
        (sq / n as f64).sqrt(),
    )
}

/// The f32 reference map as sorted `(key, posterior)`.
pub fn reference_truth(reference: &ReferenceMap<D>) -> Vec<(VoxelKey, VoxelStats<D>)> {
    reference
        .sorted()
        .into_iter()
        .map(|(k, v)| (k, *v))
        .collect()
}

/// What the robots evicted, merged in f32 without any wire quantization, and gathered: what the base
/// station must answer up to the wire's own quantization.
pub fn evicted_truth(world: &World, robots: &[RobotRig]) -> Vec<(VoxelKey, VoxelStats<D>)> {
    let mut m = ObsMap::<D>::new(world.config.map_config().unwrap()).unwrap();
    for r in robots {
        for (k, _, obs) in &r.evicted {
            m.merge_observations(*k, obs);
        }
    }
    m.posteriors_sorted()
}
