//! A voxel summary on the wire: key and residency deltas within a frame, the final flag, the exact point
//! count, then the quantized codes of [`super::codec`]. A session that forgets sends *stamped* summaries
//! instead: a count of 0, then the tick of the voxel's last change and its weight n (f32, exact), the
//! statistics being as of that tick (`wire_spec.md`, the clock rule).

use super::codec::{decode_codes_as, decode_rice_at, stamped_class, SummaryCodec, MAX_COUNT};
use super::{VoxelBatch, WireError};
use crate::key::VoxelKey;
use crate::obs::ObsStats;
/// A voxel as the base station sees it after decoding.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Summary<const D: usize> {
    /// Which voxel.
    pub key: VoxelKey,
    /// Residency number (see [`crate::sink::Evicted`]).
    pub residency: u32,
    /// Whether the voxel has left the robot's map (its last word on this residency), or is a live update
    /// of a voxel still resident (to be replaced by newer ones).
    pub is_final: bool,
    /// What was observed in the voxel during this residency. n is exact; m and S are quantized.
    pub obs: ObsStats<D>,
    /// A mean band's scale (the lead band's or the others') and the largest scatter entry were sent with
    /// the codec's top code (255): each value was clamped there (a mean scale at ≈ 6.0e4, S at ≈ 9.6e5) or
    /// lies within 1/8 octave below it.
    /// Receivers count it.
    pub at_ceiling: Ceiling,
    /// A stamped summary's tick (forgetting: `obs` are as of it, and n is a weight, not a count); `None`
    /// for a summary of a session that does not forget.
    pub time: Option<u32>,
}

/// Which of a summary's log-coded values were sent with the top code (see [`Summary::at_ceiling`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Ceiling {
    /// A mean band's scale code (the lead band's or the others') was 255.
    pub mean_scale: bool,
    /// The largest-scatter code was 255.
    pub psi: bool,
}

/// Key and residency of the previous summary in a frame (deltas are taken against it).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DeltaBase {
    key: VoxelKey,
    residency: u32,
}

fn put(out: &mut [u8], at: &mut usize, bytes: &[u8]) -> Result<(), WireError> {
    let end = *at + bytes.len();
    out.get_mut(*at..end)
        .ok_or(WireError::BufferFull)?
        .copy_from_slice(bytes);
    *at = end;
    Ok(())
}

/// postcard's varint: LEB128, 7 bits per byte, least significant first. (Out of line on Arm, where one
/// copy for a summary head's four or five fields saves flash: 172 B on the an386, 336 B in its forgetting
/// build, 40 B on thumbv6m; inlined on riscv32imac, where it would cost 68 B more.)
#[cfg_attr(target_arch = "arm", inline(never))]
pub(super) fn put_varint(out: &mut [u8], at: &mut usize, mut v: u64) -> Result<(), WireError> {
    loop {
        let byte = (v & 0x7f) as u8;
        v >>= 7;
        if v == 0 {
            return put(out, at, &[byte]);
        }
        put(out, at, &[byte | 0x80])?;
    }
}

fn take<'a>(bytes: &'a [u8], at: &mut usize, n: usize) -> Result<&'a [u8], WireError> {
    let end = at.checked_add(n).ok_or(WireError::Truncated)?;
    let s = bytes.get(*at..end).ok_or(WireError::Truncated)?;
    *at = end;
    Ok(s)
}

fn take_varint(bytes: &[u8], at: &mut usize, max_bytes: usize) -> Result<u64, WireError> {
    let mut v = 0u64;
    for i in 0..max_bytes {
        let b = take(bytes, at, 1)?[0];
        v |= u64::from(b & 0x7f) << (7 * i);
        if b & 0x80 == 0 {
            return Ok(v);
        }
    }
    Err(WireError::Malformed)
}

