//! LatentBKI firmware for riscv32imac (no FPU), run on QEMU `virt`.
//!
//! The same self-test program as every QEMU board (`latentbki-selftest-firmware`): its UART stream must
//! equal the host twin's (`host-sim/tests/firmware_qemu.rs`), and `boards/measure.sh` counts its
//! instructions per point. Here only the board: the NS16550A UART, the stack gauge, the RISC-V markers of the
//! instruction counter, the trap handlers.
#![no_std]
#![no_main]

use latentbki_selftest_firmware::{
    self as firmware, embedded_io, exit, exit_code, Markers, Probe, StackGauge,
};

#[riscv_rt::entry]
fn main() -> ! {
    // riscv-rt does not paint the stack: paint it here, where almost none of it is in use yet.
    let mut stack = PaintedStack;
    stack.repaint();
    let mut uart = Uart::uart0();
    exit(firmware::run(&mut uart, &mut HintMarkers, &mut stack))
}

/// TX-only driver for virt's NS16550A UART0 (QEMU needs no baud-rate set-up).
struct Uart {
    base: usize,
}

const UART0_BASE: usize = 0x1000_0000;
const THR: usize = 0; // transmit holding register (write)
const LSR: usize = 5; // line status register
const LSR_THR_EMPTY: u8 = 1 << 5;

impl Uart {
    /// UART0 of virt. Call once: it takes the peripheral.
    fn uart0() -> Self {
        Self { base: UART0_BASE }
    }

    fn tx_ready(&self) -> bool {
        // SAFETY: byte read of the LSR register of virt's UART0 (0x1000_0000, QEMU's virt memory map), which
        // only this driver touches; reading LSR has no side effect on the transmitter.
        unsafe { core::ptr::read_volatile((self.base + LSR) as *const u8) & LSR_THR_EMPTY != 0 }
    }

    fn write_byte(&mut self, b: u8) {
        while !self.tx_ready() {}
        // SAFETY: byte write of the THR register of the UART this driver owns.
        unsafe { core::ptr::write_volatile((self.base + THR) as *mut u8, b) }
    }
}

impl embedded_io::ErrorType for Uart {
    type Error = core::convert::Infallible;
}

impl embedded_io::Write for Uart {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        for &b in buf {
            self.write_byte(b);
        }
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        while !self.tx_ready() {}
        Ok(())
    }
}

/// The stack gauge: the free stack painted with a pattern (cortex-m-rt's value), scanned from the bottom.
struct PaintedStack;

const PAINT: u32 = 0xCCCC_CCCC;

extern "C" {
    static _stack_start: u32; // initial SP (top of the stack), riscv-rt's
    static __euninit: u32; // end of .bss/.uninit: the lowest address the stack may reach (riscv-rt's link.x)
}

impl StackGauge for PaintedStack {
    fn size(&self) -> usize {
        // Only the addresses of the linker symbols are taken, never their contents.
        &raw const _stack_start as usize - &raw const __euninit as usize
    }

    fn high_water(&self) -> usize {
        let (top, mut p) = (
            &raw const _stack_start as usize,
            &raw const __euninit as usize,
        );
        while p < top {
            // SAFETY: [__euninit, _stack_start) is RAM owned by the stack, word aligned; reading it is
            // harmless (volatile so the scan is not optimised on the assumption that nothing wrote there).
            if unsafe { core::ptr::read_volatile(p as *const u32) } != PAINT {
                break;
            }
            p += 4;
        }
        top - p
    }

    #[inline(never)]
    fn repaint(&mut self) {
        let sp: usize;
        // SAFETY: reads the stack pointer into a register; nothing else.
        unsafe { core::arch::asm!("mv {}, sp", out(reg) sp, options(nostack, preserves_flags)) };
        // 64 bytes of margin below the stack pointer for this function's own (leaf) use.
        let (bot, sp) = (&raw const __euninit as usize, sp - 64);
        let mut p = bot;
        while p < sp {
            // SAFETY: [__euninit, sp − 64) is free stack: below the stack pointer, owned by no live frame and
            // by no static (.bss/.uninit end at __euninit). No interrupt is enabled, so nothing else uses it
            // concurrently; word-aligned volatile writes.
            unsafe { core::ptr::write_volatile(p as *mut u32, PAINT) };
            p += 4;
        }
    }
}

/// Markers for the `insncount` QEMU plugin: `addi x0, x0, 10/11/12` (0x00a00013, 0x00b00013, 0x00c00013),
/// HINT encodings that execute as no-ops. Written with `.insn` so that the assembler keeps them 32-bit
/// (the C extension would otherwise compress them to `c.nop` hints).
#[derive(Default)]
struct HintMarkers;

impl Probe for HintMarkers {
    #[inline(always)]
    fn start(&mut self) {
        // SAFETY: a no-op hint; no register, memory or stack touched.
        unsafe {
            core::arch::asm!(
                ".insn i 0x13, 0, x0, x0, 10",
                options(nostack, preserves_flags)
            )
        }
    }
    #[inline(always)]
    fn stop(&mut self) {
        // SAFETY: as above.
        unsafe {
            core::arch::asm!(
                ".insn i 0x13, 0, x0, x0, 11",
                options(nostack, preserves_flags)
            )
        }
    }
}

impl Markers for HintMarkers {
    #[inline(always)]
    fn report() {
        // SAFETY: as above.
        unsafe {
            core::arch::asm!(
                ".insn i 0x13, 0, x0, x0, 12",
                options(nostack, preserves_flags)
            )
        }
    }
}

/// Any exception (illegal instruction, access fault…): exit with the fault code.
#[unsafe(export_name = "ExceptionHandler")]
fn exception_handler(_frame: &riscv_rt::TrapFrame) -> ! {
    exit(exit_code::HARD_FAULT)
}

/// An interrupt (none is enabled).
#[unsafe(export_name = "DefaultHandler")]
fn default_handler() -> ! {
    exit(exit_code::UNHANDLED)
}
