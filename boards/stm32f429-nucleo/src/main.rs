//! LatentBKI on a NUCLEO-F429ZI (STM32F429ZI: Cortex-M4F, 2 MiB flash, 192 KiB contiguous SRAM).
//!
//! The same loop as the QEMU firmware, wired to real peripherals: a VL53L5CX-style 8×8 ToF on I2C1
//! (PB8 = SCL, PB9 = SDA, 400 kHz) gives ranges; each valid zone becomes a point along its ray in integer
//! millimetres (the library's fixed-point zone table, `latentbki::tof::VL53L5CX_8X8`, and the map's integer
//! point path: no float per point); the core's `Mapper` (the quantized `LocalMap` and the `FrameEncoder`) lives in
//! a static; evicted voxels stream as frames on USART3 (PD8, the ST-LINK virtual COM port, 921,600 Bd).
//! Flash with `cargo run --release` (probe-rs).
//!
//! Stubbed, and why: the ToF firmware blob is ST's and not shipped (see `vl53l5cx.rs`; give it at build time
//! with `VL53L5CX_FW=path`, else the board keeps retrying the sensor); there is no camera, so every point carries one fixed unit vector as its feature, as int8 codes (a real
//! robot gets features from its vision model, or its segmenter's scores through `latentbki::classes`: docs/firmware.md); there is no odometry, so the pose
//! is fixed (a real robot passes its pose estimate).
#![no_std]
#![no_main]

mod vl53l5cx;

use latentbki::local_map::LocalMap;
use latentbki::nalgebra::{Isometry3, Translation3, UnitQuaternion};
use latentbki::tof::VL53L5CX_8X8;
use latentbki::{packed_len, EncoderSettings, MapConfig, Mapper, Setup};
use latentbki_selftest::{SELF_TEST_CODEC, SELF_TEST_MEAN_WEIGHTS};
use static_cell::ConstStaticCell;
use stm32f4xx_hal::{i2c::I2c, pac, prelude::*};
use vl53l5cx::{MultizoneRanger, Vl53l5cx, ZoneFrame, ZONES};

const D: usize = 64;
const P: usize = packed_len(D);
/// RAM for the map's voxels (slots and index): 192 KiB less stack, the encoder and the HAL.
const MAP_BUDGET: usize = 144 * 1024;
const CAP: usize = MAP_BUDGET / LocalMap::<D, 1, P>::BYTES_PER_VOXEL;
type Robot = Mapper<D, CAP, P, 4096, 512>;

/// Robot 1, session 1, a 2 m window around the sensor, 0.1 m voxels, ℓ = 0.5 m, f = 3; int8 features, a
/// code c standing for c / 127; summaries and mean codes as the QEMU boards ship and measure them
/// (`latentbki_selftest::SELF_TEST_CODEC`, `SELF_TEST_MEAN_WEIGHTS`: the accuracy rows of boards/measure.sh).
static SETUP: Setup = Setup {
    codec: SELF_TEST_CODEC,
    ..Setup::new(MapConfig::DEFAULT, 2.0, EncoderSettings::new(1, 1))
}
.with_int8_features(1.0 / 127.0)
.with_mean_weights(SELF_TEST_MEAN_WEIGHTS);
/// ST's VL53L5CX firmware blob (≈ 84 KB, not redistributable): given at build time with `VL53L5CX_FW=path`
/// (build.rs), else empty.
static VL53L5CX_FW: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/vl53l5cx_fw.bin"));
/// The map and the encoder (≈ 170 KiB) in `.bss`, configured in place (never on the stack).
static MAPPER: ConstStaticCell<Robot> = ConstStaticCell::new(Robot::EMPTY);

/// The feature every point carries until a vision model provides one: a fixed unit vector (int8 codes).
const FEATURE: [i8; D] = {
    let mut f = [0; D];
    f[0] = 127;
    f
};

/// The HAL's UART speaks embedded-io 0.6; the core's encoder writes through embedded-io 0.7.
struct Uart<W>(W);

impl<W: embedded_io_06::Write> embedded_io::ErrorType for Uart<W> {
    type Error = embedded_io::ErrorKind;
}

impl<W: embedded_io_06::Write> embedded_io::Write for Uart<W> {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.0.write(buf).map_err(|_| embedded_io::ErrorKind::Other)
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        self.0.flush().map_err(|_| embedded_io::ErrorKind::Other)
    }
}

#[cortex_m_rt::entry]
fn main() -> ! {
    let Some(dp) = pac::Peripherals::take() else {
        halt()
    };
    let rcc = dp.RCC.constrain();
    // 8 MHz from the ST-LINK's MCO (HSE bypass), 168 MHz system clock.
    let clocks = rcc
        .cfgr
        .use_hse(8.MHz())
        .bypass_hse_oscillator()
        .sysclk(168.MHz())
        .freeze();
    let gpiob = dp.GPIOB.split();
    let gpiod = dp.GPIOD.split();
    let Ok(tx) = dp.USART3.tx(gpiod.pd8, 921_600.bps(), &clocks) else {
        halt()
    };
    let mut uart = Uart(tx);
    let i2c = I2c::new(dp.I2C1, (gpiob.pb8, gpiob.pb9), 400.kHz(), &clocks);
    let mut tof = Vl53l5cx::new(i2c, vl53l5cx::DEFAULT_ADDRESS);

    let mapper = MAPPER.take();
    if mapper.configure(&SETUP).is_err() {
        halt()
    }

    // The sensor's firmware blob, if the build was given one (`VL53L5CX_FW`, see build.rs); without it the
    // board keeps checking the sensor. Hidden from the optimiser: an empty blob known at compile time made
    // `init` fail provably, and the whole mapping loop — the map, the encoder, the UART — was dropped from
    // the build (11 KB of text), so the firmware measured and flashed would not be the one that maps.
    let blob: &[u8] = core::hint::black_box(VL53L5CX_FW);
    while tof.init(blob).is_err() {
        cortex_m::asm::delay(168_000_000);
    }
    let pose = Isometry3::from_parts(Translation3::new(0.0, 0.0, 0.3), UnitQuaternion::identity());
    let mut frame = ZoneFrame::EMPTY;
    loop {
        if !matches!(tof.data_ready(), Ok(true)) || tof.read_frame(&mut frame).is_err() {
            continue;
        }
        // One sensor frame, a point at a time (no 64 × 256-byte feature buffer).
        let mut batch = mapper.begin_frame(&pose);
        for z in (0..ZONES).filter(|&z| frame.valid(z)) {
            // valid() means a positive range: it fits u16.
            let range = u16::try_from(frame.distance_mm[z]).unwrap_or(0);
            if let Some(point_mm) = VL53L5CX_8X8.point_mm(z, range) {
                let _ = batch.add_point_mm_i8(point_mm, &FEATURE); // refusals are counted
            }
        }
        // 921,600 Bd at 15 frames/s ≈ 6 kB per frame.
        let _ = mapper.tick(&mut uart, 6000);
    }
}

fn halt() -> ! {
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(_info: &core::panic::PanicInfo) -> ! {
    halt()
}
