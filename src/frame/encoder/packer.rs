//! Packing frames: summaries are appended to the frame being filled while it fits, then the frame's
//! body (header + message) gets its CRC-32 and is COBS-encoded between two delimiters.

use super::queue::Weight;
use super::{FrameEncoder, VOXEL_FRAME_OVERHEAD};
use crate::frame::wire_len;
use crate::key::VoxelKey;
use crate::obs::ObsStats;
use crate::wire::{
    encode_body, encode_codes_as, encode_summary_head, DeltaBase, FrameHeader, Message,
    SummaryCodec, VoxelBatch, WireError, CRC32, PROTOCOL_VERSION,
};

impl<const D: usize, const QB: usize, const N: usize> FrameEncoder<D, QB, N> {
    pub(super) fn header(&self) -> FrameHeader {
        FrameHeader {
            version: PROTOCOL_VERSION,
            robot: self.settings.robot,
            session: self.settings.session,
            seq: self.seq,
            config_id: self.config_id,
        }
    }

    /// Serialize a control message as the next frame into `scratch`; returns its wire length.
    pub(super) fn build_message(&mut self, message: Message<'_>) -> Result<usize, WireError> {
        let len = encode_body(&self.header(), &message, &mut self.body)?;
        self.finish(len)
    }

    /// Serialize the `count` summaries in `scratch[..used]` as the next frame into `scratch`.
    pub(super) fn build_voxels(&mut self, count: u16, used: usize) -> Result<usize, WireError> {
        let header = self.header();
        let batch = VoxelBatch {
            count,
            summaries: self.scratch.get(..used).ok_or(WireError::BufferFull)?,
        };
        let len = encode_body(&header, &Message::Voxels(batch), &mut self.body)?;
        self.finish(len)
    }

    /// Append the CRC to `body[..len]`, COBS it into `scratch` between two delimiters.
    pub(super) fn finish(&mut self, len: usize) -> Result<usize, WireError> {
        let body = self.body.get(..len).ok_or(WireError::BufferFull)?;
        let crc = CRC32.checksum(body);
        self.body
            .get_mut(len..len + 4)
            .ok_or(WireError::BufferFull)?
            .copy_from_slice(&crc.to_le_bytes());
        let body = self.body.get(..len + 4).ok_or(WireError::BufferFull)?;
        let (first, out) = self
            .scratch
            .split_first_mut()
            .ok_or(WireError::BufferFull)?;
        *first = 0;
        let n = cobs::try_encode(body, out).map_err(|_| WireError::BufferFull)?;
        *out.get_mut(n).ok_or(WireError::BufferFull)? = 0;
        Ok(n + 2)
    }
}

