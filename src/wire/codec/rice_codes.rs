//! A Rice session's summary codes ([`crate::wire::rice`]): the mean's steps and bands and the scatter as
//! one bit stream, written and read.

use super::*;

/// [`encode_codes_as`] of a Rice session, its steps chosen by `policy` (the study compares policies):
/// one bit stream from bit 0 of `out`, padded to a whole byte. Returns the bytes written.
pub fn encode_rice<const D: usize>(
    codec: SummaryCodec,
    policy: crate::wire::rice::Policy,
    stats: &ObsStats<D>,
    count: u32,
    out: &mut [u8],
) -> Result<usize, WireError> {
    out.fill(0);
    Ok(encode_rice_at(codec, policy, stats, count, out, 0)?.div_ceil(8))
}

/// A Rice session's codes — mean (steps, bands) then scatter (n ≥ 2: its largest entry's code, 8 bits,
/// and a 4-bit code per block) — as bits of `out` from bit `start` on (the bits from there on are 0).
/// Returns the bit after them.
pub(crate) fn encode_rice_at<const D: usize>(
    codec: SummaryCodec,
    policy: crate::wire::rice::Policy,
    stats: &ObsStats<D>,
    count: u32,
    out: &mut [u8],
    start: usize,
) -> Result<usize, WireError> {
    codec.validate(D)?;
    let blocks = NonZeroUsize::new(usize::from(codec.psi_blocks)).ok_or(WireError::BadConfig)?;
    let lead = usize::from(codec.lead);
    let mut t = stats.mean;
    let mut tmp = [0.0f32; D];
    let norm = libm::sqrtf(t.iter().map(|v| v * v).sum::<f32>());
    let (lead_band, rest_band) = t.split_at_mut(lead.min(D));
    let (lead_tmp, rest_tmp) = tmp.split_at_mut(lead.min(D));
    rotate(lead_band, lead_tmp);
    rotate(rest_band, rest_tmp);
    let mut w = crate::wire::rice::BitWriter { out, bit: start };
    crate::wire::rice::encode_bands(
        policy,
        [lead_band, rest_band],
        (norm, count),
        crate::wire::rice::cap(D, lead),
        &mut w,
        |c| log_value(c, SCALE_OFFSET),
        |x| log_code_up(x, SCALE_OFFSET),
    );
    if count >= 2 {
        // The packed scatter bytes (block 2i in the low nibble of byte i), as 8 + 4·B bits.
        let mut s = [0u8; 33];
        let len = codec.scatter_len(count).min(s.len());
        encode_scatter::<D>(blocks, &stats.scatter, s.get_mut(..len).unwrap_or_default());
        w.put(u32::from(s[0]), 8);
        for b in 0..blocks.get() {
            w.put(
                u32::from(s.get(1 + b / 2).copied().unwrap_or(0) >> (4 * (b % 2))),
                4,
            );
        }
    }
    w.bytes()?;
    Ok(w.bit)
}

/// Decode a Rice session's codes from `bytes`, bit `start` on, into statistics of weight `count` (codes
/// sized for `n` points); with `D` = 0 only parses. Returns them, the bit after the codes and the
/// ceilings (a step code or the scatter's code at 255).
fn decode_rice<const D: usize>(
    codec: SummaryCodec,
    dim: usize,
    (n, count): (u32, f32),
    bytes: &[u8],
    start: usize,
) -> Result<(ObsStats<D>, usize, crate::wire::Ceiling), WireError> {
    let lead = usize::from(codec.lead).min(dim);
    let mut r = crate::wire::rice::BitReader { bytes, bit: start };
    let mut t = [0.0f32; D];
    let mut tmp = [0.0f32; D];
    let steps = {
        let (lead_band, rest_band) = t.split_at_mut(lead.min(D));
        let bands = if D == 0 {
            [None, None]
        } else {
            [Some(lead_band), Some(rest_band)]
        };
        crate::wire::rice::decode_bands(&mut r, [lead, dim - lead], bands, n, |c| {
            log_value(c, SCALE_OFFSET)
        })?
    };
    let (lead_band, rest_band) = t.split_at_mut(lead.min(D));
    let (lead_tmp, rest_tmp) = tmp.split_at_mut(lead.min(D));
    rotate(lead_band, lead_tmp);
    rotate(rest_band, rest_tmp);
    let mut scatter = [0.0f32; D];
    let mut psi_code = 0;
    if n >= 2 {
        psi_code = r.get(8)? as u8;
        let psi_max = log_value(psi_code, PSI_OFFSET);
        let blocks =
            NonZeroUsize::new(usize::from(codec.psi_blocks)).ok_or(WireError::BadConfig)?;
        for b in 0..blocks.get() {
            let c = r.get(4)? as i32;
            if psi_max > 0.0 {
                let v = psi_max * f32math::pow2_steps(-c, BLOCK_STEPS_PER_OCTAVE);
                for p in scatter
                    .get_mut(block_range(D, blocks, b))
                    .unwrap_or_default()
                {
                    *p = v;
                }
            }
        }
    }
    let ceiling = crate::wire::Ceiling {
        mean_scale: steps.contains(&u8::MAX),
        psi: psi_code == u8::MAX,
    };
    let obs = ObsStats {
        count,
        mean: t,
        scatter,
    };
    Ok((obs, r.bit, ceiling))
}

/// The bit after a Rice session's codes of a summary of `count` points starting at bit `start` of
/// `bytes` (read from them).
pub(crate) fn rice_end<const D: usize>(
    codec: SummaryCodec,
    dim: usize,
    count: u32,
    bytes: &[u8],
    start: usize,
) -> Result<usize, WireError> {
    decode_rice::<0>(codec, dim, (count, 0.0), bytes, start).map(|(_, end, _)| end)
}

/// A Rice session's summary codes at bit `start` of `bytes`, sized for `n` points, as statistics of
/// weight `count`: them, the bit after the codes, and the ceilings.
pub(crate) fn decode_rice_at<const D: usize>(
    codec: SummaryCodec,
    (n, count): (u32, f32),
    bytes: &[u8],
    start: usize,
) -> Result<(ObsStats<D>, usize, crate::wire::Ceiling), WireError> {
    codec.validate(D)?;
    decode_rice::<D>(codec, D, (n, count), bytes, start)
}
