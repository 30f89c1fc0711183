//! A robot's mapping loop, ready to copy into a `no_std` firmware: configure once from statics, then per
//! sensor frame — pose, points and features in, a byte-budgeted send — and everything out at the end.
//!
//! On a microcontroller, `Link` is your UART (anything that implements `embedded_io::Write`), the points
//! come from your depth sensor and the features from your vision model (PCA-compressed to `D`
//! dimensions). Here a made-up sensor looks at a wall while the robot drives along it, and the link
//! counts bytes. Run: `cargo run --release --example robot`.

use latentbki::nalgebra::{Isometry3, Translation3, UnitQuaternion};
use latentbki::{mapper_type, EncoderSettings, KernelMode, MapConfig, Prior, Setup, TickReport};
use static_cell::ConstStaticCell;

/// Feature dimension.
const D: usize = 64;
/// Voxels the map holds (≈ 120 B each at D = 64: see `LocalMap::BYTES_PER_VOXEL`).
const VOXELS: usize = 1024;
/// The map: D, voxels, a 4 KiB queue of evicted voxels, frames of at most 512 bytes on the wire.
type Robot = mapper_type!(D, VOXELS, 4096, 512);

/// 5 cm voxels, kernel length 0.3 m, f = 3 — validated at compile time.
const MAP: MapConfig = match MapConfig::new(0.05, 0.3, 3, Prior::DEFAULT, KernelMode::VoxelOffset) {
    Ok(c) => c,
    Err(_) => panic!("invalid map configuration"),
};
/// Robot 1, session 42 (use a boot counter), voxels farther than 1.5 m from the sensor stream out.
static SETUP: Setup = Setup::new(MAP, 1.5, EncoderSettings::new(1, 42));
/// All zero until configured: lives in `.bss`, costs no flash, never touches the stack.
static MAPPER: ConstStaticCell<Robot> = ConstStaticCell::new(Robot::EMPTY);

/// Bytes per frame the link carries (115,200 Bd at 10 frames/s).
const BUDGET: usize = 1152;

fn main() {
    let mapper = MAPPER.take();
    if let Err(e) = mapper.configure(&SETUP) {
        panic!("{e}"); // e.g. "setup refused by the map: window radius …" (SetupError: Display)
    }
    let mut link = Link(0);
    let mut points = [[0.0f32; 3]; 64];
    let mut features = [[0.0f32; D]; 64];
    for frame in 0..50u16 {
        // Your odometry: here the robot drives 5 cm per frame along x.
        let x = f32::from(frame) * 0.05;
        let pose =
            Isometry3::from_parts(Translation3::new(x, 0.0, 0.0), UnitQuaternion::identity());
        // Your sensor: 8 × 8 points on a wall 1 m ahead (sensor frame); your vision model: the features.
        for (i, (p, f)) in points.iter_mut().zip(&mut features).enumerate() {
            *p = [
                (i % 8) as f32 * 0.04 - 0.14,
                (i / 8) as f32 * 0.04 - 0.14,
                1.0,
            ];
            f.fill(0.0);
            f[i % 4] = 1.0; // four kinds of surface
        }
        mapper.integrate(&pose, &points, &features);
        let sent: TickReport = mapper
            .tick(&mut link, BUDGET)
            .expect("the link never fails here");
        if frame % 10 == 0 {
            println!(
                "frame {frame:2}: {} voxels held, {} evicted voxels sent in {} B",
                mapper.map().len(),
                sent.evicted_sent,
                sent.bytes
            );
        }
    }
    let flushed = mapper.drain(&mut link).expect("the link never fails here");
    let stats = mapper.encoder().stats();
    println!(
        "end: {flushed} voxels flushed; {} frames, {} B on the link, {} voxels sent; {} points refused",
        stats.frames_sent,
        link.0,
        stats.evicted_sent,
        mapper.map().rejections().total()
    );
}

/// A link that counts bytes (on a robot: your UART's `embedded_io::Write`).
struct Link(usize);

impl embedded_io::ErrorType for Link {
    type Error = core::convert::Infallible;
}

impl embedded_io::Write for Link {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.0 += buf.len();
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}