/// Where a summary's quantized part comes from: an evicted voxel's, encoded when it was queued, or a live
/// voxel's statistics, encoded now, or (a session of stored codes) a live voxel's codes as its map holds
/// them, copied now.
pub(super) enum Codes<'a, const D: usize> {
    Queued(&'a [u8]),
    Live(&'a ObsStats<D>),
    #[cfg(feature = "stored-codes")]
    LiveStored(crate::quant::StoredCodes<'a>),
}

/// Append one summary — (key, residency, point count, codes) — to the frame being filled in
/// `out[..*used]` if the frame still fits in `limit` wire bytes; `base` is the delta-coding state. Both
/// kinds of summary go through here; a queued one is marked evicted (closed), a live one is not.
pub(super) fn append<const D: usize>(
    out: &mut [u8],
    used: &mut usize,
    base: &mut DeltaBase,
    limit: usize,
    codec: SummaryCodec,
    (key, residency, weight, codes): (VoxelKey, u32, Weight, Codes<'_, D>),
) -> bool {
    if codec.is_rice() {
        return append_rice(
            out,
            used,
            base,
            limit,
            codec,
            (key, residency, weight, codes),
        );
    }
    let mut trial = *base;
    let evicted = matches!(codes, Codes::Queued(_));
    let count = weight.class();
    let Some(Ok(h)) = out.get_mut(*used..).map(|o| match weight {
        Weight::Count(c) => encode_summary_head(&mut trial, key, residency, evicted, c, o),
        #[cfg(feature = "forgetting")]
        Weight::Stamped { n, time } => {
            crate::wire::encode_stamped_head(&mut trial, (key, residency, evicted), time, n, o)
        }
    }) else {
        return false;
    };
    let at = *used + h;
    let c = match codes {
        Codes::Queued(codes) => {
            // The queue entry has room for the largest codes; this summary's are the leading ones.
            let len = codec.codes_len(D, count, codes).unwrap_or(codes.len());
            let codes = codes.get(..len).unwrap_or(codes);
            match out.get_mut(at..at + codes.len()) {
                Some(o) => {
                    o.copy_from_slice(codes);
                    codes.len()
                }
                None => return false,
            }
        }
        Codes::Live(obs) => match out
            .get_mut(at..)
            .map(|o| encode_codes_as(codec, obs, count, o))
        {
            Some(Ok(c)) => c,
            _ => return false,
        },
        #[cfg(feature = "stored-codes")]
        Codes::LiveStored(stored) => match out
            .get_mut(at..)
            .map(|o| crate::wire::write_stored::<D>(&stored, count, o))
        {
            Some(Ok(c)) => c,
            _ => return false,
        },
    };
    if wire_len(VOXEL_FRAME_OVERHEAD + at + c) > limit {
        return false;
    }
    *used = at + c;
    *base = trial;
    true
}

/// A summary's head in a Rice session (`wire::encode_rice_head`).
fn rice_head(
    base: &mut DeltaBase,
    id: (VoxelKey, u32, bool),
    weight: Weight,
    out: &mut [u8],
) -> Result<usize, crate::wire::WireError> {
    match weight {
        Weight::Count(c) => crate::wire::encode_rice_head(base, id, c, None, out),
        #[cfg(feature = "forgetting")]
        Weight::Stamped { n, time } => {
            crate::wire::encode_rice_head(base, id, 0, Some((time, n)), out)
        }
    }
}

/// [`append`] in a Rice session: head and codes are one bit stream, so queued codes (from bit 0 of their
/// entry) are shifted in right after the head's last bit, and live codes encoded there.
fn append_rice<const D: usize>(
    out: &mut [u8],
    used: &mut usize,
    base: &mut DeltaBase,
    limit: usize,
    codec: SummaryCodec,
    (key, residency, weight, codes): (VoxelKey, u32, Weight, Codes<'_, D>),
) -> bool {
    let mut trial = *base;
    let evicted = matches!(codes, Codes::Queued(_));
    let Some(o) = out.get_mut(*used..) else {
        return false;
    };
    let Ok(head) = rice_head(&mut trial, (key, residency, evicted), weight, o) else {
        return false;
    };
    let end = match codes {
        Codes::Queued(c) => {
            let Ok(bits) = crate::wire::codec::rice_end::<0>(codec, D, weight.class(), c, 0) else {
                return false;
            };
            // Shift the codes' bytes by the head's bits within its last byte.
            let (at, shift) = (head / 8, head % 8);
            let Some(dst) = o.get_mut(at..at + (head % 8 + bits).div_ceil(8)) else {
                return false;
            };
            for (i, &b) in c.iter().take(bits.div_ceil(8)).enumerate() {
                let wide = u16::from(b) << shift;
                if let Some(d) = dst.get_mut(i) {
                    *d |= wide as u8;
                }
                if let Some(d) = dst.get_mut(i + 1) {
                    *d |= (wide >> 8) as u8;
                }
            }
            head + bits
        }
        // Stored codes travel in sessions of stored codes, never of Rice codes.
        #[cfg(feature = "stored-codes")]
        Codes::LiveStored(_) => return false,
        Codes::Live(obs) => {
            let policy = crate::wire::rice::Policy::DEFAULT;
            match crate::wire::codec::encode_rice_at(codec, policy, obs, weight.class(), o, head) {
                Ok(end) => end,
                Err(_) => return false,
            }
        }
    };
    let len = end.div_ceil(8);
    if wire_len(VOXEL_FRAME_OVERHEAD + *used + len) > limit {
        // Leave the frame's tail as it was (zero) for the next summary.
        if let Some(o) = out.get_mut(*used..) {
            o.fill(0);
        }
        return false;
    }
    *used += len;
    *base = trial;
    true
}
