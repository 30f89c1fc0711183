//! Board support shared by QEMU's Arm MPS2 machines (`mps2-an385`, a Cortex-M3 that runs the thumbv6m
//! build, and `mps2-an386`, a Cortex-M4F): the CMSDK APB UART0 at the same address on both, the stack gauge
//! of cortex-m-rt's `paint-stack`, and the Thumb hint markers of the instruction counter.

use latentbki_selftest::Probe;

/// Minimal TX-only driver for the CMSDK APB UART.
pub struct Uart {
    base: usize,
}

const UART0_BASE: usize = 0x4000_4000;
const DATA: usize = 0x00;
const STATE: usize = 0x04;
const CTRL: usize = 0x08;
const BAUDDIV: usize = 0x10;
const STATE_TX_FULL: u32 = 1;
const CTRL_TX_EN: u32 = 1;

impl Uart {
    /// UART0 of mps2-an385/an386, transmitter enabled. Call once: it takes the peripheral.
    pub fn uart0() -> Self {
        // SAFETY: 0x4000_4000 is UART0's register block on mps2-an385 and mps2-an386 (AN385/AN386 memory
        // maps); these are aligned 32-bit MMIO writes, and only this driver touches UART0 (main creates it
        // once).
        unsafe {
            // BAUDDIV must be ≥ 16 or the UART counts as misconfigured.
            core::ptr::write_volatile((UART0_BASE + BAUDDIV) as *mut u32, 16);
            core::ptr::write_volatile((UART0_BASE + CTRL) as *mut u32, CTRL_TX_EN);
        }
        Self { base: UART0_BASE }
    }

    fn tx_full(&self) -> bool {
        // SAFETY: aligned read of the STATE register of the UART this driver owns.
        unsafe { core::ptr::read_volatile((self.base + STATE) as *const u32) & STATE_TX_FULL != 0 }
    }

    /// Send one byte (waits while the transmit buffer is full).
    pub fn write_byte(&mut self, b: u8) {
        while self.tx_full() {}
        // SAFETY: aligned write of the DATA register of the UART this driver owns.
        unsafe { core::ptr::write_volatile((self.base + DATA) as *mut u32, u32::from(b)) }
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
        while self.tx_full() {}
        Ok(())
    }
}

/// The stack gauge: cortex-m-rt's `paint-stack` fills the stack with a pattern at reset.
pub struct PaintedStack;

extern "C" {
    static _stack_start: u32; // initial SP (top of the stack)
    static _stack_end: u32; // lowest address of the painted region (end of .bss/.uninit)
}

impl crate::StackGauge for PaintedStack {
    fn size(&self) -> usize {
        // Only the addresses of the linker symbols are taken, never their contents.
        let (top, bot) = (
            &raw const _stack_start as usize,
            &raw const _stack_end as usize,
        );
        top - bot
    }

    fn high_water(&self) -> usize {
        let (top, mut p) = (
            &raw const _stack_start as usize,
            &raw const _stack_end as usize,
        );
        while p < top {
            // SAFETY: [_stack_end, _stack_start) is RAM owned by the stack, word aligned; reading it is
            // harmless (volatile so the scan is not optimised on the assumption that nothing wrote there).
            if unsafe { core::ptr::read_volatile(p as *const u32) }
                != cortex_m_rt::STACK_PAINT_VALUE
            {
                break;
            }
            p += 4;
        }
        top - p
    }

    #[inline(never)]
    fn repaint(&mut self) {
        let bot = &raw const _stack_end as usize;
        // 64 bytes of margin below the stack pointer for this function's own (leaf) use.
        let sp = cortex_m::register::msp::read() as usize - 64;
        let mut p = bot;
        while p < sp {
            // SAFETY: [_stack_end, sp − 64) is free stack: below the stack pointer, owned by no live frame
            // and by no static (.bss/.data end at _stack_end). No interrupt handler is enabled, so nothing
            // else uses it concurrently; word-aligned volatile writes.
            unsafe { core::ptr::write_volatile(p as *mut u32, cortex_m_rt::STACK_PAINT_VALUE) };
            p += 4;
        }
    }
}

/// Markers for the `insncount` QEMU plugin: Thumb hints 0xBFA0 / 0xBFB0 / 0xBFC0, unallocated, so they
/// execute as NOP on a Cortex-M and in QEMU. The plugin counts the instructions strictly between a start
/// and the next stop, sums the regions, and logs the sum at each report marker.
#[derive(Default)]
pub struct ThumbMarkers;

impl Probe for ThumbMarkers {
    #[inline(always)]
    fn start(&mut self) {
        // SAFETY: an architectural NOP hint; no memory, stack or flags touched.
        unsafe { core::arch::asm!("hint #10", options(nostack, preserves_flags)) }
    }
    #[inline(always)]
    fn stop(&mut self) {
        // SAFETY: as above.
        unsafe { core::arch::asm!("hint #11", options(nostack, preserves_flags)) }
    }
}

impl crate::Markers for ThumbMarkers {
    #[inline(always)]
    fn report() {
        // SAFETY: as above.
        unsafe { core::arch::asm!("hint #12", options(nostack, preserves_flags)) }
    }
}
