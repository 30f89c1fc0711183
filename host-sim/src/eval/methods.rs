//! The mapping methods compared, behind one small interface, all decoded by the same codebook.
//!
//! - **Segmentation only**: each held-out point decoded from its own feature (no map).
//! - **Heuristic**: each voxel keeps the last feature that fell into it.
//! - **VLMap-style mean**: each voxel keeps the running mean of the features that fell into it (f = 1, no
//!   kernel, no uncertainty). Its expectation equals LatentBKI's with f = 1 and λ₀ = 0 — the paper's point
//!   that LatentBKI is a probabilistic generalisation of the weighted average — so the two rows differ only
//!   by rounding; LatentBKI adds the uncertainty.
//! - **ConvBKI-style categorical BKI**: Dirichlet counts per voxel over the network's argmax labels, spread
//!   by the same sparse kernel table (the closed-dictionary semantic BKI of the paper's Table I).
//! - **LatentBKI** on the f32 [`ObsMap`] (f = 1, 3, 5 …): per-voxel observation statistics gathered
//!   through the kernel, equal to the paper's batch update of [`crate::ReferenceMap`] to f32 rounding.
//! - **LatentBKI on the device**: the firmware's own [`latentbki::Mapper`] (quantized, fixed-capacity map
//!   and frame encoder); every voxel it hands to the link is tapped with its exact statistics and merged
//!   back for evaluation, as the base station does. Its link goes to a [`Radio`] (the demo's faulty link
//!   and base station plug in there) or, without one, nowhere.
//!
//! Every map method uses the core's keys, kernel table, locate/spread, statistics and gather: no second copy
//! of the math.

use crate::ObsMap;
use latentbki::frame::EncoderSettings;
use latentbki::{
    batch::locate, batch::spread, decode::Codebook, kernel::KernelLut, key::VoxelKey,
    obs::ObsLookup, obs::ObsStats, quant::MeanWeights, sink::Evicted, stats::VoxelStats, MapConfig,
    Setup,
};
use std::collections::HashMap;

pub use crate::sim::vocab::D;
/// Codebook capacity: the most classes a scene can have (the vocabulary has 64 phrases).
pub const K: usize = 64;
/// A compressed feature.
pub type Feature = [f32; D];
/// The decoder all methods share.
pub type Decoder = Codebook<D, K>;

/// One frame as the maps see it: the integrated 80 % and the held-out 20 %.
#[derive(Clone, Debug)]
pub struct EncodedFrame {
    /// Sensor → map pose.
    pub pose: latentbki::nalgebra::Isometry3<f32>,
    /// Integrated points, sensor frame.
    pub points: Vec<[f32; 3]>,
    /// Integrated points, map frame.
    pub map_points: Vec<[f32; 3]>,
    /// Their compressed features.
    pub features: Vec<Feature>,
    /// Their true classes (what the scale search validates against; no map reads them).
    pub classes: Vec<u16>,
    /// Held-out points, map frame.
    pub held_points: Vec<[f32; 3]>,
    /// Their true classes.
    pub held_classes: Vec<u16>,
    /// Their own (noisy) features, for segmentation only.
    pub held_features: Vec<Feature>,
}

/// A mapping method under evaluation.
pub trait MappingMethod: Send {
    /// Integrate one frame's input points.
    fn integrate(&mut self, frame: &EncodedFrame);
    /// The class predicted at a held-out point (`own` is the point's own feature); `None` = unknown.
    fn predict(&self, decoder: &Decoder, position: [f32; 3], own: &Feature) -> Option<usize>;
    /// The LatentBKI posterior of the voxel at `position`, for methods that have one.
    fn posterior(&self, _position: [f32; 3]) -> Option<VoxelStats<D>> {
        None
    }
    /// Voxels held (0 for methods without a map).
    fn voxels(&self) -> usize;
    /// Every voxel's LatentBKI posterior, sorted by key (empty for methods without one).
    fn snapshot(&self) -> Vec<(VoxelKey, VoxelStats<D>)> {
        Vec::new()
    }
    /// End of the run (after the last frame was integrated and scored): a robot streams what it still holds.
    fn finish(&mut self, _decoder: &Decoder) {}
    /// Points its map refused, by reason: the robot's `Mapper` counts every point it does not take (the
    /// host maps take every point the evaluation hands them).
    fn refused(&self) -> Option<latentbki::RejectionCounts> {
        None
    }
}

