//! Acknowledgements (protocol 3): the base station tells a robot, over the link's other direction, which
//! frames it applied; the robot reads them without blocking and frees or re-sends its kept frames.
//!
//! An acknowledgement is framed like a frame (`0x00 | COBS(body | crc32) | 0x00`) so the same decoder
//! re-synchronises after damage. Its body is the receiver's sequence state for one session: the highest
//! sequence number received and a 64-bit map of the 64 numbers ending there — it repeats everything the
//! last one said, so a lost acknowledgement costs nothing but time. The robot trusts none of it until it
//! checked it: CRC, version, length, and its own robot and session ids; everything else is refused and
//! counted ([`AckStats`]).

use super::decoder::{Feed, FrameDecoder};
use super::seq::SeqTracker;
use super::wire_len;
use crate::wire::{CRC32, PROTOCOL_VERSION};
use serde::{Deserialize, Serialize};

/// One acknowledgement: "of robot `robot`'s session `session`, I have frame `highest` and, for each bit i
/// of `received`, frame `highest − i`".
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Ack {
    /// Protocol version ([`PROTOCOL_VERSION`]).
    pub version: u8,
    /// The robot acknowledged.
    pub robot: u16,
    /// Its session.
    pub session: u32,
    /// Highest sequence number received.
    pub highest: u32,
    /// Bit i set: frame `highest − i` was received (bit 0 is always set).
    pub received: u64,
}

/// Largest body of an acknowledgement (postcard: 1 + 3 + 5 + 5 + 10 bytes).
pub const MAX_ACK_BODY: usize = 24;
/// Largest acknowledgement on the wire (delimiters, COBS, CRC included).
pub const MAX_ACK_WIRE: usize = wire_len(MAX_ACK_BODY);

impl Ack {
    /// The acknowledgement of a session's sequence state (`None` before its first frame).
    pub fn of(robot: u16, session: u32, seq: &SeqTracker) -> Option<Self> {
        Some(Self {
            version: PROTOCOL_VERSION,
            robot,
            session,
            highest: seq.highest()?,
            received: seq.window(),
        })
    }

    /// Write the acknowledgement as it goes on the wire into `out`; returns its length (≤
    /// [`MAX_ACK_WIRE`]), or `None` if `out` is too small.
    pub fn encode(&self, out: &mut [u8]) -> Option<usize> {
        let mut body = [0u8; MAX_ACK_BODY + 4];
        let mut n = 0;
        *body.get_mut(0)? = self.version;
        n += 1;
        for v in [
            u64::from(self.robot),
            u64::from(self.session),
            u64::from(self.highest),
            self.received,
        ] {
            n += put_varint(body.get_mut(n..)?, v)?;
        }
        let crc = CRC32.checksum(body.get(..n)?);
        body.get_mut(n..n + 4)?.copy_from_slice(&crc.to_le_bytes());
        let (first, rest) = out.split_first_mut()?;
        *first = 0;
        let m = cobs::try_encode(body.get(..n + 4)?, rest).ok()?;
        *rest.get_mut(m)? = 0;
        Some(m + 2)
    }

    /// Parse a checked body (CRC removed). `None` if it is not exactly one acknowledgement of this version.
    pub fn parse(body: &[u8]) -> Option<Self> {
        let (&version, mut rest) = body.split_first()?;
        let mut next = |max_bytes: usize, max: u64| {
            let (v, r) = take_varint(rest, max_bytes)?;
            rest = r;
            (v <= max).then_some(v)
        };
        let ack = Self {
            version,
            robot: next(3, u64::from(u16::MAX))? as u16,
            session: next(5, u64::from(u32::MAX))? as u32,
            highest: next(5, u64::from(u32::MAX))? as u32,
            received: next(10, u64::MAX)?,
        };
        (rest.is_empty() && ack.version == PROTOCOL_VERSION && ack.received & 1 == 1).then_some(ack)
    }
}

// The body is postcard's encoding of `Ack` (varints), written and read here by hand: the robot reads
// acknowledgements on its firmware, where serde's generic machinery would cost flash for five fields.

