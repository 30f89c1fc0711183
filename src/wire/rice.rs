//! Rice sessions ([`super::SummaryCodec::rice`]): each summary is one bit stream — its head as
//! Exp-Golomb codes, its mean bands rounded to multiples of steps the sender chooses per voxel and written
//! with a Golomb–Rice code whose parameter it also chooses per band, then the scatter.
//!
//! Why: the packed codes give every component the same number of bits and scale them to the band's
//! largest entry, so most codes sit near the middle and their entropy is well below their width
//! (`demo --codec-study`). A step chosen freely and a variable-length code spend bits where the values
//! are: on the demo's map the base station's error against the robot's map falls from 0.0399 to 0.0235
//! for 13.91 instead of 13.78 wire bytes per point (`host-sim/src/demo_radio.rs`). Rice rather than an
//! arithmetic coder: a summary is ≈ 35 bytes and must stand alone (a lost frame breaks no other), where an
//! arithmetic coder's flush costs 2–4 bytes per summary, and a Rice code is a few lines to implement from
//! the spec (its symbols cost ≈ 0.1–0.15 bit more than their entropy). The step is the sender's policy
//! ([`Policy`]): a receiver only multiplies.

use super::WireError;

/// Bits of a band's Rice parameter k (0..=7).
const K_BITS: u32 = 3;
/// A prefix of this many 1 bits escapes: the zigzagged value follows in [`RAW_BITS`] bits.
const ESCAPE: u32 = 6;
/// Bits of an escaped value.
const RAW_BITS: u32 = 8;
/// Largest |q| a sender writes (a zigzagged q then fits [`RAW_BITS`]).
const MAX_Q: i32 = 127;

/// How a sender chooses its steps (a receiver needs none of this). A band's step is the whole mean's
/// norm ‖m‖ divided by 2^(`eighths`/8), and by a further 2^(`per_doubling`/8) per doubling of the point
/// count n: the error a receiver sees is relative (‖Δμ‖/‖μ‖), so the step follows ‖m‖, and a voxel of
/// many points weighs more in every posterior around it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Policy {
    /// Lead band: log₂(‖m‖ / step) in eighths of an octave, for n = 1.
    pub lead_eighths: u8,
    /// The other components: the same.
    pub rest_eighths: u8,
    /// Eighths of an octave the lead band's step shrinks per doubling of n (⌊log₂ n⌋ doublings, at
    /// most 6).
    pub lead_per_doubling: u8,
    /// The same for the other components.
    pub rest_per_doubling: u8,
    /// Eighths of an octave the other components' step of a one-point voxel is coarser: such a voxel
    /// weighs little in the posteriors around it.
    pub rest_single: i8,
}

impl Policy {
    /// The policy Rice sessions are encoded with (measured on the demo's map, `demo --codec-study`).
    pub const DEFAULT: Self = Self {
        lead_eighths: 52,
        rest_eighths: 47,
        lead_per_doubling: 4,
        rest_per_doubling: 2,
        rest_single: 0,
    };
}

/// Bits written LSB first into a zeroed buffer (bits past its end are counted, not written).
pub(super) struct BitWriter<'a> {
    pub(super) out: &'a mut [u8],
    pub(super) bit: usize,
}

/// Longest Exp-Golomb prefix: values below 2³⁵ − 1.
const EXP_GOLOMB_MAX_PREFIX: u32 = 34;

/// Most bits of an unstamped summary's head: three key deltas and the residency delta of at most 65
/// bits each (the Exp-Golomb code of a u32), the final flag, and the count (≤ 2²⁴: 49 bits). Keys far
/// apart take more than a packed head's 24 bytes: frames are sized by it
/// ([`super::SummaryCodec::max_summary_len`]). (A stamped head's time and weight are counted apart.)
pub const HEAD_MAX_BITS: usize = 4 * 65 + 1 + 49;

impl BitWriter<'_> {
    /// Exp-Golomb code of v (order 0): with w = v + 1 of b bits, b − 1 one bits, a zero bit, then the
    /// low b − 1 bits of w, least significant first. v < 2³⁵ − 1.
    pub(super) fn exp_golomb(&mut self, v: u64) {
        let w = v.saturating_add(1);
        let len = 63 - w.leading_zeros();
        for _ in 0..len {
            self.put(1, 1);
        }
        self.put(0, 1);
        self.put(w as u32, len.min(32));
        if len > 32 {
            self.put((w >> 32) as u32, len - 32);
        }
    }

    /// Bytes written (the last one padded with 0 bits), if they all fit.
    pub(super) fn bytes(&self) -> Result<usize, WireError> {
        let n = self.bit.div_ceil(8);
        if n <= self.out.len() {
            Ok(n)
        } else {
            Err(WireError::BufferFull)
        }
    }

    pub(super) fn put(&mut self, v: u32, n: u32) {
        for i in 0..n as usize {
            if let Some(b) = self.out.get_mut((self.bit + i) / 8) {
                *b |= ((v >> i & 1) as u8) << ((self.bit + i) % 8);
            }
        }
        self.bit += n as usize;
    }
}