fn key_of(position: [f32; 3], config: &MapConfig) -> Option<VoxelKey> {
    VoxelKey::from_position(position, 1.0 / config.voxel_size()).ok()
}

fn decode(decoder: &Decoder, mu: &Feature) -> Option<usize> {
    decoder.argmax(mu).map(|(c, _)| c)
}

/// Decode each point's own feature.
pub struct SegmentationOnly;

impl MappingMethod for SegmentationOnly {
    fn integrate(&mut self, _frame: &EncodedFrame) {}
    fn predict(&self, decoder: &Decoder, _p: [f32; 3], own: &Feature) -> Option<usize> {
        decode(decoder, own)
    }
    fn voxels(&self) -> usize {
        0
    }
}

/// Last observation in the voxel wins.
pub struct Heuristic {
    config: MapConfig,
    voxels: HashMap<VoxelKey, Feature>,
}

impl Heuristic {
    /// An empty map with the voxel size of `config`.
    pub fn new(config: MapConfig) -> Self {
        Self {
            config,
            voxels: HashMap::new(),
        }
    }
}

impl MappingMethod for Heuristic {
    fn integrate(&mut self, frame: &EncodedFrame) {
        for (p, y) in frame.map_points.iter().zip(&frame.features) {
            if let Some(k) = key_of(*p, &self.config) {
                self.voxels.insert(k, *y);
            }
        }
    }
    fn predict(&self, decoder: &Decoder, p: [f32; 3], _own: &Feature) -> Option<usize> {
        decode(decoder, self.voxels.get(&key_of(p, &self.config)?)?)
    }
    fn voxels(&self) -> usize {
        self.voxels.len()
    }
}

/// VLMap-style running mean of the features in each voxel.
pub struct RunningMean {
    config: MapConfig,
    voxels: HashMap<VoxelKey, (u32, Box<[f64; D]>)>,
}

impl RunningMean {
    /// An empty map with the voxel size of `config`.
    pub fn new(config: MapConfig) -> Self {
        Self {
            config,
            voxels: HashMap::new(),
        }
    }
}

impl MappingMethod for RunningMean {
    fn integrate(&mut self, frame: &EncodedFrame) {
        for (p, y) in frame.map_points.iter().zip(&frame.features) {
            if let Some(k) = key_of(*p, &self.config) {
                let e = self
                    .voxels
                    .entry(k)
                    .or_insert_with(|| (0, Box::new([0.0; D])));
                e.0 += 1;
                for (s, v) in e.1.iter_mut().zip(y) {
                    *s += f64::from(*v);
                }
            }
        }
    }
    fn predict(&self, decoder: &Decoder, p: [f32; 3], _own: &Feature) -> Option<usize> {
        let (n, sum) = self.voxels.get(&key_of(p, &self.config)?)?;
        let mean: Feature = std::array::from_fn(|i| (sum[i] / f64::from(*n)) as f32);
        decode(decoder, &mean)
    }
    fn voxels(&self) -> usize {
        self.voxels.len()
    }
}

/// ConvBKI-style categorical BKI: kernel-weighted Dirichlet counts of the network's argmax labels.
pub struct CategoricalBki {
    lut: Box<KernelLut<{ crate::reference_map::HOST_LUT_CAP }>>,
    decoder: Decoder,
    voxels: HashMap<VoxelKey, Vec<f32>>,
}

