//! Frames on a byte link: COBS + CRC-32 + sequence numbers, in fixed buffers.
//!
//! A serial link flips bits, drops bytes, cuts frames short and repeats them. Each frame is therefore
//! self-contained and self-checking ([`crate::wire`] gives the layout): COBS makes 0x00 a pure delimiter,
//! so a receiver re-synchronises at the next 0x00 after any damage; a CRC-32 refuses damaged frames
//! whole; a per-session sequence number lets the receiver count every frame it never got.
//!
//! The sending side is [`FrameEncoder`]: it is the local map's [`EvictionSink`](crate::sink::EvictionSink) (evicted voxels are
//! quantized at once into a fixed byte queue; a full queue refuses, and the map keeps the voxel), and each
//! [`FrameEncoder::tick`] spends a byte budget — session header when due, then evicted voxels, then the
//! live voxels the caller ranks most changed — so a slow link degrades by sending fewer live updates, never
//! by losing evicted voxels. It writes whole frames through [`embedded_io::Write`], so any HAL's UART works.
//!
//! The receiving side is [`FrameDecoder`] (bytes in arbitrary chunks → checked frame bodies) and
//! [`SeqTracker`] (lost, duplicate and late frames of one session); [`crate::receiver`] applies the whole
//! acceptance rule with them. With a back channel (protocol 3) the receiver acknowledges ([`Ack`]), and the
//! encoder keeps every frame until acknowledged and re-sends it when it is overdue.
//!
//! Submodules: [`encoder`] (the sending side and its queue), `resend` (the kept frames), [`ack`]
//! (acknowledgements and the robot's non-blocking reader), [`decoder`] (bytes → checked frame bodies),
//! [`seq`] (sequence numbers of a session).

pub mod ack;
pub mod decoder;
pub mod encoder;
mod resend;
pub mod seq;

pub use ack::{Ack, AckReader, AckStats};
pub use decoder::{DecoderStats, Feed, FrameDecoder, FrameError};
pub use encoder::{live, EncoderSettings, FrameEncoder, LiveItem, Resend, TickError, TickReport};
pub use resend::ACK_WINDOW;
pub use seq::{SeqTracker, SeqVerdict};

/// Bytes a frame body of `body_len` bytes takes on the wire, at most: two delimiters, COBS overhead, CRC.
pub const fn wire_len(body_len: usize) -> usize {
    let n = body_len + 4;
    n + n / 254 + 1 + 2
}

#[cfg(test)]
mod tests;