/// Bits read LSB first; reading past the end is [`WireError::Truncated`].
pub(super) struct BitReader<'a> {
    pub(super) bytes: &'a [u8],
    pub(super) bit: usize,
}

impl BitReader<'_> {
    /// An Exp-Golomb value ([`BitWriter::exp_golomb`]); a prefix longer than 34 is malformed.
    pub(super) fn exp_golomb(&mut self) -> Result<u64, WireError> {
        let mut len = 0;
        while self.get(1)? == 1 {
            len += 1;
            if len > EXP_GOLOMB_MAX_PREFIX {
                return Err(WireError::Malformed);
            }
        }
        let low = u64::from(self.get(len.min(32))?);
        let high = if len > 32 {
            u64::from(self.get(len - 32)?) << 32
        } else {
            0
        };
        Ok(((1u64 << len) | high | low) - 1)
    }

    pub(super) fn get(&mut self, n: u32) -> Result<u32, WireError> {
        let mut v = 0u32;
        for i in 0..n as usize {
            let byte = self
                .bytes
                .get((self.bit + i) / 8)
                .ok_or(WireError::Truncated)?;
            v |= u32::from(byte >> ((self.bit + i) % 8) & 1) << i;
        }
        self.bit += n as usize;
        Ok(v)
    }

    /// One zigzagged value of parameter k.
    fn symbol(&mut self, k: u32) -> Result<u32, WireError> {
        let mut u = 0;
        while u < ESCAPE && self.get(1)? == 1 {
            u += 1;
        }
        if u == ESCAPE {
            return self.get(RAW_BITS);
        }
        Ok(u << k | self.get(k)?)
    }
}

const fn zigzag(q: i32) -> u32 {
    ((q << 1) ^ (q >> 31)) as u32
}

const fn unzigzag(z: u32) -> i32 {
    ((z >> 1) as i32) ^ -((z & 1) as i32)
}

/// Bits of one zigzagged value z (≤ 255) with parameter k.
const fn symbol_bits(z: u32, k: u32) -> u32 {
    let u = z >> k;
    if u < ESCAPE {
        u + 1 + k
    } else {
        ESCAPE + RAW_BITS
    }
}

fn put_symbol(w: &mut BitWriter<'_>, z: u32, k: u32) {
    let u = z >> k;
    if u < ESCAPE {
        w.put((1 << u) - 1, u + 1);
        w.put(z, k);
    } else {
        w.put((1 << ESCAPE) - 1, ESCAPE);
        w.put(z, RAW_BITS);
    }
}

/// The integer of component v at step `step` (> 0): v/step rounded to nearest, clamped to ±[`MAX_Q`].
fn quantize(v: f32, step: f32) -> i32 {
    // The cast saturates and maps NaN to 0.
    (libm::roundf(v / step) as i32).clamp(-MAX_Q, MAX_Q)
}

/// The best parameter for a band's values at `step` and the bits it takes (k and the values).
fn best_k(t: &[f32], step: f32) -> (u32, u32) {
    let mut best = (0, u32::MAX);
    for k in 0..1 << K_BITS {
        let bits: u32 = t
            .iter()
            .map(|&v| symbol_bits(zigzag(quantize(v, step)), k))
            .sum();
        if bits < best.1 {
            best = (k, bits);
        }
    }
    (best.0, K_BITS + best.1)
}

/// The policy's step codes of the bands (lead, rest) for a mean whose norm has log code `norm_codes`
/// and `count` points.
fn step_codes(policy: Policy, norm_codes: [u8; 2], count: u32) -> [u8; 2] {
    let doublings = if count > 1 { count.ilog2().min(6) } else { 0 };
    let code = |norm_code: u8, eighths: u8, per_doubling: u8| {
        let shrink = (doublings * u32::from(per_doubling)) as i32;
        (i32::from(norm_code) - i32::from(eighths) - shrink).clamp(1, 255) as u8
    };
    [
        code(norm_codes[0], policy.lead_eighths, policy.lead_per_doubling),
        code(norm_codes[1], policy.rest_eighths, policy.rest_per_doubling)
            .saturating_add_signed(if count < 2 { policy.rest_single } else { 0 })
            .max(1),
    ]
}