impl CategoricalBki {
    /// An empty map; `decoder` plays the segmentation network's classifier head (argmax label per point).
    pub fn new(config: MapConfig, decoder: Decoder) -> Result<Self, latentbki::ConfigError> {
        Ok(Self {
            lut: Box::new(KernelLut::new(&config)?),
            decoder,
            voxels: HashMap::new(),
        })
    }
}

impl MappingMethod for CategoricalBki {
    fn integrate(&mut self, frame: &EncodedFrame) {
        let k = self.decoder.len();
        for (p, y) in frame.map_points.iter().zip(&frame.features) {
            let (Some(label), Ok((key, cell))) =
                (decode(&self.decoder, y), locate(&self.lut, *p, y))
            else {
                continue;
            };
            let voxels = &mut self.voxels;
            spread(&self.lut, key, cell, |t, w| {
                voxels.entry(t).or_insert_with(|| vec![0.0; k])[label] += w;
            });
        }
    }
    fn predict(&self, _decoder: &Decoder, p: [f32; 3], _own: &Feature) -> Option<usize> {
        let key = VoxelKey::from_position(p, self.lut.inv_voxel_size()).ok()?;
        let counts = self.voxels.get(&key)?;
        counts
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1).then(b.0.cmp(&a.0)))
            .map(|(c, _)| c)
    }
    fn voxels(&self) -> usize {
        self.voxels.len()
    }
}

/// LatentBKI on the host's f32 observation map (equal to the reference map's paper update to f32 rounding:
/// `host-sim/tests/obs_map.rs`).
pub struct LatentBki {
    map: ObsMap<D>,
}

impl LatentBki {
    /// An empty map.
    pub fn new(config: MapConfig) -> Result<Self, crate::obs_map::ObsMapError> {
        Ok(Self {
            map: ObsMap::new(config)?,
        })
    }
    /// The map.
    pub fn map(&self) -> &ObsMap<D> {
        &self.map
    }
}

impl MappingMethod for LatentBki {
    fn integrate(&mut self, frame: &EncodedFrame) {
        self.map
            .integrate(&frame.pose, &frame.points, &frame.features);
    }
    fn predict(&self, decoder: &Decoder, p: [f32; 3], _own: &Feature) -> Option<usize> {
        decode(decoder, &self.posterior(p)?.mean)
    }
    fn posterior(&self, p: [f32; 3]) -> Option<VoxelStats<D>> {
        self.map.posterior_in_reach(key_of(p, self.map.config())?)
    }
    fn voxels(&self) -> usize {
        self.map.in_reach_len()
    }
    fn snapshot(&self) -> Vec<(VoxelKey, VoxelStats<D>)> {
        self.map.posteriors_sorted()
    }
}

/// Packed code length of a 64-d quantized voxel.
pub const PACKED: usize = latentbki::packed_len(D);
/// Voxels the simulated device holds (the host runs it with a generous pool; the firmware's is smaller).
pub const DEVICE_CAPACITY: usize = 60_000;
/// Bytes of the robot's link queue (evicted voxels, and unacknowledged frames with a back channel).
pub const DEVICE_QUEUE: usize = 32 * 1024;
/// Largest frame on the robot's link.
pub const DEVICE_FRAME: usize = 512;
/// The robot the simulator runs: the firmware's `Mapper`.
pub type DeviceRobot = latentbki::Mapper<D, DEVICE_CAPACITY, PACKED, DEVICE_QUEUE, DEVICE_FRAME>;