/// The quantized part of a summary of `count` points at `*at` (its length read from it when Rice-coded).
fn take_codes<'a, const D: usize>(
    codec: SummaryCodec,
    count: u32,
    bytes: &'a [u8],
    at: &mut usize,
) -> Result<&'a [u8], WireError> {
    let len = codec.codes_len(D, count, bytes.get(*at..).unwrap_or_default())?;
    take(bytes, at, len)
}

pub(super) const fn zigzag(v: i32) -> u32 {
    ((v << 1) ^ (v >> 31)) as u32
}

pub(super) const fn unzigzag(v: u32) -> i32 {
    ((v >> 1) as i32) ^ -((v & 1) as i32)
}

/// Write one summary: key deltas, residency delta with the final flag, point count, codes. `codes` come
/// from [`encode_codes`](super::encode_codes). Returns the bytes written and advances `base`.
#[allow(clippy::too_many_arguments)]
pub fn encode_summary(
    base: &mut DeltaBase,
    key: VoxelKey,
    residency: u32,
    is_final: bool,
    count: u32,
    codes: &[u8],
    out: &mut [u8],
) -> Result<usize, WireError> {
    let mut at = encode_summary_head(base, key, residency, is_final, count, out)?;
    put(out, &mut at, codes)?;
    Ok(at)
}

/// Write a summary's head (key deltas, residency delta with the final flag, point count) and advance
/// `base`; the caller appends the codes ([`encode_codes`](super::encode_codes)) right after. Returns the bytes written.
pub fn encode_summary_head(
    base: &mut DeltaBase,
    key: VoxelKey,
    residency: u32,
    is_final: bool,
    count: u32,
    out: &mut [u8],
) -> Result<usize, WireError> {
    let mut at = put_key_residency(base, key, residency, is_final, out)?;
    put_varint(out, &mut at, u64::from(count))?;
    Ok(at)
}

/// Write a stamped summary's head (forgetting): key and residency deltas with the final flag, a count of
/// 0, the tick `time` of the voxel's last change (varint), its weight `n` (f32 little-endian); the caller
/// appends codes sized for [`stamped_class`]`(n)`. Returns the bytes written and advances `base`.
pub fn encode_stamped_head(
    base: &mut DeltaBase,
    (key, residency, is_final): (VoxelKey, u32, bool),
    time: u32,
    n: f32,
    out: &mut [u8],
) -> Result<usize, WireError> {
    let mut at = put_key_residency(base, key, residency, is_final, out)?;
    put_varint(out, &mut at, 0)?;
    put_varint(out, &mut at, u64::from(time))?;
    put(out, &mut at, &n.to_le_bytes())?;
    Ok(at)
}

/// Write a summary's head in a Rice session ([`SummaryCodec::rice`]) as the start of its bit stream
/// (`out` is zeroed first): the key deltas as Exp-Golomb codes, the final flag (1 bit), the residency
/// delta, the count (0 and 1 swapped), and, with `stamp` = (tick, weight), count 0, the tick and the
/// weight's 32 bits. The codes follow in the same stream ([`encode_rice`](super::encode_rice)). Returns
/// the bits written and advances `base`.
pub fn encode_rice_head(
    base: &mut DeltaBase,
    (key, residency, is_final): (VoxelKey, u32, bool),
    count: u32,
    stamp: Option<(u32, f32)>,
    out: &mut [u8],
) -> Result<usize, WireError> {
    let mut w = super::rice::BitWriter { out, bit: 0 };
    w.out.fill(0);
    for (k, b) in key.as_array().iter().zip(base.key.as_array()) {
        w.exp_golomb(u64::from(zigzag(k.wrapping_sub(b))));
    }
    w.put(u32::from(is_final), 1);
    w.exp_golomb(u64::from(zigzag(
        residency.wrapping_sub(base.residency) as i32
    )));
    match stamp {
        None => w.exp_golomb(rice_count(u64::from(count))),
        Some((time, n)) => {
            w.exp_golomb(rice_count(0));
            w.exp_golomb(u64::from(time));
            w.put(n.to_bits(), 32);
        }
    }
    w.bytes()?;
    *base = DeltaBase { key, residency };
    Ok(w.bit)
}

