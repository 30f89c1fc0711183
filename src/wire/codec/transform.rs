//! The mean's transform: an orthonormal Walsh–Hadamard rotation (so every component of a band carries an
//! equal share of its energy), and a band rotated and written as a scale code and packed uniform codes,
//! and read back.

use super::*;

/// One stage of the Walsh–Hadamard transform in constant geometry: pairs (2j, 2j + 1) of `from` become
/// their sum at j and their difference at j + n/2 of `to` (both of length n). log₂ n stages are the
/// transform in Sylvester order, each output the same tree of sums and differences as the in-place
/// butterflies (so the same bits), but every stage is one short loop instead of log₂ n nested ones.
#[inline(never)]
fn hadamard_stage(from: &[f32], to: &mut [f32]) {
    let (from, to) = core::hint::black_box((from, to));
    let (sums, diffs) = to.split_at_mut(to.len() / 2);
    for ((pair, s), d) in from.chunks_exact(2).zip(sums).zip(diffs) {
        if let [x, y] = *pair {
            *s = x + y;
            *d = x - y;
        }
    }
}

/// Orthonormal Walsh–Hadamard transform (its own inverse) when D is a power of two; identity otherwise.
/// Returns the largest |entry| of the result (NaN entries ignored; 0 for none).
#[cfg(test)]
pub(in crate::wire) fn hadamard<const D: usize>(v: &mut [f32; D]) -> f32 {
    rotate(v, &mut [0.0; D])
}

/// [`hadamard`] of a slice of any length (`tmp` as long as `v`, scratch).
#[inline(never)]
pub(super) fn rotate(v: &mut [f32], tmp: &mut [f32]) -> f32 {
    let len = v.len();
    if len < 2 || !len.is_power_of_two() || tmp.len() != len {
        return scale_all(v, 1.0);
    }
    let stages = len.trailing_zeros();
    for _ in 0..stages / 2 {
        hadamard_stage(v, tmp);
        hadamard_stage(tmp, v);
    }
    if stages % 2 == 1 {
        hadamard_stage(v, tmp);
        v.copy_from_slice(tmp);
    }
    scale_all(v, 1.0 / libm::sqrtf(len as f32))
}

// The summary codec runs once per voxel sent, not per point: its loops over D stay loops instead of being
// unrolled D times into flash (≈ 6 KB at D = 64). They take slices, are not inlined, and hide the length
// (a constant everywhere, which the optimizer would propagate) behind `black_box`; only code size and a
// few instructions per voxel depend on that, never a result. Maxima are comparisons, not `f32::max`,
// which thumbv7em lowers to a call to `fmaxf` per element.

/// `v *= k`, element-wise; returns the largest |v| after it (NaN entries ignored; 0 for none).
#[inline(never)]
pub(super) fn scale_all(v: &mut [f32], k: f32) -> f32 {
    let v = core::hint::black_box(v);
    let mut peak = 0.0f32;
    for x in v {
        *x *= k;
        let a = libm::fabsf(*x);
        if a > peak {
            peak = a;
        }
    }
    peak
}

/// The largest v, at least 0 (NaN entries ignored), as `fold(0, max)`.
#[inline(never)]
pub(super) fn max_or_zero(values: &[f32]) -> f32 {
    core::hint::black_box(values)
        .iter()
        .fold(0.0f32, |a, &v| if v > a { v } else { a })
}

/// One band of the mean: rotate `t` (`tmp`: scratch of its length), write its scale code and its codes
/// of `bits` bits (mid-rise uniform, packed LSB first) into `out` (`1 + ⌈len·bits/8⌉` bytes, zeroed).
#[inline(never)]
pub(super) fn encode_band(t: &mut [f32], tmp: &mut [f32], bits: u32, out: &mut [u8]) {
    let peak = rotate(t, tmp);
    let Some((scale_byte, mean_bytes)) = out.split_first_mut() else {
        return;
    };
    let levels = 1u32 << bits;
    let scale_code = if peak > 0.0 && peak.is_finite() {
        log_code_up(peak, SCALE_OFFSET)
    } else {
        0
    };
    *scale_byte = scale_code;
    let scale = log_value(scale_code, SCALE_OFFSET);
    if scale > 0.0 {
        let half = (levels / 2) as f32;
        let top = levels - 1;
        // Bits not yet stored (LSB first) and how many.
        let (mut pending, mut n) = (0u32, 0u32);
        let mut bytes = mean_bytes.iter_mut();
        for &v in t.iter() {
            // The float-to-int cast truncates and saturates (NaN → 0), so here it is floor clamped at 0:
            // a component a rounding step below −scale still gets code 0.
            let q = (((v / scale + 1.0) * half) as u32).min(top);
            pending |= q << n;
            n += bits;
            if n >= 8 {
                if let Some(b) = bytes.next() {
                    *b = pending as u8;
                }
                pending >>= 8;
                n -= 8;
            }
        }
        if let Some(b) = bytes.next() {
            *b = pending as u8;
        }
    }
}

/// Read one band written by [`encode_band`] from `bytes` into `t` (rotated back; `tmp`: scratch).
pub(super) fn decode_band(bytes: &[u8], bits: u32, t: &mut [f32], tmp: &mut [f32]) {
    let scale = log_value(bytes.first().copied().unwrap_or(0), SCALE_OFFSET);
    if scale > 0.0 {
        let bits = bits as usize;
        let half = (1u32 << bits) as f32 / 2.0;
        let mut bit = 8usize;
        for v in t.iter_mut() {
            let mut q = 0u32;
            for k in 0..bits {
                let byte = bytes.get((bit + k) / 8).copied().unwrap_or(0);
                q |= u32::from(byte >> ((bit + k) % 8) & 1) << k;
            }
            *v = scale * ((q as f32 + 0.5) / half - 1.0);
            bit += bits;
        }
        rotate(t, tmp);
    }
}
