//! LatentBKI firmware for QEMU `mps2-an386` (Cortex-M4F with FPU).
//!
//! Runs the self-test ([`latentbki_selftest::SELF_TEST`]) on the device: a synthetic room seen by a moving
//! 8×8 ToF and by a 64×64 depth camera, features from the compiled-in codebook plus noise, integrated into a
//! quantized `LocalMap` in a static, evicted voxels streamed as frames over UART0 by the core's
//! `FrameEncoder` — both owned by the core's `Mapper`, the same loop any firmware runs. The host twin (`host-sim/tests/firmware_qemu.rs`) runs the same core code and compares.
//!
//! UART0 carries only frames. Human-readable results go to semihosting stdout (one `frame …` line per
//! frame, one `scenario …` line per scenario, then `stack …` and `done`); the exit code says how it went.
#![no_std]
#![no_main]

mod board;

/// A line of the human-readable report on semihosting stdout. Not in the `panic-never` build: semihosting's
/// formatted output can panic (a formatter error, its stdout handle's assertion), and that build is a
/// link-time proof about the map and the encoder, not a run (the arguments are still type-checked there).
#[cfg(not(feature = "panic-never"))]
macro_rules! report {
    ($($arg:tt)*) => { semihosting::println!($($arg)*) };
}
#[cfg(feature = "panic-never")]
macro_rules! report {
    ($($arg:tt)*) => {{
        let _ = format_args!($($arg)*);
    }};
}

use board::{exit, exit_code, Markers, Uart};
use latentbki::local_map::LocalMap;
use latentbki::quant::packed_len;
use latentbki::Mapper;
use latentbki_selftest::{
    self as selftest, Chunk, FrameReport, RunError, Scenario, SELF_TEST, SELF_TEST_CAPACITY,
    SELF_TEST_FRAME_BYTES, SELF_TEST_QUEUE_BYTES,
};
use static_cell::ConstStaticCell;

#[cfg(feature = "defmt")]
use defmt_semihosting as _;

/// Feature dimension (PCA-compressed).
const D: usize = 64;
const P: usize = packed_len(D);
/// Points generated per chunk (4.3 KiB of scratch).
const K: usize = 16;

type Map = LocalMap<D, SELF_TEST_CAPACITY, P>;
type Robot = Mapper<D, SELF_TEST_CAPACITY, P, SELF_TEST_QUEUE_BYTES, SELF_TEST_FRAME_BYTES>;

/// The map and the encoder (≈ 170 KiB) live in a static (`.bss`), reconfigured in place for each
/// scenario; never on the stack.
static MAPPER: ConstStaticCell<Robot> = ConstStaticCell::new(Robot::EMPTY);
static CHUNK: ConstStaticCell<Chunk<D, K>> = ConstStaticCell::new(Chunk::ZERO);

#[cortex_m_rt::entry]
fn main() -> ! {
    // `main` runs once, so each static is taken exactly once (`try_take`: no panic path).
    let (Some(mapper), Some(chunk)) = (MAPPER.try_take(), CHUNK.try_take()) else {
        exit(exit_code::FAILED)
    };
    let mut uart = Uart::uart0();
    for (s, scenario) in SELF_TEST.iter().enumerate() {
        if let Err(code) = run_scenario(s, scenario, mapper, chunk, &mut uart) {
            exit(code)
        }
    }
    // Since the last repaint (before the last scenario's loop): that loop and the reports after it. With the
    // set-up and loop marks of every scenario, every stack byte the run used falls in some measured window.
    let tail_stack = board::stack::high_water_since_repaint();
    report!(
        "memory stack_size={} map_bytes={} bytes_per_voxel={} tail_stack_high_water={}",
        board::stack::size(),
        core::mem::size_of::<Map>(),
        Map::BYTES_PER_VOXEL,
        tail_stack
    );
    report!("done");
    exit(exit_code::SUCCESS)
}

/// One scenario of the self-test: the map and the encoder configured in place, the run, a report.
#[inline(never)]
fn run_scenario(
    s: usize,
    scenario: &Scenario,
    mapper: &mut Robot,
    chunk: &mut Chunk<D, K>,
    uart: &mut Uart,
) -> Result<(), i32> {
    configure(scenario, mapper)?;
    let setup_stack = board::stack::high_water();
    // From here on: the integrate-and-stream loop. Its own stack high-water mark is measured from a fresh
    // paint (the whole-run mark above includes the one-time set-up; see README "Firmware").
    board::stack::repaint();
    let on_frame = |i: u32, f: &FrameReport, m: &Map| {
        Markers.report();
        report!(
            "frame s={} i={} f={} points={} integrated={} voxels={}",
            s,
            i,
            scenario.filter_size,
            f.points,
            f.integrated,
            m.len()
        );
        if i + 1 == scenario.frames {
            // Outside the counted regions: how many voxels the full map answers (stored voxels and every
            // voxel within the kernel's reach of one).
            report!(
                "answerable s={} f={} held={} answerable={}",
                s,
                scenario.filter_size,
                m.len(),
                m.answerable()
            );
        }
    };
    let r = match selftest::run(scenario, mapper, chunk, uart, &mut Markers, on_frame) {
        Ok(r) => r,
        Err(RunError::Config(_) | RunError::NotConfigured | RunError::Stuck) => {
            return Err(exit_code::FAILED)
        }
        Err(RunError::Write(never)) => match never {},
    };
    let loop_stack = board::stack::high_water_since_repaint();
    #[cfg(feature = "defmt")]
    defmt::info!(
        "scenario {}: {} points, {} frames sent",
        s,
        r.points,
        r.link.frames_sent
    );
    report!(
        "scenario s={} name={} f={} frames={} points={} integrated={} peak_voxels={} capacity={} evicted={} refused={} flushed={} no_room={} outside_window={} frames_sent={} bytes_sent={} evicted_sent={} invalid={}",
        s,
        scenario.name,
        scenario.filter_size,
        scenario.frames,
        r.points,
        r.integrated,
        r.peak_voxels,
        mapper.map().capacity(),
        r.counters.evicted,
        r.counters.refused,
        r.flushed,
        r.rejections.no_room,
        r.rejections.outside_window,
        r.link.frames_sent,
        r.link.bytes_sent,
        r.link.evicted_sent,
        r.link.invalid
    );
    report!(
        "stack s={} setup_high_water={} loop_high_water={}",
        s,
        setup_stack,
        loop_stack
    );
    Ok(())
}

/// Configure the map (its kernel table is rebuilt in place) and start the encoder's session in place: no
/// table- or buffer-sized value is built on the stack. Kept out of the loop's frame.
#[inline(never)]
fn configure(scenario: &Scenario, mapper: &mut Robot) -> Result<(), i32> {
    scenario
        .configure(mapper)
        .map_err(|_| exit_code::FAILED)
}
