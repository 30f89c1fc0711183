//! The robot's loop over `embedded-io-async` (feature `async`) writes the bytes of the blocking one: the
//! self-test's run (`latentbki_selftest::run_async`: `Mapper::tick_async`, `poll_acks_async`, `drain_async`)
//! on a trivial executor against `latentbki_selftest::run`, over the scenarios the embassy board streams
//! (`boards/embassy-mps2-an386`, whose QEMU run against the blocking twin is
//! `boards/firmware-tests/tests/embassy_qemu.rs`).

use latentbki::quant::packed_len;
use latentbki::Mapper;
use latentbki_selftest::{
    self as selftest, Chunk, SELF_TEST, SELF_TEST_CAPACITY, SELF_TEST_FRAME_BYTES,
    SELF_TEST_QUEUE_BYTES,
};
use std::future::Future;
use std::pin::pin;
use std::task::{Context, Poll, Waker};

use host_sim::sim::vocab::D;
type Robot =
    Mapper<D, SELF_TEST_CAPACITY, { packed_len(D) }, SELF_TEST_QUEUE_BYTES, SELF_TEST_FRAME_BYTES>;

/// The board's scenarios (`boards/embassy-mps2-an386/src/main.rs`, `SCENARIOS`).
const SCENARIOS: [usize; 2] = [0, 2];

/// A UART into a byte vector, blocking and async alike.
#[derive(Default)]
struct Uart(Vec<u8>);
impl embedded_io::ErrorType for Uart {
    type Error = core::convert::Infallible;
}
impl embedded_io::Write for Uart {
    fn write(&mut self, b: &[u8]) -> Result<usize, Self::Error> {
        self.0.extend_from_slice(b);
        Ok(b.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}
impl embedded_io_async::Write for Uart {
    async fn write(&mut self, b: &[u8]) -> Result<usize, Self::Error> {
        self.0.extend_from_slice(b);
        Ok(b.len())
    }
    async fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// Run a future that never waits for anything outside itself (everything here is ready at once).
fn block_on<F: Future>(f: F) -> F::Output {
    let mut f = pin!(f);
    let mut cx = Context::from_waker(Waker::noop());
    loop {
        if let Poll::Ready(v) = f.as_mut().poll(&mut cx) {
            return v;
        }
    }
}

/// The blocking host twin's UART bytes over the board's scenarios.
fn twin(run_async: bool) -> Vec<u8> {
    let mut mapper: Box<Robot> = Box::new(Robot::EMPTY);
    let mut chunk = Box::new(Chunk::<D, 16>::ZERO);
    let mut uart = Uart::default();
    for &i in &SCENARIOS {
        let scenario = &SELF_TEST[i];
        scenario.configure(&mut mapper).unwrap();
        if run_async {
            block_on(selftest::run_async(
                scenario,
                &mut mapper,
                &mut chunk,
                &mut uart,
                &mut (),
                |_, _, _| {},
            ))
            .unwrap();
        } else {
            selftest::run(
                scenario,
                &mut mapper,
                &mut chunk,
                &mut uart,
                &mut (),
                |_, _, _| {},
            )
            .unwrap();
        }
    }
    uart.0
}

#[test]
fn the_async_loop_writes_the_bytes_of_the_blocking_one() {
    let blocking = twin(false);
    assert!(blocking.len() > 10_000, "{} bytes", blocking.len());
    assert!(twin(true) == blocking, "the async run's bytes differ");
}
