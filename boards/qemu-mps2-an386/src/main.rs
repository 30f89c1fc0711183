//! LatentBKI firmware for QEMU `mps2-an386` (Cortex-M4F with FPU).
//!
//! The same self-test program as every QEMU board (`latentbki-selftest-firmware`): the self-test's
//! scenarios integrated by the core's `Mapper` into a quantized `LocalMap` in a static, evicted voxels
//! streamed as frames over UART0. The host twin (`host-sim/tests/firmware_qemu.rs`) runs the same core code
//! and compares. Here only the board: the MPS2 UART, stack gauge and markers (shared with the an385), the
//! fault handlers, the defmt transport.
#![no_std]
#![no_main]

use latentbki_selftest_firmware::{self as firmware, exit, exit_code, mps2};

#[cfg(feature = "defmt")]
use defmt_semihosting as _;

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
