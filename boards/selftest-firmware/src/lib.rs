//! The self-test firmware, whatever the board: every QEMU board (`boards/qemu-*`) runs the same program, so
//! that each target's UART stream can be compared with the one host twin (`host-sim/tests/firmware_qemu.rs`)
//! and each target's instruction counts mean the same thing.
//!
//! The program runs the self-test ([`latentbki_selftest::SELF_TEST`]): a synthetic room seen by a moving
//! 8×8 ToF and by a 64×64 depth camera, features from the compiled-in codebook plus noise, integrated into a
//! quantized `LocalMap` in a static, evicted voxels streamed as frames over the UART by the core's
//! `FrameEncoder` — both owned by the core's `Mapper`, the same loop any firmware runs.
//!
//! The UART carries only frames. Human-readable results go to semihosting stdout (one `frame …` line per
//! frame, one `scenario …` line per scenario, then `stack …`, `memory …` and `done`: the lines
//! `boards/measure.sh` reads); the exit code says how it went. A board supplies only what differs: its
//! UART, its instruction-counter markers ([`Markers`]) and its stack gauge ([`StackGauge`]).
#![no_std]

#[cfg(target_arch = "arm")]
pub mod mps2;

use core::convert::Infallible;
/// The UART trait a board implements (the version the core uses).
pub use embedded_io;
use latentbki::local_map::{LocalMap, HOT_VOXELS};
use latentbki::quant::packed_len;
use latentbki::Mapper;
pub use latentbki_selftest::Probe;
use latentbki_selftest::{
    self as selftest, Chunk, FrameReport, RunError, Scenario, SELF_TEST, SELF_TEST_CAPACITY,
    SELF_TEST_FRAME_BYTES, SELF_TEST_QUEUE_BYTES,
};
use static_cell::ConstStaticCell;

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

#[cfg(feature = "explorer-view")]
mod explorer_view;

/// Exit codes reported through semihosting (QEMU's process exit code).
pub mod exit_code {
    /// Success.
    pub const SUCCESS: i32 = 0;
    /// A scenario failed (bad configuration, stuck encoder).
    pub const FAILED: i32 = 1;
    /// The panic handler ran.
    #[cfg_attr(feature = "panic-never", allow(dead_code))]
    pub const PANIC: i32 = 101;
    /// A hardware fault (HardFault, a RISC-V exception).
    pub const HARD_FAULT: i32 = 102;
    /// An exception or interrupt without a handler.
    pub const UNHANDLED: i32 = 103;
}

/// Terminate QEMU with `code` (semihosting SYS_EXIT_EXTENDED; QEMU exits with `code`).
pub fn exit(code: i32) -> ! {
    semihosting::process::exit(code)
}

/// The instruction-counter markers: `start` and `stop` (from [`Probe`]) bracket the map's work, [`report`]
/// logs the count since the last report (one per frame). Each is one instruction that executes as a no-op
/// and that the `insncount` QEMU plugin recognises (see `boards/qemu-mps2-an386/plugin/insncount.c`).
///
/// [`report`]: Markers::report
pub trait Markers: Probe + Default {
    /// Log the regions counted since the last report.
    fn report();
}

/// Stack high-water mark: the free stack is painted with a pattern, the deepest word that lost it is the
/// mark.
pub trait StackGauge {
    /// Bytes between the end of static RAM and the initial stack pointer.
    fn size(&self) -> usize;
    /// Deepest stack use (bytes from the top) since reset or since the last [`repaint`](Self::repaint).
    fn high_water(&self) -> usize;
    /// Paint the free stack again (below the current stack pointer), so that [`high_water`] measures only
    /// what runs after this call.
    ///
    /// [`high_water`]: Self::high_water
    fn repaint(&mut self);
}

/// Feature dimension (PCA-compressed).
pub const D: usize = 64;
const P: usize = packed_len(D);
/// Points generated per chunk (4.3 KiB of scratch).
pub const K: usize = 16;

#[cfg(not(feature = "forgetting"))]
type Clock = latentbki::forget::Timeless;
#[cfg(feature = "forgetting")]
type Clock = latentbki::forget::Fading;
/// Half-life of the forgetting build, in frames (ticks): the self-test's runs are 8 to 24 frames long.
#[cfg(feature = "forgetting")]
const HALF_LIFE_FRAMES: f32 = 4.0;
/// Voxels in the candidate view the forgetting build scores after each frame.
#[cfg(all(feature = "forgetting", not(feature = "explorer-view")))]
const VIEW_VOXELS: usize = 64;

