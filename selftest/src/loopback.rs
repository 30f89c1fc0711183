//! The self-test's back channel: its own frames, as they are written to the UART, go through the core's
//! receiver, and the acknowledgements it produces come back to the robot as bytes to read — so the
//! firmware runs protocol 3's whole ack path (kept frames, non-blocking reads, freeing) in CI without a
//! second device. Deterministic, so the host twin writes the same bytes.

use latentbki::frame::ack::MAX_ACK_WIRE;
use latentbki::frame::Ack;
use latentbki::receiver::{Receipt, Receiver, Sessions};

/// A writer that also hands every byte to a receiver; acknowledgements wait to be read.
pub struct Loopback<'w, W, const D: usize, const N: usize> {
    /// The UART.
    pub uart: &'w mut W,
    receiver: Receiver<D, N>,
    sessions: Sessions<1>,
    /// The newest acknowledgement, on the wire, and how much of it was read.
    ack: [u8; MAX_ACK_WIRE],
    ack_len: usize,
    ack_read: usize,
    /// Acknowledgements produced.
    pub acks: u32,
}

impl<'w, W: embedded_io::Write, const D: usize, const N: usize> Loopback<'w, W, D, N> {
    /// A loopback in front of `uart` (the receiver adopts the first session header it sees).
    pub fn new(uart: &'w mut W) -> Self {
        Self {
            uart,
            receiver: Receiver::new(None),
            sessions: Sessions::new(),
            ack: [0; MAX_ACK_WIRE],
            ack_len: 0,
            ack_read: 0,
            acks: 0,
        }
    }

    fn receive(&mut self, mut bytes: &[u8]) {
        let mut newest: Option<Ack> = None;
        loop {
            let (ack, rest) = match self.receiver.feed(bytes, &mut self.sessions) {
                Receipt::NeedMore => break,
                Receipt::Accepted { frame, rest } => (frame.ack, rest),
                Receipt::Refused { ack, rest, .. } => (ack, rest),
            };
            if ack.is_some() {
                newest = ack;
            }
            bytes = rest;
        }
        // A newer acknowledgement repeats everything an unread older one said: it replaces it.
        if let Some(a) = newest {
            if let Some(n) = a.encode(&mut self.ack) {
                self.ack_len = n;
                self.ack_read = 0;
                self.acks = self.acks.wrapping_add(1);
            }
        }
    }
}

impl<W: embedded_io::Write, const D: usize, const N: usize> embedded_io::ErrorType
    for Loopback<'_, W, D, N>
{
    type Error = W::Error;
}

impl<W: embedded_io::Write, const D: usize, const N: usize> embedded_io::Write
    for Loopback<'_, W, D, N>
{
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        let n = self.uart.write(buf)?;
        self.receive(buf.get(..n).unwrap_or(&[]));
        Ok(n)
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        self.uart.flush()
    }
}

/// The robot's end of the back channel: the pending acknowledgement's bytes.
impl<W: embedded_io::Write, const D: usize, const N: usize> embedded_io::Read
    for Loopback<'_, W, D, N>
{
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let pending = self.ack.get(self.ack_read..self.ack_len).unwrap_or(&[]);
        let n = pending.len().min(buf.len());
        if let (Some(d), Some(s)) = (buf.get_mut(..n), pending.get(..n)) {
            d.copy_from_slice(s);
        }
        self.ack_read += n;
        Ok(n)
    }
}

impl<W: embedded_io::Write, const D: usize, const N: usize> embedded_io::ReadReady
    for Loopback<'_, W, D, N>
{
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(self.ack_read < self.ack_len)
    }
}
