//! LatentBKI on embassy, in QEMU `mps2-an386` (Cortex-M4F): the self-test streamed over
//! `embedded-io-async`, its acknowledgements read back the same way.
//!
//! What a user's embassy firmware does, on the one Arm board QEMU emulates with a UART: one task owns the
//! `Mapper` (a static) and, per sensor frame, integrates, awaits `Mapper::tick_async` on the UART and
//! reads the acknowledgements that are ready with `Mapper::poll_acks_async`; at the end it awaits
//! `Mapper::drain_within_async`. The back channel is the self-test's loopback (a perfect base station:
//! there is no second device in CI). The scenarios and sizes are the self-test's, so the UART carries the
//! bytes the blocking host twin writes (`host-sim/tests/stream_embassy.rs` checks it).
//!
//! The MPS2 UART has no embassy HAL: [`AsyncUart`] adapts the shared CMSDK driver.
#![no_std]
#![no_main]

use embassy_executor::{Executor, Spawner};
use latentbki::quant::packed_len;
use latentbki::Mapper;
use latentbki_selftest::{
    run_async, Chunk, Scenario, SELF_TEST, SELF_TEST_CAPACITY, SELF_TEST_FRAME_BYTES,
    SELF_TEST_QUEUE_BYTES,
};
use latentbki_selftest_firmware::{exit, exit_code, mps2};
use static_cell::{ConstStaticCell, StaticCell};

const D: usize = 64;
type Robot =
    Mapper<D, SELF_TEST_CAPACITY, { packed_len(D) }, SELF_TEST_QUEUE_BYTES, SELF_TEST_FRAME_BYTES>;

/// The scenarios this board streams (the host twin runs the same): the 8×8 ToF (144 frames, 2 KiB a tick)
/// and the 4,096-point depth frames at f = 3.
pub const SCENARIOS: [usize; 2] = [0, 2];

static MAPPER: ConstStaticCell<Robot> = ConstStaticCell::new(Robot::EMPTY);
static CHUNK: ConstStaticCell<Chunk<D, 16>> = ConstStaticCell::new(Chunk::ZERO);
static EXECUTOR: StaticCell<Executor> = StaticCell::new();

/// The CMSDK UART as an `embedded_io_async::Write`. QEMU's transmitter takes every byte at once, so the
/// shared blocking driver does; on a real part the HAL's async UART (DMA, interrupt) takes its place.
struct AsyncUart(mps2::Uart);

impl embedded_io_async::ErrorType for AsyncUart {
    type Error = core::convert::Infallible;
}

impl embedded_io_async::Write for AsyncUart {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        for &b in buf {
            self.0.write_byte(b);
        }
        Ok(buf.len())
    }
    async fn flush(&mut self) -> Result<(), Self::Error> {
        embedded_io::Write::flush(&mut self.0)
    }
}

#[embassy_executor::task]
async fn selftest(mapper: &'static mut Robot, chunk: &'static mut Chunk<D, 16>) {
    let mut uart = AsyncUart(mps2::Uart::uart0());
    for &i in &SCENARIOS {
        let Some(scenario): Option<&Scenario> = SELF_TEST.get(i) else {
            exit(exit_code::FAILED)
        };
        if scenario.configure(mapper).is_err() {
            exit(exit_code::FAILED);
        }
        let Ok(r) = run_async(scenario, mapper, chunk, &mut uart, &mut (), |_, _, _| {}).await
        else {
            exit(exit_code::FAILED)
        };
        semihosting::println!(
            "{}: {} points integrated, {} frames sent, {} acknowledged, {} re-sent",
            scenario.name,
            r.integrated,
            r.link.frames_sent,
            r.link.acked,
            r.link.resent
        );
    }
    semihosting::println!("done");
    exit(exit_code::SUCCESS)
}

#[cortex_m_rt::entry]
fn main() -> ! {
    let executor = EXECUTOR.init(Executor::new());
    executor.run(|spawner: Spawner| {
        let task = selftest(MAPPER.take(), CHUNK.take());
        if spawner.spawn(task).is_err() {
            exit(exit_code::FAILED);
        }
    })
}

#[cortex_m_rt::exception]
unsafe fn HardFault(_frame: &cortex_m_rt::ExceptionFrame) -> ! {
    exit(exit_code::HARD_FAULT)
}

#[cortex_m_rt::exception]
unsafe fn DefaultHandler(_irqn: i16) {
    exit(exit_code::UNHANDLED)
}