/// Write one whole summary of a Rice session: [`encode_rice_head`], then `stats`' codes in the same bit
/// stream (steps by the default policy, sized for `count` points: a stamped summary's class). Returns the
/// bytes written and advances `base`.
pub fn encode_rice_summary<const D: usize>(
    codec: SummaryCodec,
    base: &mut DeltaBase,
    id: (VoxelKey, u32, bool),
    (count, stamp): (u32, Option<(u32, f32)>),
    stats: &ObsStats<D>,
    out: &mut [u8],
) -> Result<usize, WireError> {
    let mut trial = *base;
    let head = encode_rice_head(&mut trial, id, count, stamp, out)?;
    let class = match stamp {
        Some((_, n)) => stamped_class(n).ok_or(WireError::BadCount)?,
        None => count,
    };
    let policy = super::rice::Policy::DEFAULT;
    let end = super::codec::encode_rice_at(codec, policy, stats, class, out, head)?;
    *base = trial;
    Ok(end.div_ceil(8))
}

/// A summary head's fields as they are read: varints, or (Rice session) Exp-Golomb codes in a bit stream.
enum Fields<'a> {
    Varints,
    Bits(super::rice::BitReader<'a>),
}

impl Fields<'_> {
    /// An unsigned field of at most `max_bytes` varint bytes.
    fn int(&mut self, bytes: &[u8], at: &mut usize, max_bytes: usize) -> Result<u64, WireError> {
        match self {
            Self::Varints => take_varint(bytes, at, max_bytes),
            Self::Bits(r) => r.exp_golomb(),
        }
    }

    /// Four raw bytes (an f32 little-endian).
    fn raw4(&mut self, bytes: &[u8], at: &mut usize) -> Result<[u8; 4], WireError> {
        match self {
            Self::Varints => {
                let n = take(bytes, at, 4)?;
                Ok([n[0], n[1], n[2], n[3]])
            }
            Self::Bits(r) => Ok(r.get(32)?.to_le_bytes()),
        }
    }
}

fn put_key_residency(
    base: &mut DeltaBase,
    key: VoxelKey,
    residency: u32,
    is_final: bool,
    out: &mut [u8],
) -> Result<usize, WireError> {
    let mut at = 0;
    for (k, b) in key.as_array().iter().zip(base.key.as_array()) {
        put_varint(out, &mut at, u64::from(zigzag(k.wrapping_sub(b))))?;
    }
    let dres = u64::from(zigzag(residency.wrapping_sub(base.residency) as i32));
    put_varint(out, &mut at, dres << 1 | u64::from(is_final))?;
    *base = DeltaBase { key, residency };
    Ok(at)
}