/// The rest band's step code a receiver predicts from the lead band's, for a summary of `count` points:
/// `lead` + 5 + 2·min(⌊log₂ n⌋, 6). [`Policy::DEFAULT`] makes the rest step coarser than the lead's by
/// (52 − 47) eighths and by (4 − 2) eighths per doubling, so what it sends is predicted exactly and its
/// residual, zigzag(0), is the one bit `0` (protocol 5; protocol 4 subtracted, ≈ 10 bits a summary).
fn predicted_rest(lead: u8, count: u32) -> i32 {
    let doublings = if count > 1 { count.ilog2().min(6) } else { 0 } as i32;
    i32::from(lead) + 5 + 2 * doublings
}

/// Bits of the Exp-Golomb code of v.
const fn exp_golomb_bits(v: u32) -> u32 {
    2 * (32 - (v + 1).leading_zeros()) - 1
}

/// Write the rotated bands `bands` (lead, rest; the lead may be empty) into `w`: the first non-empty
/// band's step code (8 bits); with a lead band, the rest band's step as the Exp-Golomb code of
/// zigzag(its code − [`predicted_rest`]); then for each band whose step is not 0, k (3 bits) and the
/// band's values. Steps are chosen by `policy` from ‖m‖ (`norm`) and made coarser by whole octaves until
/// the mean takes at most `cap` bytes.
pub(super) fn encode_bands(
    policy: Policy,
    bands: [&[f32]; 2],
    (norm, count): (f32, u32),
    cap: usize,
    w: &mut BitWriter<'_>,
    step_value: impl Fn(u8) -> f32,
    norm_code: impl Fn(f32) -> u8,
) {
    let has_lead = !bands[0].is_empty();
    let zero = |b: &[f32]| b.iter().all(|&v| v == 0.0 || !v.is_finite());
    let base = if norm > 0.0 && norm.is_finite() {
        norm_code(norm)
    } else {
        0
    };
    // The policy's steps, at least as coarse as keeps every value within ±MAX_Q steps (never clamped).
    let mut finest = step_codes(policy, [base; 2], count);
    for (f, band) in finest.iter_mut().zip(&bands) {
        let peak = band.iter().fold(0.0f32, |a, &v| {
            if libm::fabsf(v) > a {
                libm::fabsf(v)
            } else {
                a
            }
        });
        if peak > 0.0 && peak.is_finite() {
            *f = (*f).max(norm_code(peak / (MAX_Q as f32 + 0.5)));
        }
    }
    // Coarser by whole octaves until the bytes fit `cap`.
    let mut chosen = ([0u8; 2], [0u32; 2]);
    for extra in 0..=32u8 {
        let mut ks = [0u32; 2];
        let mut codes = [0u8; 2];
        let mut bits = 0;
        // Zipped, not indexed: no bounds check (the boards' `panic-never` build links this).
        for (((band, code), k), fine) in bands.iter().zip(&mut codes).zip(&mut ks).zip(&finest) {
            if band.is_empty() || base == 0 || zero(band) {
                continue;
            }
            *code = fine.saturating_add(8u8.saturating_mul(extra));
            let (best, b) = best_k(band, step_value(*code));
            *k = best;
            bits += b;
        }
        if has_lead {
            bits += exp_golomb_bits(zigzag(
                i32::from(codes[1]) - predicted_rest(codes[0], count),
            ));
        }
        // Cannot fail at 32 octaves coarser (every value 0 or ±1); else all bands zero.
        if (bits as usize).div_ceil(8) < cap {
            chosen = (codes, ks);
            break;
        }
    }
    let (codes, ks) = chosen;
    w.put(u32::from(if has_lead { codes[0] } else { codes[1] }), 8);
    if has_lead {
        let residual = i32::from(codes[1]) - predicted_rest(codes[0], count);
        w.exp_golomb(u64::from(zigzag(residual)));
    }
    for ((band, &code), &k) in bands.iter().zip(&codes).zip(&ks) {
        if code == 0 || band.is_empty() {
            continue;
        }
        let step = step_value(code);
        w.put(k, K_BITS);
        for &v in band.iter() {
            put_symbol(w, zigzag(quantize(v, step)), k);
        }
    }
}

