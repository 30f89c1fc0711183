//! The self-test's scenarios: which scene, how many frames, the map's configuration and the link's
//! budget of each run, and the sizes every firmware and the host twin share (one table, so the QEMU boards,
//! the host twin and the measurements name the same runs).

#[allow(unused_imports)]
use crate::*;
use latentbki::config::{ConfigError, KernelMode, MapConfig, Prior};
use latentbki::forget::MapClock;
use latentbki::frame::{EncoderSettings, Resend};
use latentbki::local_map::LocalMap;
use latentbki::mapper::{Mapper, Setup, SetupError};
use latentbki::quant::Cooling;

/// One self-test run: a scene, how many frames, the map and the link.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scenario {
    /// What it measures, for reports (one word, no spaces).
    pub name: &'static str,
    /// What the sensor sees (a `static`: scenarios that differ only in the map or the features share one,
    /// so the firmware stores each scene once).
    pub scene: &'static Scene,
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

/// The 8×8 ToF circling the room.
pub static TOF_ROOM: Scene = Scene::new(DepthSensor::TOF_8X8, 0x70F);
/// 4,096-point depth frames circling the room (three seeds: f = 1, f = 3, the full map).
pub static DEPTH_D1: Scene = Scene::new(DepthSensor::DEPTH_64X64, 0xD1);
/// See [`DEPTH_D1`].
pub static DEPTH_D3: Scene = Scene::new(DepthSensor::DEPTH_64X64, 0xD3);
/// See [`DEPTH_D1`].
pub static DEPTH_D4: Scene = Scene::new(DepthSensor::DEPTH_64X64, 0xD4);
/// A 2D scanning LiDAR driving through a room and down a corridor, 240 revolutions.
pub static LIDAR_CORRIDOR: Scene = Scene::room_and_corridor(DepthSensor::LIDAR_360, 0x11DA, 240);

