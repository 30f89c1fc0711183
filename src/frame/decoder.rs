//! The receiving side's first step: bytes in arbitrary chunks → checked frame bodies. COBS makes 0x00 a
//! pure delimiter, so after any damage the decoder re-synchronises at the next 0x00; a CRC-32 refuses a
//! damaged frame whole, and every refusal is counted by reason.

use crate::wire::CRC32;

/// Why a run of bytes between delimiters was not a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameError {
    /// Not valid COBS.
    Cobs,
    /// Fewer than 5 bytes after decoding (no room for a body and a CRC).
    TooShort,
    /// CRC-32 mismatch.
    Crc,
    /// Longer than the decoder's buffer; discarded up to the next delimiter.
    Overflow,
}

/// Counters of a [`FrameDecoder`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DecoderStats {
    /// Frames that passed COBS and CRC.
    pub frames: u32,
    /// Refused: not COBS.
    pub cobs_errors: u32,
    /// Refused: too short.
    pub too_short: u32,
    /// Refused: CRC mismatch.
    pub crc_errors: u32,
    /// Refused: longer than the buffer.
    pub overflows: u32,
}

impl core::ops::AddAssign for DecoderStats {
    /// Sum two decoders' counters (saturating): a base station's links together.
    fn add_assign(&mut self, o: Self) {
        let add = |a: &mut u32, b: u32| *a = a.saturating_add(b);
        add(&mut self.frames, o.frames);
        add(&mut self.cobs_errors, o.cobs_errors);
        add(&mut self.too_short, o.too_short);
        add(&mut self.crc_errors, o.crc_errors);
        add(&mut self.overflows, o.overflows);
    }
}

impl DecoderStats {
    /// All refused runs.
    pub fn refused(&self) -> u32 {
        self.cobs_errors
            .saturating_add(self.too_short)
            .saturating_add(self.crc_errors)
            .saturating_add(self.overflows)
    }
}

/// Result of [`FrameDecoder::feed`].
#[derive(Debug, PartialEq, Eq)]
pub enum Feed<'a, 'b> {
    /// All input consumed, no frame completed.
    NeedMore,
    /// A checked frame body (CRC removed); `rest` is the input not yet consumed.
    Frame {
        /// The body: header + message.
        body: &'a [u8],
        /// Unconsumed input.
        rest: &'b [u8],
    },
    /// A run of bytes was refused; `rest` is the input not yet consumed.
    Error {
        /// Why.
        error: FrameError,
        /// Unconsumed input.
        rest: &'b [u8],
    },
}

/// Accumulates bytes into frames. `N`: largest encoded frame (between delimiters) it accepts.
pub struct FrameDecoder<const N: usize> {
    buf: [u8; N],
    len: usize,
    overflow: bool,
    stats: DecoderStats,
}

impl<const N: usize> Default for FrameDecoder<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> FrameDecoder<N> {
    /// An empty decoder.
    pub const fn new() -> Self {
        Self {
            buf: [0; N],
            len: 0,
            overflow: false,
            stats: DecoderStats {
                frames: 0,
                cobs_errors: 0,
                too_short: 0,
                crc_errors: 0,
                overflows: 0,
            },
        }
    }

    /// Counters so far.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Consume input up to the end of the next frame (or of the input). Call again with `rest`.
    pub fn feed<'a, 'b>(&'a mut self, input: &'b [u8]) -> Feed<'a, 'b> {
        for (i, &byte) in input.iter().enumerate() {
            if byte != 0 {
                if self.len < N {
                    self.buf[self.len] = byte;
                    self.len += 1;
                } else {
                    self.overflow = true;
                }
                continue;
            }
            let rest = input.get(i + 1..).unwrap_or_default();
            let n = core::mem::take(&mut self.len);
            if core::mem::take(&mut self.overflow) {
                self.stats.overflows = self.stats.overflows.saturating_add(1);
                return Feed::Error {
                    error: FrameError::Overflow,
                    rest,
                };
            }
            if n == 0 {
                continue; // empty frame: back-to-back delimiters
            }
            let run = self.buf.get_mut(..n).unwrap_or_default();
            let error = match cobs_decode_in_place(run).ok_or(()) {
                Err(()) => {
                    self.stats.cobs_errors = self.stats.cobs_errors.saturating_add(1);
                    FrameError::Cobs
                }
                Ok(m) if m < 5 || m > n => {
                    self.stats.too_short = self.stats.too_short.saturating_add(1);
                    FrameError::TooShort
                }
                Ok(m) => {
                    let checked = self
                        .buf
                        .get(..m)
                        .and_then(|f| f.split_at_checked(m - 4))
                        .filter(|(body, crc)| CRC32.checksum(body).to_le_bytes() == **crc);
                    if let Some((body, _)) = checked {
                        self.stats.frames = self.stats.frames.saturating_add(1);
                        return Feed::Frame { body, rest };
                    }
                    self.stats.crc_errors = self.stats.crc_errors.saturating_add(1);
                    FrameError::Crc
                }
            };
            return Feed::Error { error, rest };
        }
        Feed::NeedMore
    }
}

/// COBS-decode `buf` in place (no delimiters in it); returns the decoded length, or `None` if it is not
/// valid COBS (a zero byte, or a group longer than the input). The `cobs` crate encodes; decoding is
/// written here with checked indexing only, because the robot decodes acknowledgements on a path the
/// firmware's `panic-never` build proves free of panics, and the crate's decoder keeps bounds checks.
fn cobs_decode_in_place(buf: &mut [u8]) -> Option<usize> {
    let (mut read, mut write) = (0usize, 0usize);
    while read < buf.len() {
        let code = *buf.get(read)?;
        if code == 0 {
            return None;
        }
        read += 1;
        for _ in 1..code {
            let b = *buf.get(read)?;
            if b == 0 {
                return None;
            }
            *buf.get_mut(write)? = b;
            read += 1;
            write += 1;
        }
        if code != 0xFF && read < buf.len() {
            *buf.get_mut(write)? = 0;
            write += 1;
        }
    }
    Some(write)
}