/// The step codes (lead, rest; 0 for a band that is absent or zero) read from `r`, a summary of
/// `count` points.
pub(super) fn read_steps(
    r: &mut BitReader<'_>,
    has_lead: bool,
    count: u32,
) -> Result<[u8; 2], WireError> {
    let first = r.get(8)? as u8;
    if !has_lead {
        return Ok([0, first]);
    }
    let z = u32::try_from(r.exp_golomb()?).map_err(|_| WireError::Malformed)?;
    let code = predicted_rest(first, count) + unzigzag(z);
    let code = u8::try_from(code).map_err(|_| WireError::Malformed)?;
    Ok([first, code])
}

/// Read bands written by [`encode_bands`] (a summary of `count` points) from `r` into `bands` (values
/// q·step, still rotated; `None` for a band only to be skipped); returns the step codes.
pub(super) fn decode_bands(
    r: &mut BitReader<'_>,
    lens: [usize; 2],
    mut bands: [Option<&mut [f32]>; 2],
    count: u32,
    step_value: impl Fn(u8) -> f32,
) -> Result<[u8; 2], WireError> {
    let codes = read_steps(r, lens[0] > 0, count)?;
    for ((band, &code), &len) in bands.iter_mut().zip(&codes).zip(&lens) {
        if code == 0 || len == 0 {
            if let Some(b) = band {
                b.fill(0.0);
            }
            continue;
        }
        let step = step_value(code);
        let k = r.get(K_BITS)?;
        for i in 0..len {
            let q = unzigzag(r.symbol(k)?);
            if let Some(v) = band.as_mut().and_then(|b| b.get_mut(i)) {
                *v = q as f32 * step;
            }
        }
    }
    Ok(codes)
}

/// The most bytes a Rice-coded mean takes for D components: the step byte, then `D` × 6 bits, the two k
/// and the rest band's step residual (at most 19 bits). (Packed codes of 6 bits per component; a sender
/// coarsens its steps to stay within it.)
pub const fn cap(dim: usize, lead: usize) -> usize {
    1 + (6 * dim + 2 * K_BITS as usize + if lead > 0 { 19 } else { 0 }).div_ceil(8)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_golomb_round_trips_up_to_its_limit() {
        let values = [
            0u64,
            1,
            2,
            3,
            6,
            7,
            127,
            1 << 20,
            u64::from(u32::MAX),
            (1 << 35) - 2,
        ];
        let mut buf = [0u8; 128];
        let mut w = BitWriter {
            out: &mut buf,
            bit: 0,
        };
        for v in values {
            w.exp_golomb(v);
        }
        assert_eq!(w.bit, 1 + 3 + 3 + 5 + 5 + 7 + 15 + 41 + 65 + 69);
        let mut r = BitReader {
            bytes: &buf,
            bit: 0,
        };
        for v in values {
            assert_eq!(r.exp_golomb().unwrap(), v);
        }
        // The spec's examples, in stream order: 0 → 0, 1 → 100, 2 → 101, 3 → 11000.
        let mut spec = [0u8; 2];
        let mut w = BitWriter {
            out: &mut spec,
            bit: 0,
        };
        for v in 0..4 {
            w.exp_golomb(v);
        }
        assert_eq!((w.bit, spec), (12, [0b1101_0010, 0b0000_0001]));
        // 35 one bits: malformed.
        let ones = [0xff; 8];
        let mut r = BitReader {
            bytes: &ones,
            bit: 0,
        };
        assert_eq!(r.exp_golomb(), Err(WireError::Malformed));
    }

    /// The policy's two step codes differ by exactly what the receiver predicts, at every norm and count
    /// away from the codes' ends (1 and 255).
    #[test]
    fn the_default_policy_steps_are_the_predicted_ones() {
        for norm in 80u8..=190 {
            for count in (1..=200).chain([1 << 10, 1 << 24]) {
                let [lead, rest] = step_codes(Policy::DEFAULT, [norm; 2], count);
                assert_eq!(
                    i32::from(rest),
                    predicted_rest(lead, count),
                    "{norm} {count}"
                );
            }
        }
    }

    #[test]
    fn symbols_round_trip_for_every_k() {
        for k in 0..8 {
            let mut buf = [0u8; 512];
            let mut w = BitWriter {
                out: &mut buf,
                bit: 0,
            };
            let mut bits = 0;
            for q in -MAX_Q..=MAX_Q {
                put_symbol(&mut w, zigzag(q), k);
                bits += symbol_bits(zigzag(q), k);
            }
            assert_eq!(w.bit as u32, bits);
            let mut r = BitReader {
                bytes: &buf,
                bit: 0,
            };
            for q in -MAX_Q..=MAX_Q {
                assert_eq!(unzigzag(r.symbol(k).unwrap()), q, "k {k}");
            }
        }
    }
}