/// Voxels the map holds: the self-test's RAM budget at this build's bytes per voxel (the forgetting build's
/// stamps make it 124 B instead of 120: 1,189 voxels instead of 1,228).
const CAPACITY: usize =
    selftest::SELF_TEST_MAP_BUDGET / LocalMap::<D, 1, P, HOT_VOXELS, Clock>::BYTES_PER_VOXEL;
const _: () = assert!(cfg!(feature = "forgetting") || CAPACITY == SELF_TEST_CAPACITY);

type Map = LocalMap<D, CAPACITY, P, HOT_VOXELS, Clock>;
type Robot =
    Mapper<D, CAPACITY, P, SELF_TEST_QUEUE_BYTES, SELF_TEST_FRAME_BYTES, HOT_VOXELS, Clock>;

/// The map and the encoder (≈ 170 KiB) live in a static (`.bss`), reconfigured in place for each
/// scenario; never on the stack.
static MAPPER: ConstStaticCell<Robot> = ConstStaticCell::new(Robot::EMPTY);
static CHUNK: ConstStaticCell<Chunk<D, K>> = ConstStaticCell::new(Chunk::ZERO);
/// The measurement build's view: 432 hits (6,912 B), in a static, as the stack has no room for them.
#[cfg(feature = "explorer-view")]
static VIEW_HITS: ConstStaticCell<explorer_view::Hits> =
    ConstStaticCell::new([(latentbki::key::VoxelKey::new(0, 0, 0), 0.0); explorer_view::HITS]);

/// Run every scenario of the self-test, streaming frames on `uart`, and report. Returns the exit code
/// ([`exit_code`]). Call once: the second call finds the statics taken and fails.
pub fn run<U, M, S>(uart: &mut U, markers: &mut M, stack: &mut S) -> i32
where
    U: embedded_io::Write<Error = Infallible>,
    M: Markers,
    S: StackGauge,
{
    // `try_take`: each static is handed out once, without a panic path.
    let (Some(mapper), Some(chunk)) = (MAPPER.try_take(), CHUNK.try_take()) else {
        return exit_code::FAILED;
    };
    #[cfg(feature = "explorer-view")]
    let Some(hits) = VIEW_HITS.try_take() else {
        return exit_code::FAILED;
    };
    for (s, scenario) in SELF_TEST.iter().enumerate() {
        // `ONLY_SCENARIO=N` at build time runs scenario N alone (a profile of one sensor pattern:
        // boards/profile-scenario.sh); unset, every scenario runs.
        if option_env!("ONLY_SCENARIO").is_some_and(|only| only != crate::scenario_name(s)) {
            continue;
        }
        if let Err(code) = run_scenario(
            s,
            scenario,
            mapper,
            chunk,
            uart,
            markers,
            stack,
            #[cfg(feature = "explorer-view")]
            hits,
        ) {
            return code;
        }
    }
    // Since the last repaint (before the last scenario's loop): that loop and the reports after it. With the
    // set-up and loop marks of every scenario, every stack byte the run used falls in some measured window.
    let tail_stack = stack.high_water();
    report!(
        "memory stack_size={} map_bytes={} bytes_per_voxel={} tail_stack_high_water={}",
        stack.size(),
        core::mem::size_of::<Map>(),
        Map::BYTES_PER_VOXEL,
        tail_stack
    );
    report!("done");
    exit_code::SUCCESS
}

/// Scenario `s`'s number as `ONLY_SCENARIO` names it.
fn scenario_name(s: usize) -> &'static str {
    const NAMES: [&str; 10] = ["0", "1", "2", "3", "4", "5", "6", "7", "8", "9"];
    NAMES.get(s).copied().unwrap_or("")
}

