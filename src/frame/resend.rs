//! The robot's re-send buffer (protocol 3): wire frames kept, byte for byte, until the base station
//! acknowledges them.
//!
//! A link with a back channel can lose nothing: every frame that carries final voxels (and every control
//! frame) stays here after it was written, and is written again — same bytes, same sequence number — when
//! its acknowledgement is overdue or a later frame's acknowledgement shows it missing. The base station
//! applies each sequence number once, so a re-sent copy that was not needed is a counted duplicate.
//!
//! The buffer is a ring of variable-length records in a byte region the encoder carves out of its queue
//! budget (`QB`): no memory beyond what the firmware already sized. A record never wraps: when it does not
//! fit before the region's end it starts at offset 0 and the bytes left at the end are skipped. When the
//! ring is full no new frame is built, the queue stops draining and the map keeps its voxels
//! (back-pressure). Records are only freed from the oldest end; an acknowledged record behind an
//! unacknowledged one waits, marked, for the older one.

/// Fixed part of a record: sequence number (u32), tick it was last written (u32), wire length (u16),
/// flags (u8), all little-endian.
const RECORD_HEAD: usize = 11;
const ACKED: u8 = 1;
/// Marked for a re-send: a later frame was acknowledged and this one was not.
const GAP: u8 = 2;

/// The sequence-number window of the receiver's tracker (and of an acknowledgement): the oldest frame in
/// flight and the newest one sent must stay within it, or a re-sent frame would arrive too old to apply.
pub const ACK_WINDOW: u32 = 64;

/// State of the ring over a byte region (the region itself is the encoder's).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct Ring {
    /// Offset of the oldest record.
    head: usize,
    /// Offset one past the newest record.
    tail: usize,
    /// When the data wraps (`tail ≤ head`): where the records before the region's end stop.
    wrap: usize,
    wrapped: bool,
    /// Records held.
    frames: usize,
    /// Bytes of wire frames held (without record heads).
    bytes: usize,
}

/// One record's fixed part, read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Record {
    pub seq: u32,
    pub sent_at: u32,
    pub len: usize,
    flags: u8,
}

fn read_head(region: &[u8], at: usize) -> Option<Record> {
    let h = region.get(at..at + RECORD_HEAD)?;
    let word = |i: usize| u32::from_le_bytes([h[i], h[i + 1], h[i + 2], h[i + 3]]);
    Some(Record {
        seq: word(0),
        sent_at: word(4),
        len: usize::from(u16::from_le_bytes([h[8], h[9]])),
        flags: h[10],
    })
}

fn write_head(region: &mut [u8], at: usize, r: &Record) {
    if let Some(h) = region.get_mut(at..at + RECORD_HEAD) {
        h[0..4].copy_from_slice(&r.seq.to_le_bytes());
        h[4..8].copy_from_slice(&r.sent_at.to_le_bytes());
        h[8..10].copy_from_slice(&(r.len as u16).to_le_bytes());
        h[10] = r.flags;
    }
}

impl Ring {
    pub const EMPTY: Self = Self {
        head: 0,
        tail: 0,
        wrap: 0,
        wrapped: false,
        frames: 0,
        bytes: 0,
    };

    /// Frames held.
    pub fn frames(&self) -> usize {
        self.frames
    }
    /// Wire bytes held.
    pub fn bytes(&self) -> usize {
        self.bytes
    }

    /// Sequence number of the oldest frame held.
    pub fn oldest_seq(&self, region: &[u8]) -> Option<u32> {
        (self.frames > 0)
            .then(|| read_head(region, self.head).map(|r| r.seq))
            .flatten()
    }

