//! LatentBKI firmware for thumbv6m (the Cortex-M0/M0+ instruction set: no FPU), run on QEMU `mps2-an385`.
//!
//! The same self-test program as every QEMU board (`latentbki-selftest-firmware`): its UART0 stream must
//! equal the host twin's (`host-sim/tests/firmware_qemu.rs`), and `boards/measure.sh` counts its
//! instructions per point. Here only the board: the MPS2 UART, stack gauge and markers, the fault handlers.
#![no_std]
#![no_main]

use latentbki_selftest_firmware::{self as firmware, exit, exit_code, mps2};

#[cortex_m_rt::entry]
fn main() -> ! {
    let mut uart = mps2::Uart::uart0();
    exit(firmware::run(
        &mut uart,
        &mut mps2::ThumbMarkers,
        &mut mps2::PaintedStack,
    ))
}

#[cortex_m_rt::exception]
unsafe fn HardFault(_frame: &cortex_m_rt::ExceptionFrame) -> ! {
    exit(exit_code::HARD_FAULT)
}

#[cortex_m_rt::exception]
unsafe fn DefaultHandler(_irqn: i16) {
    exit(exit_code::UNHANDLED)
}