/// Write `v` as a LEB128 varint into `out`; returns its length.
fn put_varint(out: &mut [u8], mut v: u64) -> Option<usize> {
    let mut n = 0;
    loop {
        let byte = (v & 0x7f) as u8;
        v >>= 7;
        let slot = out.get_mut(n)?;
        n += 1;
        if v == 0 {
            *slot = byte;
            return Some(n);
        }
        *slot = byte | 0x80;
    }
}

/// Read a LEB128 varint of at most `max_bytes` bytes (and 64 bits); returns it and the rest.
fn take_varint(bytes: &[u8], max_bytes: usize) -> Option<(u64, &[u8])> {
    let mut v = 0u64;
    for i in 0..max_bytes.min(10) {
        let b = *bytes.get(i)?;
        let part = u64::from(b & 0x7f);
        if i == 9 && part > 1 {
            return None; // beyond 64 bits
        }
        v |= part << (7 * i);
        if b & 0x80 == 0 {
            return Some((v, bytes.get(i + 1..)?));
        }
    }
    None
}

/// What an [`AckReader`] saw.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AckStats {
    /// Acknowledgements accepted (this robot and session).
    pub accepted: u32,
    /// Runs of bytes refused by the frame layer (COBS, length, CRC, overflow).
    pub damaged: u32,
    /// Checked frames that are not an acknowledgement of this version.
    pub malformed: u32,
    /// Acknowledgements of another robot or session (refused).
    pub foreign: u32,
    /// Bytes read from the back channel.
    pub bytes: u32,
}

impl AckStats {
    /// Everything refused.
    pub fn refused(&self) -> u32 {
        self.damaged
            .saturating_add(self.malformed)
            .saturating_add(self.foreign)
    }
}

/// Reads acknowledgements from the back channel, a few bytes at a time, never blocking: it reads only
/// while the reader says bytes are ready ([`embedded_io::ReadReady`]).
pub struct AckReader {
    decoder: FrameDecoder<{ MAX_ACK_WIRE }>,
    stats: AckStats,
}

impl Default for AckReader {
    fn default() -> Self {
        Self::new()
    }
}

impl AckReader {
    /// A reader with nothing pending.
    pub const fn new() -> Self {
        Self {
            decoder: FrameDecoder::new(),
            stats: AckStats {
                accepted: 0,
                damaged: 0,
                malformed: 0,
                foreign: 0,
                bytes: 0,
            },
        }
    }

    /// Counters so far.
    pub fn stats(&self) -> AckStats {
        self.stats
    }

    /// Forget the counters and any partial frame (a new session).
    pub fn reset(&mut self) {
        *self = Self::new();
    }

    /// Feed bytes from the back channel; `f` receives every acknowledgement of `(robot, session)`.
    pub fn feed(&mut self, mut bytes: &[u8], robot: u16, session: u32, mut f: impl FnMut(Ack)) {
        self.stats.bytes = self.stats.bytes.wrapping_add(bytes.len() as u32);
        while !bytes.is_empty() {
            match self.decoder.feed(bytes) {
                Feed::NeedMore => return,
                Feed::Error { rest, .. } => {
                    self.stats.damaged = self.stats.damaged.saturating_add(1);
                    bytes = rest;
                }
                Feed::Frame { body, rest } => {
                    match Ack::parse(body) {
                        None => self.stats.malformed = self.stats.malformed.saturating_add(1),
                        Some(a) if a.robot != robot || a.session != session => {
                            self.stats.foreign = self.stats.foreign.saturating_add(1)
                        }
                        Some(a) => {
                            self.stats.accepted = self.stats.accepted.saturating_add(1);
                            f(a);
                        }
                    }
                    bytes = rest;
                }
            }
        }
    }