/// The firmware self-test: the 8×8 ToF for three turns (f = 1), then 4,096-point depth frames at f = 1
/// and f = 3 (the instruction-count benchmark), then half a turn of depth frames with a window that holds
/// the whole room (f = 3): the map fills, so the run measures how many voxels a full map answers; then the
/// sensor patterns at f = 3 for the instruction counts: the depth frames with int8 features, the 8×8 ToF,
/// and a 2D scanning LiDAR (360 beams per revolution, 240 revolutions: 24 s at 10 Hz) driving through a room
/// and down a corridor; then the two sparse patterns again with int8 features (the all-integer path an MCU
/// without an FPU runs: points in millimetres, codes of [`SELF_TEST_INT8_SCALE`]).
pub const SELF_TEST: [Scenario; 9] = [
    Scenario {
        name: "tof_f1",
        scene: &TOF_ROOM,
        frames: 144,
        filter_size: 1,
        window_radius: 2.0,
        session: 1,
        tick_budget: 2048,
        int8_scale: 0.0,
    },
    Scenario {
        name: "depth_f1",
        scene: &DEPTH_D1,
        frames: 8,
        filter_size: 1,
        window_radius: 2.5,
        session: 2,
        tick_budget: 8192,
        int8_scale: 0.0,
    },
    Scenario {
        name: "depth_f3",
        scene: &DEPTH_D3,
        frames: 8,
        filter_size: 3,
        window_radius: 2.5,
        session: 3,
        tick_budget: 8192,
        int8_scale: 0.0,
    },
    Scenario {
        name: "full_map",
        scene: &DEPTH_D4,
        frames: 24,
        filter_size: 3,
        window_radius: 4.0,
        session: 4,
        tick_budget: 8192,
        int8_scale: 0.0,
    },
    Scenario {
        name: "depth_f3_i8",
        scene: &DEPTH_D3,
        frames: 8,
        filter_size: 3,
        window_radius: 2.5,
        session: 5,
        tick_budget: 8192,
        int8_scale: SELF_TEST_INT8_SCALE,
    },
    Scenario {
        name: "tof_f3",
        scene: &TOF_ROOM,
        frames: 144,
        filter_size: 3,
        window_radius: 2.0,
        session: 6,
        tick_budget: 2048,
        int8_scale: 0.0,
    },
    Scenario {
        name: "lidar_f3",
        scene: &LIDAR_CORRIDOR,
        frames: 240,
        filter_size: 3,
        window_radius: 4.0,
        session: 7,
        tick_budget: 2048,
        int8_scale: 0.0,
    },
    Scenario {
        name: "tof_f3_i8",
        scene: &TOF_ROOM,
        frames: 144,
        filter_size: 3,
        window_radius: 2.0,
        session: 8,
        tick_budget: 2048,
        int8_scale: SELF_TEST_INT8_SCALE,
    },
    Scenario {
        name: "lidar_f3_i8",
        scene: &LIDAR_CORRIDOR,
        frames: 240,
        filter_size: 3,
        window_radius: 4.0,
        session: 9,
        tick_budget: 2048,
        int8_scale: SELF_TEST_INT8_SCALE,
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

    /// The mapper's setup: this map, robot [`SELF_TEST_ROBOT`] with the scenario's session,
    /// [`SELF_TEST_CODEC`], [`SELF_TEST_MEAN_WEIGHTS`], no PCA, the int8 scale if any, and a back channel
    /// (half the queue budget keeps unacknowledged frames; [`run`] loops the acknowledgements back).
    pub fn setup(&self) -> Result<Setup, ConfigError> {
        let setup = Setup {
            codec: SELF_TEST_CODEC,
            ..Setup::new(
                self.map_config()?,
                self.window_radius,
                EncoderSettings::new(SELF_TEST_ROBOT, self.session)
                    .with_resend(Resend::new(SELF_TEST_RESEND_BYTES as u32, 4)),
            )
        }
        .with_mean_weights(SELF_TEST_MEAN_WEIGHTS);
        Ok(if self.int8_scale > 0.0 {
            setup.with_int8_features(self.int8_scale)
        } else {
            setup
        })
    }

    /// Clear `mapper` and configure it for this scenario (in place), cooling int8 sums by this build's
    /// method ([`Cooling::NATIVE`]: what a firmware does).
    pub fn configure<
        const D: usize,
        const CAP: usize,
        const P: usize,
        const QB: usize,
        const N: usize,
        const H: usize,
        C: MapClock,
    >(
        &self,
        mapper: &mut Mapper<D, CAP, P, QB, N, H, C>,
    ) -> Result<(), SetupError> {
        self.configure_cooling(mapper, Cooling::NATIVE)
    }

    /// [`Self::configure`] cooling int8 sums by `cooling`: a host twin passes its board's method.
    pub fn configure_cooling<
        const D: usize,
        const CAP: usize,
        const P: usize,
        const QB: usize,
        const N: usize,
        const H: usize,
        C: MapClock,
    >(
        &self,
        mapper: &mut Mapper<D, CAP, P, QB, N, H, C>,
        cooling: Cooling,
    ) -> Result<(), SetupError> {
        let setup = self.setup().map_err(SetupError::Map)?;
        mapper.configure(&setup.with_cooling(cooling))
    }

    /// [`Self::configure`] forgetting with `forgetting` (a mapper with the
    /// [`latentbki::forget::Fading`] clock; [`run`] ticks once per frame).
    #[cfg(feature = "forgetting")]
    pub fn configure_forgetting<
        const D: usize,
        const CAP: usize,
        const P: usize,
        const QB: usize,
        const N: usize,
        const H: usize,
        C: MapClock,
    >(
        &self,
        mapper: &mut Mapper<D, CAP, P, QB, N, H, C>,
        forgetting: Option<latentbki::forget::Forgetting>,
    ) -> Result<(), SetupError> {
        let setup = self.setup().map_err(SetupError::Map)?;
        mapper.configure(&setup.with_forgetting(forgetting))
    }
}
