//! A simulated faulty serial link, deterministic from a seed, that knows which frames it delivered intact.
//!
//! Fault tests need ground truth: which frames did the link destroy, and which did it deliver untouched?
//! The link takes whole encoded frames (as the encoder writes them, `0x00 … 0x00`) and applies, per frame,
//! drops, truncation (the rest of the frame never sent, as after a UART reset) and duplication, then per
//! byte, random bit flips (the byte error rate), dropped bytes and bursts of garbage. Every frame whose
//! bytes all went through unchanged is recorded as intact; a correct receiver must accept exactly those
//! (and never anything else).

/// Fault rates. Byte-level rates are per transmitted byte; frame-level rates per frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Faults {
    /// Probability a byte is corrupted (1–8 random bits flipped).
    pub byte_error_rate: f64,
    /// Probability a byte is lost (UART overrun).
    pub byte_drop_rate: f64,
    /// Probability a burst of garbage starts at a byte.
    pub burst_rate: f64,
    /// Longest burst (bytes replaced by random values, zeros included).
    pub burst_len: usize,
    /// Probability a frame is dropped whole.
    pub frame_drop_rate: f64,
    /// Probability a frame is cut short at a random point.
    pub truncate_rate: f64,
    /// Probability a frame is sent twice.
    pub duplicate_rate: f64,
}

impl Faults {
    /// Only byte errors, at this rate.
    pub fn ber(rate: f64) -> Self {
        Self {
            byte_error_rate: rate,
            ..Self::default()
        }
    }

    /// Everything at once: byte errors at `rate`, and drops, truncations, duplicates and bursts too.
    pub fn everything(rate: f64) -> Self {
        Self {
            byte_error_rate: rate,
            byte_drop_rate: rate / 10.0,
            burst_rate: rate / 50.0,
            burst_len: 32,
            frame_drop_rate: 0.02,
            truncate_rate: 0.02,
            duplicate_rate: 0.03,
        }
    }
}

/// What the link did, in total.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LinkLog {
    /// Frames offered.
    pub frames: u64,
    /// Frame copies delivered with every byte intact.
    pub intact: u64,
    /// Frames dropped whole.
    pub dropped: u64,
    /// Frames cut short.
    pub truncated: u64,
    /// Frames sent twice.
    pub duplicated: u64,
    /// Bytes corrupted.
    pub corrupted_bytes: u64,
    /// Bytes lost.
    pub dropped_bytes: u64,
    /// Bursts.
    pub bursts: u64,
}

/// SplitMix64: small, fast, deterministic.
#[derive(Clone, Debug)]
pub struct SplitMix(u64);

impl SplitMix {
    /// Seeded generator.
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }
    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// True with probability p.
    pub fn chance(&mut self, p: f64) -> bool {
        p > 0.0 && self.unit() < p
    }
    /// Uniform in 0..n (n > 0).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }
}

/// The link.
pub struct FaultyLink {
    faults: Faults,
    rng: SplitMix,
    log: LinkLog,
    burst_left: usize,
}

impl FaultyLink {
    /// A link with these faults, deterministic from `seed`.
    pub fn new(faults: Faults, seed: u64) -> Self {
        Self {
            faults,
            rng: SplitMix::new(seed),
            log: LinkLog::default(),
            burst_left: 0,
        }
    }

    /// Totals so far.
    pub fn log(&self) -> LinkLog {
        self.log
    }

    /// Send one encoded frame; append what arrives to `out`. Returns how many copies arrived intact.
    pub fn send(&mut self, frame: &[u8], out: &mut Vec<u8>) -> u32 {
        self.log.frames += 1;
        if self.rng.chance(self.faults.frame_drop_rate) {
            self.log.dropped += 1;
            return 0;
        }
        let copies = if self.rng.chance(self.faults.duplicate_rate) {
            self.log.duplicated += 1;
            2
        } else {
            1
        };
        let mut intact = 0;
        for _ in 0..copies {
            let mut len = frame.len();
            if self.rng.chance(self.faults.truncate_rate) {
                self.log.truncated += 1;
                len = self.rng.below(frame.len());
            }
            let mut clean = len == frame.len();
            for &b in &frame[..len] {
                if self.burst_left == 0 && self.rng.chance(self.faults.burst_rate) {
                    self.log.bursts += 1;
                    self.burst_left = 1 + self.rng.below(self.faults.burst_len.max(1));
                }
                if self.burst_left > 0 {
                    self.burst_left -= 1;
                    let g = self.rng.next_u64() as u8;
                    clean &= g == b;
                    out.push(g);
                    continue;
                }
                if self.rng.chance(self.faults.byte_drop_rate) {
                    self.log.dropped_bytes += 1;
                    clean = false;
                    continue;
                }
                if self.rng.chance(self.faults.byte_error_rate) {
                    self.log.corrupted_bytes += 1;
                    clean = false;
                    let flip = (self.rng.next_u64() as u8).max(1);
                    out.push(b ^ flip);
                    continue;
                }
                out.push(b);
            }
            if clean {
                intact += 1;
            }
        }
        self.log.intact += u64::from(intact);
        intact
    }
}

/// Split an encoder's output into its frames (each `0x00 … 0x00`).
pub fn split_frames(bytes: &[u8]) -> Vec<&[u8]> {
    let mut frames = Vec::new();
    let mut start = None;
    for (i, &b) in bytes.iter().enumerate() {
        if b != 0 {
            continue;
        }
        match start {
            Some(s) if i > s + 1 => {
                frames.push(&bytes[s..=i]);
                start = None;
            }
            _ => start = Some(i),
        }
    }
    frames
}

/// An [`embedded_io::Write`] that appends to a `Vec` (the host side of a robot's UART).
#[derive(Clone, Debug, Default)]
pub struct ByteLog(pub Vec<u8>);

impl embedded_io::ErrorType for ByteLog {
    type Error = core::convert::Infallible;
}

impl embedded_io::Write for ByteLog {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.0.extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clean_link_is_transparent_and_faults_are_logged() {
        let frame = [0u8, 5, 1, 2, 3, 4, 0];
        let mut out = Vec::new();
        let mut clean = FaultyLink::new(Faults::default(), 1);
        assert_eq!(clean.send(&frame, &mut out), 1);
        assert_eq!(out, frame);
        let mut bad = FaultyLink::new(Faults::ber(0.5), 2);
        let mut out = Vec::new();
        for _ in 0..100 {
            bad.send(&frame, &mut out);
        }
        let log = bad.log();
        assert!(log.corrupted_bytes > 200 && log.intact < 10, "{log:?}");
        assert_eq!(
            split_frames(&[0, 1, 2, 0, 0, 3, 0]),
            vec![&[0u8, 1, 2, 0][..], &[0, 3, 0][..]]
        );
    }
}