    /// Read whatever the back channel has ready (never blocking) and hand every acknowledgement of
    /// `(robot, session)` to `f`. Returns the bytes read.
    pub fn poll<R: embedded_io::Read + embedded_io::ReadReady>(
        &mut self,
        r: &mut R,
        robot: u16,
        session: u32,
        mut f: impl FnMut(Ack),
    ) -> Result<usize, R::Error> {
        let mut total = 0;
        let mut chunk = [0u8; 32];
        while r.read_ready()? {
            let n = r.read(&mut chunk)?;
            if n == 0 {
                break;
            }
            total += n;
            self.feed(chunk.get(..n).unwrap_or(&[]), robot, session, &mut f);
        }
        Ok(total)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    extern crate std;
    use std::vec::Vec;

    fn ack(highest: u32, received: u64) -> Ack {
        Ack {
            version: PROTOCOL_VERSION,
            robot: 3,
            session: 9,
            highest,
            received,
        }
    }

    #[test]
    fn the_body_is_postcards_encoding() {
        for a in [
            ack(0, 1),
            ack(u32::MAX, u64::MAX),
            ack(300, 0x8000_0000_0000_0001),
        ] {
            let mut ours = [0u8; MAX_ACK_WIRE];
            let n = a.encode(&mut ours).unwrap();
            let mut body = [0u8; MAX_ACK_WIRE];
            let m = cobs::decode(&ours[1..n - 1], &mut body).unwrap();
            let mut theirs = [0u8; MAX_ACK_BODY];
            let p = postcard::to_slice(&a, &mut theirs).unwrap();
            assert_eq!(&body[..m - 4], &p[..]);
            assert_eq!(Ack::parse(p), Some(a));
            assert_eq!(postcard::from_bytes::<Ack>(&body[..m - 4]).unwrap(), a);
        }
        // Overlong varints and trailing bytes are refused.
        let v = PROTOCOL_VERSION;
        assert_eq!(Ack::parse(&[v, 0x81, 0x80, 0x80, 0x00, 0, 0, 1]), None);
        assert_eq!(Ack::parse(&[v, 3, 9, 5, 1, 0]), None);
        assert_eq!(Ack::parse(&[v - 1, 3, 9, 5, 1]), None, "another version");
        assert_eq!(
            Ack::parse(&[v, 3, 9, 5, 1]),
            Some(Ack {
                highest: 5,
                received: 1,
                ..ack(0, 1)
            })
        );
    }

    /// The spec's size: the largest acknowledgement (every varint at its longest) is 31 bytes on the wire.
    #[test]
    fn the_largest_acknowledgement_is_31_bytes() {
        let a = Ack {
            robot: u16::MAX,
            session: u32::MAX,
            ..ack(u32::MAX, u64::MAX)
        };
        let mut wire = [0u8; 64];
        assert_eq!((a.encode(&mut wire), MAX_ACK_WIRE), (Some(31), 31));
    }

    #[test]
    fn acknowledgements_round_trip_and_bad_bytes_are_refused() {
        let mut wire = [0u8; MAX_ACK_WIRE];
        let a = ack(u32::MAX, u64::MAX);
        let n = a.encode(&mut wire).unwrap();
        assert!(n <= MAX_ACK_WIRE);
        let mut stream = Vec::new();
        stream.extend_from_slice(&wire[..n]);
        // Damaged copy: one byte flipped.
        let mut bad = wire[..n].to_vec();
        bad[5] ^= 0x40;
        stream.extend_from_slice(&bad);
        // Another robot's.
        let other = Ack { robot: 4, ..a };
        let m = other.encode(&mut wire).unwrap();
        stream.extend_from_slice(&wire[..m]);
        // Garbage, then a good one split in two.
        stream.extend_from_slice(&[0, 0xff, 0xfe, 7, 0]);
        let n = ack(5, 0b101).encode(&mut wire).unwrap();
        stream.extend_from_slice(&wire[..n]);
        let mut reader = AckReader::new();
        let mut got = Vec::new();
        let (a1, a2) = stream.split_at(stream.len() - 3);
        reader.feed(a1, 3, 9, |a| got.push(a));
        reader.feed(a2, 3, 9, |a| got.push(a));
        assert_eq!(got, [a, ack(5, 0b101)]);
        let s = reader.stats();
        assert_eq!((s.accepted, s.foreign), (2, 1));
        assert!(s.damaged + s.malformed >= 2, "{s:?}");
        // An acknowledgement that says it lacks its own highest frame is malformed.
        let n = ack(5, 0b100).encode(&mut wire).unwrap();
        reader.feed(&wire[..n], 3, 9, |_| panic!("accepted"));
    }
}