/// One scenario of the self-test: the map and the encoder configured in place, the run, a report.
#[inline(never)]
#[cfg_attr(feature = "explorer-view", allow(clippy::too_many_arguments))]
fn run_scenario<U, M, S>(
    s: usize,
    scenario: &Scenario,
    mapper: &mut Robot,
    chunk: &mut Chunk<D, K>,
    uart: &mut U,
    markers: &mut M,
    stack: &mut S,
    #[cfg(feature = "explorer-view")] hits: &mut explorer_view::Hits,
) -> Result<(), i32>
where
    U: embedded_io::Write<Error = Infallible>,
    M: Markers,
    S: StackGauge,
{
    configure(scenario, mapper)?;
    let setup_stack = stack.high_water();
    // From here on: the integrate-and-stream loop. Its own stack high-water mark is measured from a fresh
    // paint (the whole-run mark above includes the one-time set-up; see README "Firmware").
    stack.repaint();
    let on_frame = |i: u32, f: &FrameReport, m: &Map| {
        M::report();
        report!(
            "frame s={} i={} f={} points={} integrated={} voxels={}",
            s,
            i,
            scenario.filter_size,
            f.points,
            f.integrated,
            m.len()
        );
        // After the frame's line: its `view` line pairs with the next report marker.
        #[cfg(all(feature = "forgetting", not(feature = "explorer-view")))]
        score_view::<M>(s, m);
        #[cfg(feature = "explorer-view")]
        explorer_view::score::<M>(s, scenario, i, m, hits);
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
    let r = match selftest::run(scenario, mapper, chunk, uart, markers, on_frame) {
        Ok(r) => r,
        Err(RunError::Config(_) | RunError::NotConfigured | RunError::Stuck) => {
            return Err(exit_code::FAILED)
        }
        Err(RunError::Write(never)) => match never {},
    };
    let loop_stack = stack.high_water();
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
    #[cfg(not(feature = "forgetting"))]
    return scenario.configure(mapper).map_err(|_| exit_code::FAILED);
    #[cfg(feature = "forgetting")]
    return scenario
        .configure_forgetting(mapper, latentbki::forget::Forgetting::new(HALF_LIFE_FRAMES))
        .map_err(|_| exit_code::FAILED);
}

/// The forgetting build's second measurement: score one candidate view — the 8 × 8 voxels of a wall 1 m
/// ahead of the window's centre, one expected point each — against the map as it is after the frame
/// (`info_gain::view_score`, which `Mapper::view_score` runs), bracketed by the markers and reported as a
/// `view` line. Integers only on stdout (f32 formatting would cost ~10 KB of flash).
#[cfg(all(feature = "forgetting", not(feature = "explorer-view")))]
#[inline(never)]
fn score_view<M: Markers + Default>(s: usize, m: &Map) {
    use latentbki::key::VoxelKey;
    let c = m.centre();
    // Zeroed (a memclr), then filled row by row (y) and column by column (z) by a loop kept rolled (the
    // opaque `black_box`): `array::from_fn` is unrolled into half a KiB of flash.
    let mut hits = [(VoxelKey::default(), 0.0f32); VIEW_VOXELS];
    let mut key = VoxelKey::new(c.x + 10, c.y - 4, c.z - 4);
    for h in &mut hits {
        core::hint::black_box(());
        *h = (key, 1.0);
        key.z += 1;
        if key.z == c.z + 4 {
            (key.y, key.z) = (key.y + 1, c.z - 4);
        }
    }
    let mut probe = M::default();
    probe.start();
    let score = latentbki::info_gain::view_score(m.kernel(), m, m.prior().lambda, &hits);
    probe.stop();
    M::report();
    // The view's size in the literal, and no frame number (the line follows its frame's): two arguments
    // fewer to format (flash).
    const _: () = assert!(VIEW_VOXELS == 64);
    report!(
        "view s={} voxels=64 score_bits={}",
        s,
        score.map_or(0, f32::to_bits)
    );
}

#[cfg(not(feature = "panic-never"))]
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    semihosting::eprintln!("PANIC: {info}");
    exit(exit_code::PANIC)
}

/// With `panic-never` the panic handler refers to a symbol that exists nowhere: if the optimised firmware
/// still contains any path to a panic, the link fails and names the code that references it.
#[cfg(feature = "panic-never")]
#[panic_handler]
fn panic(_info: &core::panic::PanicInfo) -> ! {
    extern "Rust" {
        fn __the_integrate_and_stream_path_can_panic() -> !;
    }
    // SAFETY: never executed — the symbol is undefined on purpose, so a reachable panic is a link error.
    unsafe { __the_integrate_and_stream_path_can_panic() }
}
