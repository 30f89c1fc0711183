//! The self-test's back channel: its own frames, as they are written to the UART, are decoded again (COBS,
//! CRC, header) and their sequence numbers tracked as a receiver does, and the acknowledgements that
//! produces come back to the robot as bytes to read — so the firmware runs protocol 3's whole ack path
//! (kept frames, non-blocking reads, freeing) in CI without a second device. Deterministic, so the host
//! twin writes the same bytes. (It acknowledges by sequence number only, without the receiver's
//! validation of every summary: that would put the summary decoder, ~20 KB, into the firmware's flash.)

use latentbki::frame::ack::MAX_ACK_WIRE;
use latentbki::frame::{Ack, Feed, FrameDecoder, SeqTracker};
use latentbki::wire::FrameHeader;

/// A writer that also hands every byte to a receiver; acknowledgements wait to be read.
pub struct Loopback<'w, W, const N: usize> {
    /// The UART.
    pub uart: &'w mut W,
    decoder: FrameDecoder<N>,
    seq: SeqTracker,
    /// The newest acknowledgement, on the wire, and how much of it was read.
    ack: [u8; MAX_ACK_WIRE],
    ack_len: usize,
    ack_read: usize,
    /// Acknowledgements produced.
    pub acks: u32,
}

impl<'w, W: embedded_io::Write, const N: usize> Loopback<'w, W, N> {
    /// A loopback in front of `uart` (the receiver adopts the first session header it sees).
    pub fn new(uart: &'w mut W) -> Self {
        Self {
            uart,
            decoder: FrameDecoder::new(),
            seq: SeqTracker::default(),
            ack: [0; MAX_ACK_WIRE],
            ack_len: 0,
            ack_read: 0,
            acks: 0,
        }
    }

    fn receive(&mut self, mut bytes: &[u8]) {
        let mut newest: Option<Ack> = None;
        loop {
            bytes = match self.decoder.feed(bytes) {
                Feed::NeedMore => break,
                Feed::Error { rest, .. } => rest,
                Feed::Frame { body, rest } => {
                    if let Ok((h, _)) = postcard::take_from_bytes::<FrameHeader>(body) {
                        self.seq.accept(h.seq);
                        newest = Ack::of(h.robot, h.session, &self.seq);
                    }
                    rest
                }
            };
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

impl<W: embedded_io::Write, const N: usize> embedded_io::ErrorType for Loopback<'_, W, N> {
    type Error = W::Error;
}

impl<W: embedded_io::Write, const N: usize> embedded_io::Write for Loopback<'_, W, N> {
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
impl<W: embedded_io::Write, const N: usize> embedded_io::Read for Loopback<'_, W, N> {
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

impl<W: embedded_io::Write, const N: usize> embedded_io::ReadReady for Loopback<'_, W, N> {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(self.ack_read < self.ack_len)
    }
}