/// Read one summary from `bytes` (starting at `*at`), validating it.
pub fn decode_summary<const D: usize>(
    codec: SummaryCodec,
    base: &mut DeltaBase,
    bytes: &[u8],
    at: &mut usize,
) -> Result<Summary<D>, WireError> {
    let head_at = *at;
    let mut f = if codec.is_rice() {
        Fields::Bits(super::rice::BitReader {
            bytes: bytes.get(head_at..).unwrap_or_default(),
            bit: 0,
        })
    } else {
        Fields::Varints
    };
    let mut k = [0i32; 3];
    for (i, b) in k.iter_mut().zip(base.key.as_array()) {
        let z = u32::try_from(f.int(bytes, at, 5)?).map_err(|_| WireError::Malformed)?;
        *i = b.wrapping_add(unzigzag(z));
    }
    let key = VoxelKey::new(k[0], k[1], k[2]);
    if !key.in_range() {
        return Err(WireError::BadKey);
    }
    let rf = match &mut f {
        // Rice: the final flag as one bit, then the residency delta.
        Fields::Bits(r) => {
            let is_final = u64::from(r.get(1)?);
            r.exp_golomb()? << 1 | is_final
        }
        Fields::Varints => f.int(bytes, at, 5)?,
    };
    let z = u32::try_from(rf >> 1).map_err(|_| WireError::Malformed)?;
    let residency = base.residency.wrapping_add(unzigzag(z) as u32);
    let is_final = rf & 1 == 1;
    let count = match &mut f {
        Fields::Bits(r) => rice_count(r.exp_golomb()?),
        Fields::Varints => f.int(bytes, at, 4)?,
    };
    let stamp = if count == 0 {
        let time = u32::try_from(f.int(bytes, at, 5)?).map_err(|_| WireError::Malformed)?;
        Some((time, f32::from_le_bytes(f.raw4(bytes, at)?)))
    } else {
        None
    };
    let (class, weight, time) = match stamp {
        // Stamped (forgetting): the tick, the weight n, codes sized for its class.
        Some((time, n)) => (stamped_class(n).ok_or(WireError::BadCount)?, n, Some(time)),
        None if count > u64::from(MAX_COUNT) => return Err(WireError::BadCount),
        None => (count as u32, count as f32, None),
    };
    let (obs, at_ceiling) = if let Fields::Bits(r) = &f {
        // Rice: the codes follow the head in the same bit stream.
        let from = bytes.get(*at..).unwrap_or_default();
        let (obs, end, ceiling) = decode_rice_at::<D>(codec, (class, weight), from, r.bit)?;
        *at += end.div_ceil(8);
        (obs, ceiling)
    } else {
        let codes = take_codes::<D>(codec, class, bytes, at)?;
        let obs = decode_codes_as::<D>(codec, class, weight, codes)?;
        let psi_at = codes.len() - codec.scatter_len(class).min(codes.len());
        let rest_at = if codec.lead == 0 {
            0
        } else {
            codec.lead_len_for(class)
        };
        // Stored codes have no log-coded values: nothing is clamped to a top code.
        let ceiling = if cfg!(feature = "stored-codes") && codec.is_stored() {
            Ceiling::default()
        } else {
            Ceiling {
                mean_scale: codes.first() == Some(&u8::MAX) || codes.get(rest_at) == Some(&u8::MAX),
                psi: codes.get(psi_at) == Some(&u8::MAX),
            }
        };
        (obs, ceiling)
    };
    *base = DeltaBase { key, residency };
    Ok(Summary {
        key,
        residency,
        is_final,
        obs,
        at_ceiling,
        time,
    })
}

/// A Rice head's count field: 0 and 1 swapped (one point, the most frequent, takes one bit; 0 =
/// stamped), its own inverse.
const fn rice_count(v: u64) -> u64 {
    match v {
        0 => 1,
        1 => 0,
        v => v,
    }
}

impl<'a> VoxelBatch<'a> {
    /// Iterate over the summaries; the iterator checks that exactly `count` are present.
    pub fn iter<const D: usize>(&self, codec: SummaryCodec) -> SummaryIter<'a, D> {
        SummaryIter {
            codec,
            bytes: self.summaries,
            at: 0,
            left: self.count,
            base: DeltaBase::default(),
            failed: false,
        }
    }
}

/// Iterator over a [`VoxelBatch`]'s summaries. Yields an error (and then stops) on the first bad summary,
/// on missing summaries or on trailing bytes.
pub struct SummaryIter<'a, const D: usize> {
    codec: SummaryCodec,
    bytes: &'a [u8],
    at: usize,
    left: u16,
    base: DeltaBase,
    failed: bool,
}

impl<const D: usize> Iterator for SummaryIter<'_, D> {
    type Item = Result<Summary<D>, WireError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        if self.left == 0 {
            if self.at != self.bytes.len() {
                self.failed = true;
                return Some(Err(WireError::Malformed));
            }
            return None;
        }
        self.left -= 1;
        let r = decode_summary::<D>(self.codec, &mut self.base, self.bytes, &mut self.at);
        self.failed = r.is_err();
        Some(r)
    }
}
