//! A simulated faulty serial link, deterministic from a seed, that knows which frames it delivered intact.
//!
//! Fault tests need ground truth: which frames did the link destroy, and which did it deliver untouched?
//! The link takes whole encoded frames (as the encoder writes them, `0x00 … 0x00`) and applies, per frame,
//! drops, truncation (the rest of the frame never sent, as after a UART reset), duplication and delay
//! (later frames overtake a delayed one: reordering), outages of seconds (everything sent during one is
//! lost), then per byte, random bit flips (the byte error rate), dropped bytes and bursts of garbage.
//! Every frame whose bytes all went through unchanged is recorded as intact; a correct receiver must accept
//! exactly those (and never anything else).
//!
//! [`FaultyWriter`] puts the link in front of any [`embedded_io::Write`] — the way smoltcp's
//! `phy::FaultInjector` wraps a device — so the robot's `Mapper::tick` writes into it as into a UART, and
//! the base station's acknowledgements cross another one the other way into a [`Pipe`] the robot reads.
//! Time is the caller's: [`FaultyWriter::advance`] moves the link's clock (delays, outages).

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
    /// Probability a frame is held back by a random delay up to `max_delay_ms` (later frames overtake it).
    pub delay_rate: f64,
    /// Longest delay (ms).
    pub max_delay_ms: u64,
    /// An outage starts every this many ms (0 = never): everything sent during one is lost.
    pub outage_every_ms: u64,
    /// How long each outage lasts (ms).
    pub outage_ms: u64,
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
            ..Self::default()
        }
    }

    /// [`Self::everything`] with `drop_rate` of frames dropped whole, and 5 % of frames delayed by up to
    /// `max_delay_ms` (reordered).
    pub fn with_drops_and_delays(rate: f64, drop_rate: f64, max_delay_ms: u64) -> Self {
        Self {
            frame_drop_rate: drop_rate,
            delay_rate: 0.05,
            max_delay_ms,
            ..Self::everything(rate)
        }
    }

    /// The same with an outage of `outage_ms` every `every_ms`.
    pub fn with_outages(self, every_ms: u64, outage_ms: u64) -> Self {
        Self {
            outage_every_ms: every_ms,
            outage_ms,
            ..self
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
    /// Frames held back by a delay.
    pub delayed: u64,
    /// Frames lost to an outage.
    pub outage_dropped: u64,
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
    /// The link's clock (ms).
    now_ms: u64,
    /// Delayed frames: (release time, order of sending, bytes as they will arrive).
    delayed: Vec<(u64, u64, Vec<u8>)>,
}

impl FaultyLink {
    /// A link with these faults, deterministic from `seed`.
    pub fn new(faults: Faults, seed: u64) -> Self {
        Self {
            faults,
            rng: SplitMix::new(seed),
            log: LinkLog::default(),
            burst_left: 0,
            now_ms: 0,
            delayed: Vec::new(),
        }
    }

    /// The link's clock (ms).
    pub fn now_ms(&self) -> u64 {
        self.now_ms
    }

    /// Whether the link is down now (an outage).
    pub fn in_outage(&self) -> bool {
        let f = &self.faults;
        f.outage_every_ms > 0 && self.now_ms % f.outage_every_ms >= f.outage_every_ms - f.outage_ms
    }

    /// Move the clock by `ms`; append to `out` the delayed frames now due (in order of release).
    pub fn advance(&mut self, ms: u64, out: &mut Vec<u8>) {
        self.now_ms += ms;
        self.delayed.sort_by_key(|(t, order, _)| (*t, *order));
        let due = self.delayed.partition_point(|(t, _, _)| *t <= self.now_ms);
        for (_, _, bytes) in self.delayed.drain(..due) {
            out.extend_from_slice(&bytes);
        }
    }

    /// Send one frame at the current time: faults applied, what arrives now appended to `out` (a delayed
    /// frame arrives at a later [`Self::advance`]). Returns how many copies will arrive intact.
    pub fn send_timed(&mut self, frame: &[u8], out: &mut Vec<u8>) -> u32 {
        if self.in_outage() {
            self.log.frames += 1;
            self.log.outage_dropped += 1;
            return 0;
        }
        if self.rng.chance(self.faults.delay_rate) && self.faults.max_delay_ms > 0 {
            self.log.delayed += 1;
            let mut held = Vec::new();
            let intact = self.send(frame, &mut held);
            let release =
                self.now_ms + 1 + self.rng.below(self.faults.max_delay_ms as usize) as u64;
            let order = self.log.frames;
            self.delayed.push((release, order, held));
            return intact;
        }
        self.send(frame, out)
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

/// [`FaultyLink`] in front of a writer: whole frames written into it reach `inner` through the faults.
/// Bytes are collected up to each frame's closing delimiter, so the writer may be fed in any chunks.
pub struct FaultyWriter<W> {
    link: FaultyLink,
    inner: W,
    pending: Vec<u8>,
    out: Vec<u8>,
    /// Bytes written into the link (before faults).
    pub bytes_in: u64,
}

impl<W: embedded_io::Write> FaultyWriter<W> {
    /// `inner` behind a link with these faults, deterministic from `seed`.
    pub fn new(inner: W, faults: Faults, seed: u64) -> Self {
        Self {
            link: FaultyLink::new(faults, seed),
            inner,
            pending: Vec::new(),
            out: Vec::new(),
            bytes_in: 0,
        }
    }
    /// The link (its log and clock).
    pub fn link(&self) -> &FaultyLink {
        &self.link
    }
    /// The writer behind the link.
    pub fn inner(&mut self) -> &mut W {
        &mut self.inner
    }
    /// Move the link's clock; delayed frames now due reach the inner writer.
    pub fn advance(&mut self, ms: u64) -> Result<(), W::Error> {
        self.link.advance(ms, &mut self.out);
        self.pass_on()
    }
    fn pass_on(&mut self) -> Result<(), W::Error> {
        if !self.out.is_empty() {
            self.inner.write_all(&self.out)?;
            self.out.clear();
        }
        Ok(())
    }
}

impl<W: embedded_io::Write> embedded_io::ErrorType for FaultyWriter<W> {
    type Error = W::Error;
}

impl<W: embedded_io::Write> embedded_io::Write for FaultyWriter<W> {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.bytes_in += buf.len() as u64;
        for &b in buf {
            self.pending.push(b);
            // A frame is complete at a delimiter that follows data.
            if b == 0 && self.pending.iter().any(|&x| x != 0) {
                let frame = std::mem::take(&mut self.pending);
                let start = frame
                    .iter()
                    .position(|&x| x != 0)
                    .unwrap_or(0)
                    .saturating_sub(1);
                self.link.send_timed(&frame[start..], &mut self.out);
            } else if b == 0 {
                self.pending.clear();
                self.pending.push(0);
            }
        }
        self.pass_on()?;
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        self.pass_on()?;
        self.inner.flush()
    }
}

/// A byte pipe: written at one end, read at the other (the back channel's receiving UART).
#[derive(Clone, Debug, Default)]
pub struct Pipe(pub std::collections::VecDeque<u8>);

impl embedded_io::ErrorType for Pipe {
    type Error = core::convert::Infallible;
}

impl embedded_io::Write for Pipe {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.0.extend(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

impl embedded_io::Read for Pipe {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let n = buf.len().min(self.0.len());
        for (d, s) in buf.iter_mut().zip(self.0.drain(..n)) {
            *d = s;
        }
        Ok(n)
    }
}

impl embedded_io::ReadReady for Pipe {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(!self.0.is_empty())
    }
}

/// Frame a message body as the encoder does — CRC-32 appended, COBS-encoded between two `0x00` — so a test
/// can put any body, valid or damaged, behind a valid CRC and reach the layers above the frame.
pub fn frame_body(body: &[u8]) -> Vec<u8> {
    let mut b = body.to_vec();
    b.extend_from_slice(&latentbki::wire::CRC32.checksum(body).to_le_bytes());
    let mut out = vec![0u8; b.len() + b.len() / 254 + 2];
    let n = cobs::encode(&b, &mut out[1..]);
    out.truncate(n + 1);
    out.push(0);
    out
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

    #[test]
    fn a_framed_body_is_one_frame_holding_the_body_and_its_crc() {
        let body: Vec<u8> = (0..600u32).map(|i| (i % 7) as u8).collect();
        let framed = frame_body(&body);
        assert_eq!(split_frames(&framed), vec![&framed[..]]);
        let mut plain = vec![0u8; framed.len()];
        let n = cobs::decode(&framed[1..framed.len() - 1], &mut plain).unwrap();
        assert_eq!(&plain[..n - 4], &body[..]);
        let crc = latentbki::wire::CRC32.checksum(&body).to_le_bytes();
        assert_eq!(&plain[n - 4..n], &crc[..]);
    }

    #[test]
    fn the_writer_delays_reorders_and_cuts_whole_frames_deterministically() {
        use embedded_io::Write;
        let faults = Faults {
            delay_rate: 0.3,
            max_delay_ms: 50,
            ..Faults::default()
        }
        .with_outages(1000, 300);
        let run = || {
            let mut w = FaultyWriter::new(Pipe::default(), faults, 9);
            let mut sent = Vec::new();
            for i in 1..=200u8 {
                let frame = [0, i, i, 0];
                // Written in two pieces: the writer finds the frame's end itself.
                w.write_all(&frame[..2]).unwrap();
                w.write_all(&frame[2..]).unwrap();
                sent.push(i);
                w.advance(10).unwrap();
            }
            w.advance(1000).unwrap();
            let got: Vec<u8> = w.inner().0.iter().copied().filter(|&b| b != 0).collect();
            (got, w.link().log())
        };
        let (got, log) = run();
        assert_eq!(run().0, got, "deterministic from the seed");
        // 2 s at 10 ms per frame: 0.3 s of outage in each second, nothing corrupted.
        assert_eq!(log.outage_dropped, 60, "{log:?}");
        assert_eq!(got.len(), 2 * (200 - 60));
        assert!(log.delayed > 20);
        let firsts: Vec<u8> = got.chunks(2).map(|c| c[0]).collect();
        assert!(
            firsts.windows(2).any(|w| w[0] > w[1]),
            "delays reorder frames"
        );
    }
}
