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
    #[cfg(not(feature = "forgetting"))]
    if !int8_sums_check() {
        exit(exit_code::FAILED);
    }
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

/// The int8 sums as the M4 computes them (`asm!` DSP blocks: `latentbki::obs` on `thumbv7em`) against their
/// definition, before the self-test: points of random codes, about one in five holding a −128, which must
/// be refused and leave the sums as they were (added, then taken out again). The self-test's own codes
/// never hold −128, so the stream its host twin checks does not reach that path. Left out of the
/// forgetting build (flash).
#[cfg(not(feature = "forgetting"))]
#[inline(never)]
fn int8_sums_check() -> bool {
    use latentbki::obs::CodeSums;
    const D: usize = 64;
    let mut sums = CodeSums::<D>::EMPTY;
    let mut want = [(0i32, 0u32); D];
    let mut state = 0x2545_F491u32;
    let mut taken = 0;
    while !sums.is_full() {
        // Rolled (the opaque `black_box`): unrolled, these loops cost a kilobyte of flash.
        let mut codes = [0i8; D];
        for c in &mut codes {
            core::hint::black_box(());
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            *c = (state >> 24) as u8 as i8;
        }
        let ok = !codes.contains(&i8::MIN);
        if sums.add_checked(&codes) != ok {
            return false;
        }
        if ok {
            taken += 1;
            for ((s, q), &c) in want.iter_mut().zip(&codes) {
                core::hint::black_box(());
                let c = i32::from(c);
                (*s, *q) = (*s + c, *q + (c * c) as u32);
            }
        }
    }
    let mut i = 0;
    let mut same = sums.count == taken;
    sums.for_each_dim(|j, s, q| {
        same &= j == i && want.get(j) == Some(&(s, q));
        i += 1;
    });
    same && i == D
}