    /// Where a record of `len` wire bytes would go, if it fits now.
    fn place(&self, region_len: usize, len: usize) -> Option<(usize, bool)> {
        let need = RECORD_HEAD + len;
        if self.frames == 0 {
            return (need <= region_len).then_some((0, false));
        }
        if self.wrapped {
            return (self.tail + need <= self.head).then_some((self.tail, false));
        }
        if self.tail + need <= region_len {
            Some((self.tail, false))
        } else if need <= self.head {
            Some((0, true))
        } else {
            None
        }
    }

    /// Whether a frame of `len` wire bytes fits now.
    pub fn fits(&self, region_len: usize, len: usize) -> bool {
        self.place(region_len, len).is_some()
    }

    /// Keep a written frame. Returns false (nothing kept) if it does not fit.
    pub fn push(&mut self, region: &mut [u8], seq: u32, now: u32, frame: &[u8]) -> bool {
        let Some((at, wraps)) = self.place(region.len(), frame.len()) else {
            return false;
        };
        let Some(dst) = region.get_mut(at + RECORD_HEAD..at + RECORD_HEAD + frame.len()) else {
            return false;
        };
        dst.copy_from_slice(frame);
        let record = Record {
            seq,
            sent_at: now,
            len: frame.len(),
            flags: 0,
        };
        write_head(region, at, &record);
        if self.frames == 0 {
            self.head = 0;
            self.wrapped = false;
        }
        if wraps {
            self.wrap = self.tail;
            self.wrapped = true;
        }
        self.tail = at + RECORD_HEAD + frame.len();
        self.frames += 1;
        self.bytes += frame.len();
        true
    }

    /// The offset after the record at `at` (following the wrap).
    fn next(&self, at: usize, len: usize) -> usize {
        let n = at + RECORD_HEAD + len;
        if self.wrapped && n == self.wrap && n != self.tail {
            0
        } else {
            n
        }
    }

    /// Apply an acknowledgement: `highest` and the 64-frame bitmap `received` (bit i = `highest − i` was
    /// received). Marks acknowledged records, marks older unacknowledged ones inside the window as gaps,
    /// frees acknowledged records from the oldest end. Returns the number of frames newly acknowledged.
    pub fn ack(&mut self, region: &mut [u8], highest: u32, received: u64) -> u32 {
        let mut at = self.head;
        let mut newly = 0;
        for _ in 0..self.frames {
            let Some(mut r) = read_head(region, at) else {
                break;
            };
            let back = highest.wrapping_sub(r.seq);
            if back < ACK_WINDOW && r.flags & ACKED == 0 {
                if received >> back & 1 == 1 {
                    r.flags |= ACKED;
                    newly += 1;
                } else if back > 0 {
                    r.flags |= GAP;
                }
                write_head(region, at, &r);
            }
            at = self.next(at, r.len);
        }
        self.free_acked(region);
        newly
    }

    fn free_acked(&mut self, region: &[u8]) {
        while self.frames > 0 {
            let Some(r) = read_head(region, self.head) else {
                break;
            };
            if r.flags & ACKED == 0 {
                break;
            }
            self.frames -= 1;
            self.bytes -= r.len;
            let n = self.head + RECORD_HEAD + r.len;
            self.head = if self.wrapped && n == self.wrap { 0 } else { n };
            if self.wrapped && self.head == 0 {
                self.wrapped = false;
            }
        }
        if self.frames == 0 {
            *self = Self::EMPTY;
        }
    }

    /// The oldest record due for a re-send at tick `now`: not acknowledged, and either marked as a gap and
    /// written half the timeout ago or more (at least one tick: a frame merely delayed on the link is not
    /// re-sent at once), or written `timeout` ticks ago or more. Returns its offset and record.
    pub fn due(&self, region: &[u8], now: u32, timeout: u32) -> Option<(usize, Record)> {
        let gap_age = (timeout / 2).max(1);
        let mut at = self.head;
        for _ in 0..self.frames {
            let r = read_head(region, at)?;
            let age = now.wrapping_sub(r.sent_at);
            if r.flags & ACKED == 0 && ((r.flags & GAP != 0 && age >= gap_age) || age >= timeout) {
                return Some((at, r));
            }
            at = self.next(at, r.len);
        }
        None
    }

