//! The self-test's back channel: after each tick the "base station" acknowledges every frame the robot
//! wrote so far (a perfect link), as the bytes a real one would send — framed, CRC-checked — and the robot
//! reads them through its non-blocking acknowledgement reader, frees its kept frames and drains. So the
//! firmware runs protocol 3's whole robot side (kept frames, reading, checking and applying
//! acknowledgements) in CI without a second device, deterministically (the host twin writes the same
//! bytes). The receiver's side (sequence tracking, which frames to acknowledge) is tested on the host.

use latentbki::frame::ack::MAX_ACK_WIRE;
use latentbki::frame::Ack;
use latentbki::wire::PROTOCOL_VERSION;

/// The robot's end of the back channel: one pending acknowledgement's bytes.
pub struct Loopback {
    ack: [u8; MAX_ACK_WIRE],
    len: usize,
    read: usize,
    /// Acknowledgements produced.
    pub acks: u32,
}

impl Default for Loopback {
    fn default() -> Self {
        Self::new()
    }
}

impl Loopback {
    /// Nothing pending.
    pub const fn new() -> Self {
        Self {
            ack: [0; MAX_ACK_WIRE],
            len: 0,
            read: 0,
            acks: 0,
        }
    }

    /// Acknowledge every frame of `(robot, session)` numbered below `next_seq` (the robot's next number).
    pub fn acknowledge_all(&mut self, robot: u16, session: u32, next_seq: u32) {
        let Some(highest) = next_seq.checked_sub(1) else {
            return;
        };
        let received = if next_seq >= 64 {
            u64::MAX
        } else {
            (1u64 << next_seq) - 1
        };
        let ack = Ack {
            version: PROTOCOL_VERSION,
            robot,
            session,
            highest,
            received,
        };
        if let Some(n) = ack.encode(&mut self.ack) {
            self.len = n;
            self.read = 0;
            self.acks = self.acks.wrapping_add(1);
        }
    }
}

impl embedded_io::ErrorType for Loopback {
    type Error = core::convert::Infallible;
}

impl embedded_io::Read for Loopback {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let pending = self.ack.get(self.read..self.len).unwrap_or(&[]);
        let n = pending.len().min(buf.len());
        if let (Some(d), Some(s)) = (buf.get_mut(..n), pending.get(..n)) {
            d.copy_from_slice(s);
        }
        self.read += n;
        Ok(n)
    }
}

impl embedded_io::ReadReady for Loopback {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(self.read < self.len)
    }
}

#[cfg(feature = "async")]
impl embedded_io_async::Read for Loopback {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        embedded_io::Read::read(self, buf)
    }
}