/// Where the robot's link goes: the demo's faulty link and base station plug in here.
pub trait Radio: Send {
    /// The robot's setup, adjusted for this link (back channel, live updates).
    fn setup(&self, setup: Setup) -> Setup {
        setup
    }
    /// Before the first frame: the feature space the robot's features live in (the class names, the PCA
    /// and the codebook that decodes them), e.g. for the base station's live view.
    fn feature_space(
        &mut self,
        _classes: &[String],
        _pca: &latentbki::decode::Pca<D, { crate::sim::vocab::FULL_DIM }>,
        _decoder: &Decoder,
    ) {
    }
    /// After each sensor frame: the robot's tick over the link, and whatever comes back.
    fn tick(&mut self, robot: &mut DeviceRobot);
    /// End of the run: everything the robot holds goes out; `tap` sees every voxel handed to the link.
    fn drain(&mut self, robot: &mut DeviceRobot, tap: &mut dyn FnMut(&Evicted<'_, D>));
    /// After draining: the robot's whole map as it held it (unquantized by the wire), for comparisons.
    fn finish(&mut self, _robot: &ObsMap<D>, _decoder: &Decoder) {}
}

/// A link to nowhere: the robot's frames are written and forgotten.
struct Nowhere;

impl embedded_io::ErrorType for Nowhere {
    type Error = core::convert::Infallible;
}

impl embedded_io::Write for Nowhere {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// LatentBKI on the robot's own `Mapper`, with what it hands to the link merged back on the host.
pub struct OnDevice {
    robot: Box<DeviceRobot>,
    /// Voxels handed to the link, merged per key (what the base station's global map holds).
    evicted: HashMap<VoxelKey, ObsStats<D>>,
    link: Option<Box<dyn Radio>>,
    /// int8 features: `Some(0.0)` until the first frame sets the scale, then `Some(scale)`.
    int8_scale: Option<f32>,
    /// The robot's setup (re-applied with the int8 scale once the first frame sets it).
    setup: Setup,
}

/// Merge a tapped voxel into the host's record of what was handed to the link.
fn record(evicted: &mut HashMap<VoxelKey, ObsStats<D>>, v: &Evicted<'_, D>) {
    evicted
        .entry(v.key)
        .and_modify(|m| m.merge(v.obs))
        .or_insert(*v.obs);
}

/// Headroom of the int8 scale over the first frame's largest |feature component| (later frames may reach
/// further; beyond ±127 codes clamp).
const INT8_HEADROOM: f32 = 1.25;

impl OnDevice {
    /// A robot with a window of `window_radius` metres around it, its mean codes weighed by
    /// `mean_weights`; its link goes to `link` (e.g. the
    /// simulated radio to the base station), or nowhere.
    pub fn new(
        config: MapConfig,
        window_radius: f32,
        mean_weights: MeanWeights,
        link: Option<Box<dyn Radio>>,
    ) -> Result<Self, latentbki::SetupError> {
        let mut robot: Box<DeviceRobot> = Box::new(DeviceRobot::EMPTY);
        let setup = Setup::new(config, window_radius, EncoderSettings::new(1, 1))
            .with_mean_weights(mean_weights);
        let setup = link.as_ref().map_or(setup, |l| l.setup(setup));
        robot.configure(&setup)?;
        Ok(Self {
            robot,
            evicted: HashMap::new(),
            link,
            int8_scale: None,
            setup,
        })
    }

    /// Feed the robot int8 features: each frame's features quantized with one global scale (round to
    /// nearest, clamp to ±127), the scale set from the first frame's largest |component| with 25 %
    /// headroom — what a firmware does with an accelerator whose output scale was calibrated once.
    pub fn with_int8_features(mut self) -> Self {
        self.int8_scale = Some(0.0);
        self
    }

    /// The robot.
    pub fn robot(&self) -> &DeviceRobot {
        &self.robot
    }

    /// Everything observed in a voxel: the merged evictions and the resident statistics.
    pub fn combined(&self, key: VoxelKey) -> Option<ObsStats<D>> {
        match (self.evicted.get(&key), self.robot.map().get(key)) {
            (Some(e), Some(r)) => {
                let mut m = *e;
                m.merge(&r);
                Some(m)
            }
            (Some(e), None) => Some(*e),
            (None, r) => r,
        }
    }

    /// Keys observed (evicted or resident).
    pub fn keys(&self) -> Vec<VoxelKey> {
        let mut k: Vec<VoxelKey> = self.evicted.keys().copied().collect();
        k.extend(self.robot.map().iter().map(|v| v.key));
        k.sort_unstable();
        k.dedup();
        k
    }

    /// Everything observed, in the host's block map (gathers every posterior in one pass).
    pub fn observation_map(&self) -> ObsMap<D> {
        let mut m = ObsMap::new(*self.robot.map().config()).expect("configured in `new`");
        for k in self.keys() {
            if let Some(o) = self.combined(k) {
                m.merge_observations(k, &o);
            }
        }
        m
    }
}

impl ObsLookup<D> for OnDevice {
    fn observed(&self, key: VoxelKey) -> Option<ObsStats<D>> {
        self.combined(key)
    }
}

impl MappingMethod for OnDevice {
    fn integrate(&mut self, frame: &EncodedFrame) {
        let evicted = &mut self.evicted;
        let tap = |v: &Evicted<'_, D>| record(evicted, v);
        match self.int8_scale {
            None => {
                self.robot
                    .integrate_tapped(&frame.pose, &frame.points, &frame.features, tap);
            }
            Some(mut scale) => {
                if scale <= 0.0 {
                    let max = frame
                        .features
                        .iter()
                        .flatten()
                        .fold(0.0f32, |m, v| m.max(v.abs()));
                    if max <= 0.0 || max.is_nan() {
                        return; // nothing to calibrate on (an empty frame): wait for one with features
                    }
                    scale = max * INT8_HEADROOM / 127.0;
                    self.int8_scale = Some(scale);
                    // Nothing was integrated yet: the robot starts over with the calibrated scale.
                    self.robot
                        .configure(&self.setup.with_int8_features(scale))
                        .expect("a finite positive scale of bounded features");
                }
                let codes: Vec<[i8; D]> = frame
                    .features
                    .iter()
                    .map(|y| y.map(|v| (v / scale).round().clamp(-127.0, 127.0) as i8))
                    .collect();
                self.robot
                    .begin_frame_tapped(&frame.pose, tap)
                    .add_points_i8(&frame.points, &codes);
            }
        }
        match &mut self.link {
            Some(l) => l.tick(&mut self.robot),
            None => {
                let _ = self.robot.tick(&mut Nowhere, usize::MAX);
            }
        }
    }
    fn predict(&self, decoder: &Decoder, p: [f32; 3], _own: &Feature) -> Option<usize> {
        decode(decoder, &self.posterior(p)?.mean)
    }
    fn posterior(&self, p: [f32; 3]) -> Option<VoxelStats<D>> {
        let map = self.robot.map();
        let key = key_of(p, map.config())?;
        let obs = latentbki::obs::gather(map.kernel(), self, key).ok()?;
        (!obs.is_empty()).then(|| obs.posterior(&map.prior()))
    }
    fn voxels(&self) -> usize {
        self.observation_map().in_reach_len()
    }
    fn snapshot(&self) -> Vec<(VoxelKey, VoxelStats<D>)> {
        self.observation_map().posteriors_sorted()
    }
    fn refused(&self) -> Option<latentbki::RejectionCounts> {
        Some(self.robot.map().rejections())
    }
    fn finish(&mut self, decoder: &Decoder) {
        // Stream what the robot still holds: its last word on every voxel.
        let evicted = &mut self.evicted;
        let mut tap = |v: &Evicted<'_, D>| record(evicted, v);
        match &mut self.link {
            Some(l) => l.drain(&mut self.robot, &mut tap),
            None => {
                // Nowhere never refuses: the drain completes.
                let _ = self.robot.drain_tapped(&mut Nowhere, &mut tap);
            }
        }
        let robot = self.observation_map();
        if let Some(l) = self.link.as_mut() {
            l.finish(&robot, decoder);
        }
    }
}