    /// The wire bytes of the record at `at`.
    pub fn frame<'r>(&self, region: &'r [u8], at: usize, r: &Record) -> &'r [u8] {
        region
            .get(at + RECORD_HEAD..at + RECORD_HEAD + r.len)
            .unwrap_or(&[])
    }

    /// The wire bytes of the record at `at` (empty if there is none).
    pub fn frame_at<'r>(&self, region: &'r [u8], at: usize) -> &'r [u8] {
        match read_head(region, at) {
            Some(r) => self.frame(region, at, &r),
            None => &[],
        }
    }

    /// The record at `at` was written again at tick `now`.
    pub fn resent(&mut self, region: &mut [u8], at: usize, now: u32) {
        if let Some(mut r) = read_head(region, at) {
            r.sent_at = now;
            r.flags &= !GAP;
            write_head(region, at, &r);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_wrap_free_in_order_and_refuse_when_full() {
        let mut region = [0u8; 100];
        let mut ring = Ring::EMPTY;
        // 30-byte frames take 41 bytes each: two fit, the third does not.
        assert!(ring.push(&mut region, 0, 0, &[1; 30]));
        assert!(ring.push(&mut region, 1, 0, &[2; 30]));
        assert!(!ring.push(&mut region, 2, 0, &[3; 30]));
        assert_eq!((ring.frames(), ring.bytes()), (2, 60));
        // Frame 1 acknowledged first: nothing is freed (0 is older and missing; it becomes a gap).
        assert_eq!(ring.ack(&mut region, 1, 0b1), 1);
        assert_eq!(ring.frames(), 2);
        assert!(
            ring.due(&region, 1, 100).is_none(),
            "a gap waits half the timeout"
        );
        let (at, r) = ring.due(&region, 1, 2).unwrap();
        assert_eq!((r.seq, ring.frame(&region, at, &r)), (0, &[1u8; 30][..]));
        ring.resent(&mut region, at, 1);
        assert!(ring.due(&region, 1, 2).is_none(), "just re-sent");
        assert_eq!(ring.due(&region, 101, 100).map(|(_, r)| r.seq), Some(0));
        // Now 0 arrives: both are freed.
        assert_eq!(ring.ack(&mut region, 1, 0b11), 1);
        assert_eq!(ring.frames(), 0);
        // Wrap: fill, free the first, the next goes to offset 0.
        assert!(ring.push(&mut region, 2, 5, &[4; 30]));
        assert!(ring.push(&mut region, 3, 5, &[5; 30]));
        ring.ack(&mut region, 2, 1);
        assert_eq!(ring.frames(), 1);
        assert!(ring.push(&mut region, 4, 6, &[6; 30]), "wraps to the start");
        assert_eq!(ring.oldest_seq(&region), Some(3));
        ring.ack(&mut region, 4, 0b11);
        assert_eq!(ring.frames(), 0);
        assert!(
            !ring.push(&mut region, 5, 7, &[0; 90]),
            "larger than the region"
        );
    }

    #[test]
    fn a_timed_out_frame_is_due_and_old_acks_are_ignored() {
        let mut region = [0u8; 256];
        let mut ring = Ring::EMPTY;
        for s in 0..3 {
            assert!(ring.push(&mut region, 100 + s, s, &[7; 20]));
        }
        assert!(ring.due(&region, 3, 10).is_none());
        assert_eq!(ring.due(&region, 10, 10).map(|(_, r)| r.seq), Some(100));
        // An acknowledgement about other sequence numbers acknowledges nothing.
        assert_eq!(ring.ack(&mut region, 500, u64::MAX), 0);
        assert_eq!(ring.ack(&mut region, 102, 0b111), 3);
        assert_eq!(ring.frames(), 0);
    }
}
