//! The robot's loop over `embedded-io-async` on embassy, end to end: `boards/embassy-mps2-an386` runs the
//! self-test's 8×8 ToF and f = 3 depth scenarios in QEMU (Cortex-M4F) — `Mapper::tick_async` on the UART,
//! the loopback's acknowledgements read back with `Mapper::poll_acks_async`, `Mapper::drain_async` on an
//! embassy executor — and its UART must carry exactly the bytes the blocking host twin
//! (`latentbki_selftest::run`) writes. (On the host, the async run against the blocking one:
//! `host-sim/tests/stream_embassy.rs`.) The ELF is `LATENTBKI_EMBASSY_ELF`'s if set, else built; what a
//! machine without QEMU does is the crate's rule (`latentbki_firmware_tests`).

use latentbki::quant::packed_len;
use latentbki::Mapper;
use latentbki_firmware_tests::EMBASSY_AN386;
use latentbki_selftest::{
    self as selftest, Chunk, SELF_TEST, SELF_TEST_CAPACITY, SELF_TEST_FRAME_BYTES,
    SELF_TEST_QUEUE_BYTES,
};

const D: usize = 64;
type Robot =
    Mapper<D, SELF_TEST_CAPACITY, { packed_len(D) }, SELF_TEST_QUEUE_BYTES, SELF_TEST_FRAME_BYTES>;

/// The board's scenarios (`boards/embassy-mps2-an386/src/main.rs`, `SCENARIOS`).
const SCENARIOS: [usize; 2] = [0, 2];

#[test]
#[cfg_attr(
    latentbki_no_qemu,
    ignore = "LATENTBKI_NO_QEMU is set: the QEMU firmware tests are opted out"
)]
fn embassy_firmware_in_qemu_streams_the_host_twins_bytes() {
    if let Err(line) = EMBASSY_AN386.ready() {
        panic!("{line}");
    }
    let elf = EMBASSY_AN386.firmware_elf();
    let (uart, stdout) = EMBASSY_AN386.run_firmware(&elf);
    // The blocking host twin over the same scenarios.
    let mut mapper: Box<Robot> = Box::new(Robot::EMPTY);
    let mut chunk = Box::new(Chunk::<D, 16>::ZERO);
    let mut twin = vec![0u8; 4 << 20];
    let capacity = twin.len();
    let mut out: &mut [u8] = &mut twin[..];
    for &i in &SCENARIOS {
        let scenario = &SELF_TEST[i];
        scenario.configure(&mut mapper).unwrap();
        selftest::run(
            scenario,
            &mut mapper,
            &mut chunk,
            &mut out,
            &mut (),
            |_, _, _| {},
        )
        .unwrap();
    }
    let written = capacity - out.len();
    twin.truncate(written);
    assert!(twin.len() > 10_000, "{} bytes", twin.len());
    assert_eq!(uart.len(), twin.len(), "UART bytes\n{stdout}");
    assert!(
        uart == twin,
        "the embassy firmware's stream differs from the host twin's"
    );
}
