//! Board support for QEMU `mps2-an386` (Cortex-M4F): CMSDK UART0, semihosting exit codes, fault and panic
//! handlers, stack high-water mark, and the instruction-counter markers.

/// Exit codes reported through semihosting (QEMU's process exit code).
pub mod exit_code {
    /// Success.
    pub const SUCCESS: i32 = 0;
    /// A scenario failed (bad configuration, stuck encoder).
    pub const FAILED: i32 = 1;
    /// The panic handler ran.
    #[cfg_attr(feature = "panic-never", allow(dead_code))]
    pub const PANIC: i32 = 101;
    /// HardFault.
    pub const HARD_FAULT: i32 = 102;
    /// An exception or interrupt without a handler.
    pub const UNHANDLED: i32 = 103;
}

/// Terminate QEMU with `code` (semihosting SYS_EXIT_EXTENDED).
pub fn exit(code: i32) -> ! {
    semihosting::process::exit(code)
}

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
    /// UART0 of mps2-an386, transmitter enabled. Call once: it takes the peripheral.
    pub fn uart0() -> Self {
        // SAFETY: 0x4000_4000 is UART0's register block on mps2-an386 (AN386 memory map); these are aligned
        // 32-bit MMIO writes, and only this driver touches UART0 (main creates it once).
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

/// Stack high-water mark: cortex-m-rt's `paint-stack` fills the stack with a pattern at reset.
pub mod stack {
    extern "C" {
        static _stack_start: u32; // initial SP (top of the stack)
        static _stack_end: u32; // lowest address of the painted region (end of .bss/.uninit)
    }

    /// Bytes between the end of static RAM and the initial stack pointer.
    pub fn size() -> usize {
        // Only the addresses of the linker symbols are taken, never their contents.
        let (top, bot) = (
            &raw const _stack_start as usize,
            &raw const _stack_end as usize,
        );
        top - bot
    }

    /// Deepest stack use since reset (bytes): from the bottom, the first word that lost the paint.
    pub fn high_water() -> usize {
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

    /// Paint the free stack again (below the current stack pointer), so that
    /// [`high_water_since_repaint`] measures only what runs after this call.
    #[inline(never)]
    pub fn repaint() {
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

    /// Deepest stack use (bytes from the top) since the last [`repaint`].
    pub fn high_water_since_repaint() -> usize {
        high_water()
    }
}

/// Markers for the `insncount` QEMU plugin: Thumb hints 0xBFA0 / 0xBFB0 / 0xBFC0, unallocated, so they
/// execute as NOP on a Cortex-M and in QEMU. The plugin counts the instructions strictly between a start
/// and the next stop, sums the regions, and logs the sum at each report marker.
pub struct Markers;

impl latentbki_selftest::Probe for Markers {
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

impl Markers {
    /// Log the regions counted since the last report (one line per frame).
    #[inline(always)]
    pub fn report(&mut self) {
        // SAFETY: as above.
        unsafe { core::arch::asm!("hint #12", options(nostack, preserves_flags)) }
    }
}

#[cortex_m_rt::exception]
unsafe fn HardFault(_frame: &cortex_m_rt::ExceptionFrame) -> ! {
    exit(exit_code::HARD_FAULT)
}

#[cortex_m_rt::exception]
unsafe fn DefaultHandler(_irqn: i16) {
    exit(exit_code::UNHANDLED)
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
