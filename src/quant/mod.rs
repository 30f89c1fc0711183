//! Compact voxel codes: how a 64-d voxel's observation statistics fit in about a hundred bytes.
//!
//! A voxel's f32 statistics (n, m, S) at D = 64 are 516 B (the authors' code keeps 528 B of posterior per
//! voxel). On a microcontroller the map must hold thousands of voxels, so each is stored as:
//! - n as f32 — exact, so every point is counted once through every merge;
//! - m as [`MU_BITS`]-bit signed codes times one per-voxel f16 scale (max |mᵢ| / q_max), optionally with a
//!   per-dimension weight 2^−sᵢ of that step ([`MeanWeights`], feature `mean-weights`);
//! - S as [`PSI_BITS`]-bit codes of its float bit pattern shifted right, i.e. a "minifloat" with
//!   2^[`PSI_STEPS_LOG2`] steps per octave, relative to a per-voxel base: S is non-negative and spans orders
//!   of magnitude, so a logarithmic code keeps the relative error even (a single point's S = 0 codes as 0).
//!   Encoding and decoding are bit operations (no `log`/`exp` on the hot path).
//!
//! Rounding is stochastic (unbiased): when n is large, one visit moves m by far less than a code step, and
//! round-to-nearest would drop every such update; dithered rounding keeps them in expectation. The dither
//! comes from a per-map xorshift generator, so results are reproducible. A voxel is re-encoded only when it
//! cools out of the local map's f32 hot tier (`crate::local_map`), once per visit.

use crate::obs::ObsStats;
use half::f16;

/// Wraps a function that is inlined where an FPU makes the f32 path the fast one, and kept as one
/// out-of-line copy on an MCU without one (thumbv6m's `eabi`, riscv32 without F), where flash is the scarce
/// thing and the call costs little next to the soft-float work around it.
macro_rules! inline_with_fpu {
    ($item:item) => {
        #[cfg_attr(latentbki_soft_float, inline(never))]
        #[cfg_attr(not(latentbki_soft_float), inline)]
        $item
    };
}

/// Whether the target has an FPU, so the f32 encoder is the fast path and worth code twice where that
/// saves instructions (unswitched loops, inlined conversions). Without one (thumbv6m's `eabi`, riscv32
/// without F) flash is the scarce thing and the soft float around the encoder costs far more: one path.
pub(crate) const HAS_FPU: bool = cfg!(not(latentbki_soft_float));

mod bytes;
mod cooling;
mod fixed;
#[cfg(all(feature = "sparse-cooling", not(latentbki_soft_float)))]
mod merge;
mod weights;
pub use bytes::{mean_codes_len, scatter_codes_len, StoredCodes, STORED_LAYOUT};
pub use cooling::Cooling;
pub use fixed::Int8Fix;
pub use weights::{MeanWeights, MAX_MEAN_SHIFT};

// Widths measured on the 400-frame tile run (host-sim/tests/local_map_accuracy.rs: μ RMS, Ψ p95 with the
// default / a weak prior) and on the streaming tests' PCA features (μ RMS against the f32 reference), bytes
// per voxel with slot and index:
//   m 6 + S 5 (4 steps/octave): 112 B, μ 2.1 % / 6.8 % (PCA), Ψ p95 1.7 % / 7.9 %
//   m 7 + S 5 (4 steps/octave): 120 B, μ 1.0 % / 3.6 % (PCA), Ψ p95 1.2 % / 5.3 %   ← used
//   m 8 + S 5 (4 steps/octave): 128 B, μ 0.5 % / 1.9 % (PCA), Ψ p95 1.1 % / 4.5 %
//   m 7 + S 4 (2 steps/octave): 112 B, Ψ p95 2.1 % / 8.8 %;  m 6 + S 4 (2 steps/octave): 104 B, 10.6 % (fails)
// Re-measured for 4-bit scatter with one re-encode per visit (the hot tier), same test, Ψ p95 / E-opt p95 with
// the default / a weak prior (the scatter does not enter μ: the demo's μ figures are unchanged):
//   m 7 + S 5 (4 steps/octave): 120 B, Ψ 1.2 % / 5.3 %, E-opt 2.2 % / 5.1 %   ← used
//   m 7 + S 4 (2 steps/octave): 112 B, Ψ 2.1 % / 8.8 %, E-opt 4.2 % / 9.5 %
//   m 7 + S 4 (4 steps/octave, 4 octaves): 112 B, Ψ 5.4 % / 23.6 % (fails: small scatters clamp to the base)
// The 4-bit row was used for a while (issue 18, answerable voxels per KiB): it bought 27.4 → 27.7 against a goal
// of 35 and doubled the Ψ and E-opt tails (weak prior E-opt p95 0.095 against a bound of 0.10), so the 5-bit
// codes are back; the map is sized from a fixed RAM budget, so narrower slots buy voxels that mostly overlap.
/// Bits per mean code (signed).
pub const MU_BITS: u32 = 7;
/// Bits per scatter code.
pub const PSI_BITS: u32 = 5;
/// log2 of the scatter code steps per octave: 4 steps (mantissas 1, 1.25, 1.5, 1.75: steps of 14–25 %), so 5
/// bits span 8 octaves.
pub const PSI_STEPS_LOG2: u32 = 2;

/// Bytes of packed codes for a D-dimensional voxel (mean codes, then scatter codes, each section
/// byte-aligned).
pub const fn packed_len(d: usize) -> usize {
    (d * MU_BITS as usize).div_ceil(8) + (d * PSI_BITS as usize).div_ceil(8)
}

const fn section_len(d: usize, width: u32) -> usize {
    (d * width as usize).div_ceil(8)
}

/// A weighed map's mean grid ([`QuantVoxel::reencode_fine`]): the scale is kept while the largest |μᵢ|
/// reaches 1/1.25 of the top code. With weights the small components use their codes' range, so the slack
/// of the step is the map's largest error left; measured on the demo's tile (the robot's map against the
/// f32 reference, RMS ‖Δμ‖/‖μ‖, weights from the spreads): 1/4 and 25 % headroom (the unweighed map's)
/// 0.0296, 1/2 and 25 % 0.0217, 1/1.5 and 10 % 0.0182, 1/1.25 and 5 % 0.0165.
pub const FINE_KEEP: f32 = 1.25;
/// Headroom of a weighed map's new mean scale over its largest |μᵢ| (5 %; see [`FINE_KEEP`]).
pub const FINE_HEADROOM: f32 = 1.05;

const MU_QMAX: i32 = (1 << (MU_BITS - 1)) - 1;
const PSI_CODE_MAX: u32 = (1 << PSI_BITS) - 1;
const PSI_SHIFT: u32 = 23 - PSI_STEPS_LOG2;

/// A small, fast, seedable dither source (xorshift32). Not for statistics, only for rounding.
#[derive(Clone, Debug)]
pub struct Dither(u32);

impl Dither {
    /// An unseeded generator (all-zero state: it yields zeros until replaced by [`Dither::new`]).
    pub const UNSEEDED: Self = Self(0);

    /// A generator from a non-zero seed (zero is replaced).
    pub const fn new(seed: u32) -> Self {
        Self(if seed == 0 { 0x9E37_79B9 } else { seed })
    }
    #[inline]
    fn next(&mut self) -> u32 {
        let mut x = self.0;
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        self.0 = x;
        x
    }
}

/// A voxel's observation statistics (n, m, S) in compact form. `P` must be [`packed_len`]`(D)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct QuantVoxel<const D: usize, const P: usize> {
    /// n, exact.
    pub count: f32,
    mu_scale: f16,
    psi_base: u16,
    codes: [u8; P],
}

/// Largest `bits & 0x7FFF_FFFF` over the values (the magnitude of the largest |v| for finite values), at
/// most the bits of f32::MAX.
#[inline]
fn max_magnitude_bits(values: &[f32]) -> u32 {
    let mut m = 0u32;
    for &v in values {
        let b = v.to_bits() & 0x7FFF_FFFF;
        if b > m {
            m = b;
        }
    }
    m.min(f32::MAX.to_bits())
}

/// Bytes of `width`-bit codes from `codes` (≤ 8 of them, the first in the lowest bits), little-endian into
/// `out` (≤ `width` bytes: 8 codes of `width` bits fill `width` bytes).
#[inline(always)]
fn put_codes(acc: u64, out: &mut [u8]) {
    for (b, src) in out.iter_mut().zip(acc.to_le_bytes()) {
        *b = src;
    }
}

/// What a section of codes stands for, to [`unpack_into`]: mean codes (signed `MU_BITS` bits) times the
/// voxel's scale, or scatter codes above the voxel's base.
#[derive(Clone, Copy)]
enum Section {
    Mean(f32),
    Scatter(u32),
}

inline_with_fpu! {
/// Unpack `width`-bit codes (8 to `width` bytes, as [`QuantVoxel::reencode`] packs them) and turn each
/// into its value as it comes out (no array of codes in between: on a Cortex-M4F a decode took 1,090
/// instructions with one, 716 without). Inlined where an FPU makes the f32 path fast (the section is then
/// a constant); one out-of-line copy on an MCU without one (flash).
fn unpack_into(data: &[u8], width: u32, out: &mut [f32], section: Section) {
    let w = width as usize;
    let mask = (1u64 << width) - 1;
    for (chunk, src) in out.chunks_mut(8).zip(data.chunks(w)) {
        let mut bytes = [0u8; 8];
        for (b, s) in bytes.iter_mut().zip(src) {
            *b = *s;
        }
        let acc = u64::from_le_bytes(bytes);
        for (i, v) in chunk.iter_mut().enumerate() {
            let c = ((acc >> (i * w)) & mask) as u32;
            *v = match section {
                // Sign-extend the MU_BITS-bit code.
                Section::Mean(scale) => ((c << (32 - MU_BITS)) as i32 >> (32 - MU_BITS)) as f32 * scale,
                Section::Scatter(base) => f32::from_bits((c + base) << PSI_SHIFT),
            };
        }
    }
}
}

/// A mean scale (f16) as f32, exactly as `half` converts it: a normal f16 by shifts where an FPU makes the
/// encode the fast path (`half`'s portable conversion branches through ≈ 20 instructions; an encode converts
/// three times), anything else through `half`. One path on an MCU without an FPU (flash).
#[inline(always)]
fn scale_to_f32(s: f16) -> f32 {
    if HAS_FPU {
        let h = u32::from(s.to_bits());
        let e = h & 0x7C00;
        if e != 0 && e != 0x7C00 {
            // Exponent bias 15 → 127: +112 in the exponent field.
            return f32::from_bits(((h & 0x8000) << 16) | (((h & 0x7FFF) << 13) + (112 << 23)));
        }
    }
    s.to_f32()
}

/// An f32 as the f16 nearest to it (ties to even), exactly as `half` rounds: [2⁻¹⁴, 65504] (normal f16
/// results) by integer operations where an FPU makes the encode the fast path, anything else through
/// `half`.
#[inline(always)]
fn scale_from_f32(x: f32) -> f16 {
    if HAS_FPU {
        let b = x.to_bits();
        if (0x3880_0000..=0x477F_E000).contains(&b) {
            let h = (b >> 13) - (112 << 10);
            let rest = b & 0x1FFF;
            let up = rest > 0x1000 || (rest == 0x1000 && h & 1 == 1);
            return f16::from_bits((h + u32::from(up)) as u16);
        }
    }
    f16::from_f32(x)
}

/// The minifloat key of a positive finite f32: exponent and top mantissa bits, monotone in the value.
/// `dither` (0..=255) is a fraction of one code step; 0 truncates. Zero, negative values (sign bit set,
/// negative as i32) and −0 give key 0.
#[inline]
fn psi_key(psi: f32, dither: u8) -> u32 {
    let bits = psi.to_bits();
    let bits = if (bits as i32) > 0 { bits } else { 0 };
    // Adding a uniform value below one step before truncating is unbiased stochastic rounding (to 1/256
    // of a step). bits ≤ 0x7FFF_FFFF, so the sum cannot overflow.
    (bits + (u32::from(dither) << (PSI_SHIFT - 8)) + (1 << (PSI_SHIFT - 9))) >> PSI_SHIFT
}

impl<const D: usize, const P: usize> QuantVoxel<D, P> {
    const CHECK: () = assert!(P == packed_len(D), "P must be packed_len(D)");

    /// The code of nothing (n = 0, m = 0, S = 0).
    pub const EMPTY: Self = Self {
        count: 0.0,
        mu_scale: f16::ZERO,
        psi_base: 0,
        codes: [0; P],
    };

    /// Encode observation statistics (non-finite or negative inputs are clamped: callers only pass valid
    /// statistics).
    pub fn encode(stats: &ObsStats<D>, dither: &mut Dither) -> Self {
        Self::EMPTY.reencode(stats, dither)
    }

    /// Encode updated statistics of this voxel, keeping its mean's scale when it still fits.
    ///
    /// Why: a new scale puts every dimension on a new grid, and re-rounding all of them at every update makes
    /// the stored μ drift like a random walk. On an unchanged grid an unchanged value re-encodes exactly and a
    /// small update adds only noise proportional to its size. So the scale changes only when μ outgrows it or
    /// shrinks below a quarter of it, and a new scale gets 25 % headroom.
    pub fn reencode(&self, stats: &ObsStats<D>, dither: &mut Dither) -> Self {
        let mut out = *self;
        out.reencode_in::<false>(stats, dither);
        out
    }

    /// [`Self::reencode`] in place (no 104-byte value returned and copied: what the map's cooling calls).
    pub fn reencode_here(&mut self, stats: &ObsStats<D>, dither: &mut Dither) {
        self.reencode_in::<false>(stats, dither);
    }

    /// [`Self::reencode`] on a finer grid, for a map with [`MeanWeights`] (see there): the scale is kept
    /// only while the largest |μᵢ| is within 1/[`FINE_KEEP`] of the top code (not 1/4), and a new one
    /// gets [`FINE_HEADROOM`] (not 25 %).
    pub fn reencode_fine(&self, stats: &ObsStats<D>, dither: &mut Dither) -> Self {
        let mut out = *self;
        out.reencode_in::<true>(stats, dither);
        out
    }

    /// [`Self::reencode_fine`] in place.
    pub fn reencode_fine_here(&mut self, stats: &ObsStats<D>, dither: &mut Dither) {
        self.reencode_in::<true>(stats, dither);
    }

    /// [`Self::reencode_here`] (`FINE`: [`Self::reencode_fine_here`]) of statistics whose every scatter is
    /// 0 — a voxel of one point, most of a sparse sensor's coolings: the same codes, without the pass over
    /// the scatters that looks for their largest.
    pub(crate) fn reencode_unscattered_here<const FINE: bool>(
        &mut self,
        stats: &ObsStats<D>,
        dither: &mut Dither,
    ) {
        debug_assert!(stats.scatter.iter().all(|&v| v.to_bits() == 0));
        self.encode_in::<FINE>(stats, max_magnitude_bits(&stats.mean), 0, dither);
    }

    fn reencode_in<const FINE: bool>(&mut self, stats: &ObsStats<D>, dither: &mut Dither) {
        // Maxima on the bit patterns: for finite floats |a| < |b| ⟺ (bits & 0x7FFF_FFFF) orders the same as
        // integers, and on a Cortex-M4 an integer compare-and-select is 4 instructions where a float one is 6
        // (vcmp + vmrs + it + vmov) and `f32::max` is an `fmaxf` call.
        let mean_max = max_magnitude_bits(&stats.mean);
        let mut scatter_max = 0i32;
        for &v in &stats.scatter {
            scatter_max = scatter_max.max(v.to_bits() as i32);
        }
        self.encode_in::<FINE>(stats, mean_max, scatter_max, dither);
    }

    /// Encode `stats` given the largest `|mᵢ|` bits (`mean_max`, as [`max_magnitude_bits`]) and the largest
    /// scatter bits as i32 (`scatter_max`: a negative value, sign bit set, never counts): the maxima are
    /// taken by whoever made the statistics, so a merge that makes them in one pass ([`Self::merge_here`])
    /// needs no second pass to find them.
    fn encode_in<const FINE: bool>(
        &mut self,
        stats: &ObsStats<D>,
        mean_max: u32,
        scatter_max: i32,
        dither: &mut Dither,
    ) {
        let () = Self::CHECK;
        let (keep_within, headroom) = if FINE {
            (FINE_KEEP, FINE_HEADROOM)
        } else {
            (4.0, 1.25)
        };
        // Clamped to f32::MAX: non-finite inputs (never passed by callers) cannot make a non-finite scale.
        let max_abs = f32::from_bits(mean_max.min(f32::MAX.to_bits()));
        let qmax = MU_QMAX as f32;
        let prev = scale_to_f32(self.mu_scale);
        let keep = prev > 0.0 && max_abs <= prev * qmax && max_abs * keep_within >= prev * qmax;
        let mu_scale = if keep {
            self.mu_scale
        } else {
            // Round the scale up so every |μᵢ| / scale ≤ q_max after f16 rounding.
            let mut s = scale_from_f32(max_abs * headroom / qmax);
            if scale_to_f32(s) * qmax < max_abs {
                s = f16::from_bits(s.to_bits() + 1);
            }
            s
        };
        let scale = scale_to_f32(mu_scale);
        let inv = if scale > 0.0 { 1.0 / scale } else { 0.0 };

        // S ≥ 0, and a negative value (sign bit set) must not count: as i32 it is negative.
        let psi_max_bits = (scatter_max.max(0) as u32).min(f32::MAX.to_bits());
        // Every scatter 0 (a voxel of one point, most of a sparse sensor's first visits): every code is 0
        // on base 0 (a key below one step), so the section is left zero and no code is computed.
        let scatter_codes = psi_max_bits != 0;
        let top = (psi_max_bits >> PSI_SHIFT) + 1;
        let psi_base = top.saturating_sub(PSI_CODE_MAX) as u16;

        let base = i32::from(psi_base);
        // Unswitched where an FPU makes this the fast path: a voxel of one point (most of a sparse sensor's
        // coolings) runs a loop with no scatter work in it at all. One copy on an MCU without one (flash).
        if HAS_FPU && !scatter_codes {
            Self::pack_codes(&mut self.codes, stats, inv, base, false, dither);
        } else {
            Self::pack_codes(&mut self.codes, stats, inv, base, scatter_codes, dither);
        }
        self.count = stats.count;
        self.mu_scale = mu_scale;
        self.psi_base = psi_base;
    }

    /// The codes of `stats` on step 1/`inv` (mean) and above `base` (scatter, only if `scatter_codes`: else
    /// the section is left zero, every scatter being 0), into `codes`.
    #[inline(always)]
    fn pack_codes(
        codes: &mut [u8; P],
        stats: &ObsStats<D>,
        inv: f32,
        base: i32,
        scatter_codes: bool,
        dither: &mut Dither,
    ) {
        // Stochastic rounding in 1/256 of a step: ⌊(⌊256·(μᵢ·inv + OFFSET) + ½⌋ + k) / 256⌋ with k the dither
        // byte, which is ⌊μᵢ·inv + OFFSET + (k + ½)/256⌋ exactly (k is an integer) — the dither added as an
        // integer (one `uxtab` on a Cortex-M4) instead of built as a float (five instructions a code).
        // |μᵢ · inv| ≤ q_max, so the sum is positive and truncation is floor: no floorf call.
        const OFFSET: i32 = 2 * MU_QMAX + 2;
        const OFFSET_256: f32 = (OFFSET * 256) as f32 + 0.5;
        let inv_256 = inv * 256.0;
        // Clamps written as signed clamps to a power-of-two range so a Cortex-M4 does each in one `ssat` /
        // `usat`. μ: −32 cannot occur (|μᵢ · inv| ≤ q_max and u ≥ 1/512), and would decode fine.
        let mu_code = |v: f32, dither: u32| {
            let q =
                ((v * inv_256 + OFFSET_256) as i32 + (dither & 0xFF) as i32 - OFFSET * 256) >> 8;
            q.clamp(-MU_QMAX - 1, MU_QMAX) as u8 & ((1 << MU_BITS) - 1) as u8
        };
        let psi_code = |v: f32, dither: u32| {
            (psi_key(v, dither as u8) as i32 - base).clamp(0, PSI_CODE_MAX as i32) as u8
        };
        // One dither step serves two dimensions: bytes 0 and 1 for μ and Ψ of the first, 2 and 3 of the second.
        // Each code goes straight into its section's bits, 8 dimensions (`MU_BITS` and `PSI_BITS` bytes) at a
        // time: no array of codes to fill, clear and pack afterwards. Whole eights as arrays, so the shifts
        // are constants (a Cortex-M4 shifts a u64 by a variable in ≈ 5 instructions).
        // Dimensions a = 2j and a + 1 into the accumulators (the second one if there is one).
        let mut pair =
            |j: u32, m: (f32, Option<f32>), p: (f32, Option<f32>), acc: &mut (u64, u64)| {
                let d = dither.next();
                acc.0 |= u64::from(mu_code(m.0, d)) << (2 * j * MU_BITS);
                if scatter_codes {
                    acc.1 |= u64::from(psi_code(p.0, d >> 8)) << (2 * j * PSI_BITS);
                }
                if let (Some(m1), Some(p1)) = (m.1, p.1) {
                    acc.0 |= u64::from(mu_code(m1, d >> 16)) << ((2 * j + 1) * MU_BITS);
                    if scatter_codes {
                        acc.1 |= u64::from(psi_code(p1, d >> 24)) << ((2 * j + 1) * PSI_BITS);
                    }
                }
            };
        let (mu_part, psi_part) = codes.split_at_mut(section_len(D, MU_BITS));
        let (m8s, m_rest) = stats.mean.as_chunks::<8>();
        let (p8s, p_rest) = stats.scatter.as_chunks::<8>();
        let mut outs = mu_part
            .chunks_mut(MU_BITS as usize)
            .zip(psi_part.chunks_mut(PSI_BITS as usize));
        for ((m, p), (mu_out, psi_out)) in m8s.iter().zip(p8s).zip(&mut outs) {
            let mut acc = (0, 0);
            // Unrolled by hand where an FPU makes this the fast path: constant shifts (−950 instructions a
            // re-encode on the M4F). Rolled on an MCU without one, where flash is scarce and the soft float
            // around it costs far more than the shifts (riscv32imac: ≈ 1 KB less).
            #[cfg(not(latentbki_soft_float))]
            {
                pair(0, (m[0], Some(m[1])), (p[0], Some(p[1])), &mut acc);
                pair(1, (m[2], Some(m[3])), (p[2], Some(p[3])), &mut acc);
                pair(2, (m[4], Some(m[5])), (p[4], Some(p[5])), &mut acc);
                pair(3, (m[6], Some(m[7])), (p[6], Some(p[7])), &mut acc);
            }
            #[cfg(latentbki_soft_float)]
            for ((j, m), p) in (0..4).zip(m.as_chunks::<2>().0).zip(p.as_chunks::<2>().0) {
                pair(j, (m[0], Some(m[1])), (p[0], Some(p[1])), &mut acc);
            }
            put_codes(acc.0, mu_out);
            put_codes(acc.1, psi_out);
        }
        // The last D mod 8 dimensions (none at D = 64).
        if let Some((mu_out, psi_out)) = outs.next() {
            let mut acc = (0, 0);
            for (j, (m, p)) in m_rest.chunks(2).zip(p_rest.chunks(2)).enumerate() {
                pair(
                    j as u32,
                    (m[0], m.get(1).copied()),
                    (p[0], p.get(1).copied()),
                    &mut acc,
                );
            }
            put_codes(acc.0, mu_out);
            put_codes(acc.1, psi_out);
        }
    }

    /// Decode to f32.
    pub fn decode(&self) -> ObsStats<D> {
        let mut out = ObsStats::EMPTY;
        self.decode_into(&mut out);
        out
    }

    /// Decode into existing f32 statistics (no 516-byte temporary on the device stack).
    pub fn decode_into(&self, out: &mut ObsStats<D>) {
        out.count = self.count;
        let scale = scale_to_f32(self.mu_scale);
        let (mu_part, psi_part) = self.codes.split_at(section_len(D, MU_BITS));
        unpack_into(mu_part, MU_BITS, &mut out.mean, Section::Mean(scale));
        let base = u32::from(self.psi_base);
        unpack_into(psi_part, PSI_BITS, &mut out.scatter, Section::Scatter(base));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const D: usize = 64;
    const P: usize = packed_len(D);

    #[test]
    fn round_trip_error_is_within_one_step() {
        let mut d = Dither::new(1);
        let mut s = ObsStats::<D> {
            count: 12.5,
            ..ObsStats::EMPTY
        };
        for i in 0..D {
            s.mean[i] = ((i as f32) * 0.37).sin() * 0.8;
            s.scatter[i] = 0.5 + (i as f32) * 0.3;
        }
        let q = QuantVoxel::<D, P>::encode(&s, &mut d);
        let back = q.decode();
        assert_eq!(back.count, s.count);
        let step = q.mu_scale.to_f32();
        for i in 0..D {
            assert!(
                (back.mean[i] - s.mean[i]).abs() <= step * 1.0001,
                "mean {i}"
            );
            // Stochastic rounding lands on one of the two neighbouring codes: within one step (the widest:
            // mantissa 1 → 1 + 2^−PSI_STEPS_LOG2, 25 % at 4 steps per octave).
            let wide = 1.0 + 1.0 / (1u32 << PSI_STEPS_LOG2) as f32;
            let rel = back.scatter[i] / s.scatter[i];
            assert!(rel > 1.0 / wide && rel < wide, "psi {i}: {rel}");
        }
    }

    #[test]
    fn stochastic_rounding_is_unbiased() {
        // A value a third of a step above a code: round-to-nearest would always lose it.
        let mut d = Dither::new(7);
        let mut s = ObsStats::<D> {
            count: 1.0,
            mean: [0.0; D],
            scatter: [1.0; D],
        };
        s.mean[0] = 1.0; // sets the scale: step = 1/q_max
        s.mean[1] = (10.0 + 1.0 / 3.0) / MU_QMAX as f32;
        s.scatter[1] = 1.01; // 1 % above a code of Ψ = 1
        let (mut sum_mu, mut sum_psi) = (0.0f64, 0.0f64);
        let n = 20_000;
        for _ in 0..n {
            let b = QuantVoxel::<D, P>::encode(&s, &mut d).decode();
            sum_mu += b.mean[1] as f64;
            sum_psi += b.scatter[1] as f64;
        }
        assert!((sum_mu / n as f64 - s.mean[1] as f64).abs() < 2e-4);
        assert!(
            (sum_psi / n as f64 - 1.01).abs() < 1e-3,
            "{}",
            sum_psi / n as f64
        );
    }

    /// Many small updates of one voxel (a long residency): the stored μ must track the f32 μ, not drift.
    #[test]
    fn repeated_requantization_does_not_drift() {
        let mut d = Dither::new(5);
        let mut truth = ObsStats::<D> {
            count: 1.0,
            mean: [0.0; D],
            scatter: [1.0; D],
        };
        for i in 0..D {
            truth.mean[i] = ((i as f32) * 0.91).cos() * 0.2;
        }
        let mut code = QuantVoxel::<D, P>::encode(&truth, &mut d);
        let y: [f32; D] = core::array::from_fn(|i| {
            ((i as f32) * 0.91).cos() * 0.2 + ((i * 7) as f32).sin() * 0.05
        });
        for _ in 0..2000 {
            let mut stored = code.decode();
            let point = ObsStats {
                count: 0.05,
                mean: y,
                scatter: [0.0; D],
            };
            stored.merge(&point);
            truth.merge(&point);
            code = code.reencode(&stored, &mut d);
        }
        let back = code.decode();
        let err: f32 = (0..D)
            .map(|i| (back.mean[i] - truth.mean[i]).powi(2))
            .sum::<f32>()
            .sqrt();
        let norm: f32 = truth.mean.iter().map(|v| v * v).sum::<f32>().sqrt();
        assert!(
            err / norm < 0.06,
            "μ drifted: relative error {}",
            err / norm
        );
    }

    /// The finer grid of a weighed map re-grids more often: its stored μ must not drift either.
    #[test]
    fn the_fine_grid_does_not_drift() {
        let mut d = Dither::new(5);
        let mut truth = ObsStats::<D> {
            count: 1.0,
            mean: core::array::from_fn(|i| ((i as f32) * 0.91).cos() * 0.2),
            scatter: [1.0; D],
        };
        let mut code = QuantVoxel::<D, P>::EMPTY.reencode_fine(&truth, &mut d);
        let mut coarse = QuantVoxel::<D, P>::EMPTY.reencode(&truth, &mut d);
        let y: [f32; D] = core::array::from_fn(|i| {
            ((i as f32) * 0.91).cos() * 0.2 + ((i * 7) as f32).sin() * 0.05
        });
        let point = ObsStats {
            count: 0.05,
            mean: y,
            scatter: [0.0; D],
        };
        for _ in 0..2000 {
            let mut stored = code.decode();
            stored.merge(&point);
            code = code.reencode_fine(&stored, &mut d);
            let mut stored = coarse.decode();
            stored.merge(&point);
            coarse = coarse.reencode(&stored, &mut d);
            truth.merge(&point);
        }
        let rel = |q: &QuantVoxel<D, P>| {
            let back = q.decode();
            let err: f32 = (0..D)
                .map(|i| (back.mean[i] - truth.mean[i]).powi(2))
                .sum::<f32>()
                .sqrt();
            err / truth.mean.iter().map(|v| v * v).sum::<f32>().sqrt()
        };
        let (fine, coarse) = (rel(&code), rel(&coarse));
        // Measured: fine 0.0137, coarse 0.0126 (a long residency re-grids more often on the finer grid).
        assert!(
            fine < 0.06 && fine < 1.5 * coarse,
            "fine {fine}, coarse {coarse}"
        );
    }

    /// The codes as they were first written (every code into an array, then packed; decoded through an
    /// array): the fused loops must give the same bytes and values, bit for bit.
    fn reference_reencode(
        prev: &QuantVoxel<D, P>,
        stats: &ObsStats<D>,
        dither: &mut Dither,
    ) -> QuantVoxel<D, P> {
        fn pack(codes: &[u8], width: u32, out: &mut [u8]) {
            let w = width as usize;
            for (chunk, dst) in codes.chunks(8).zip(out.chunks_mut(w)) {
                let mut acc = 0u64;
                for (i, &c) in chunk.iter().enumerate() {
                    acc |= u64::from(c) << (i * w);
                }
                for (b, src) in dst.iter_mut().zip(acc.to_le_bytes()) {
                    *b = src;
                }
            }
        }
        // The scale and base as the fused path picks them (unchanged code): taken from it, the rest redone.
        let mut d0 = dither.clone();
        let fused = prev.reencode(stats, &mut d0);
        let (scale, base) = (fused.mu_scale.to_f32(), i32::from(fused.psi_base));
        let inv = if scale > 0.0 { 1.0 / scale } else { 0.0 };
        const OFFSET: i32 = 2 * MU_QMAX + 2;
        let inv_256 = inv * 256.0;
        let mu_code = |v: f32, d: u32| {
            let fine = (v * inv_256 + ((OFFSET * 256) as f32 + 0.5)) as i32;
            let q = (fine + (d & 0xFF) as i32) / 256 - OFFSET;
            q.clamp(-MU_QMAX - 1, MU_QMAX) as u8 & ((1 << MU_BITS) - 1) as u8
        };
        let psi_code = |v: f32, d: u32| {
            (psi_key(v, d as u8) as i32 - base).clamp(0, PSI_CODE_MAX as i32) as u8
        };
        let (mut mu, mut psi) = ([0u8; D], [0u8; D]);
        for i in (0..D).step_by(2) {
            let d = dither.next();
            mu[i] = mu_code(stats.mean[i], d);
            psi[i] = psi_code(stats.scatter[i], d >> 8);
            mu[i + 1] = mu_code(stats.mean[i + 1], d >> 16);
            psi[i + 1] = psi_code(stats.scatter[i + 1], d >> 24);
        }
        let mut codes = [0u8; P];
        let (a, b) = codes.split_at_mut(section_len(D, MU_BITS));
        pack(&mu, MU_BITS, a);
        pack(&psi, PSI_BITS, b);
        QuantVoxel {
            count: stats.count,
            mu_scale: fused.mu_scale,
            psi_base: fused.psi_base,
            codes,
        }
    }

    fn reference_decode(q: &QuantVoxel<D, P>) -> ObsStats<D> {
        let mut out = ObsStats::<D> {
            count: q.count,
            ..ObsStats::EMPTY
        };
        let (mu_part, psi_part) = q.codes.split_at(section_len(D, MU_BITS));
        let code = |data: &[u8], w: u32, i: usize| {
            let bit = i * w as usize;
            let mut word = 0u32;
            for k in 0..3 {
                word |= u32::from(*data.get(bit / 8 + k).unwrap_or(&0)) << (8 * k);
            }
            (word >> (bit % 8)) & ((1 << w) - 1)
        };
        for i in 0..D {
            let c = code(mu_part, MU_BITS, i) as i32;
            out.mean[i] = ((c << (32 - MU_BITS)) >> (32 - MU_BITS)) as f32 * q.mu_scale.to_f32();
            out.scatter[i] =
                f32::from_bits((code(psi_part, PSI_BITS, i) + u32::from(q.psi_base)) << PSI_SHIFT);
        }
        out
    }

    #[test]
    fn fused_codes_equal_the_array_layout_bit_for_bit() {
        let mut rng = Dither::new(11);
        let mut unit = || (rng.next() >> 8) as f32 / (1 << 24) as f32;
        let mut prev = QuantVoxel::<D, P>::EMPTY;
        let (mut a, mut b) = (Dither::new(3), Dither::new(3));
        for round in 0..500 {
            let spread = [0.01, 1.0, 100.0][round % 3];
            let mut s = ObsStats::<D> {
                count: 1.0 + round as f32,
                ..ObsStats::EMPTY
            };
            for i in 0..D {
                s.mean[i] = (unit() - 0.5) * spread;
                // Zero scatters (one point) in a third of the rounds.
                s.scatter[i] = if round % 3 == 1 { 0.0 } else { unit() * spread };
            }
            let want = reference_reencode(&prev, &s, &mut a);
            let mut got = prev;
            got.reencode_here(&s, &mut b);
            assert_eq!(got, want, "round {round}");
            assert_eq!(got.decode(), reference_decode(&got), "round {round}");
            prev = got;
        }
    }

    /// A voxel of one point skips the scatter pass and the scatter codes: its codes must be the general
    /// path's, bit for bit, on both grids, whatever codes the voxel held before.
    #[test]
    fn one_point_codes_equal_the_general_ones() {
        let mut rng = Dither::new(19);
        let mut unit = || (rng.next() >> 8) as f32 / (1 << 24) as f32;
        let mut prev = QuantVoxel::<D, P>::EMPTY;
        for round in 0..300 {
            let spread = [0.01, 1.0, 100.0][round % 3];
            let s = ObsStats::<D> {
                count: 1.0,
                mean: core::array::from_fn(|_| (unit() - 0.5) * spread),
                scatter: [0.0; D],
            };
            let seed = Dither::new(round as u32 + 1);
            let (mut a, mut b) = (seed.clone(), seed.clone());
            let (mut fa, mut fb) = (seed.clone(), seed);
            let mut got = prev;
            got.reencode_unscattered_here::<false>(&s, &mut b);
            assert_eq!(got, prev.reencode(&s, &mut a), "round {round}");
            let mut fine = prev;
            fine.reencode_unscattered_here::<true>(&s, &mut fb);
            assert_eq!(fine, prev.reencode_fine(&s, &mut fa), "fine, round {round}");
            // The next round starts from codes with a scatter section, as a reused slot would.
            let mut scattered = s;
            scattered.scatter = core::array::from_fn(|i| unit() * (i + 1) as f32);
            prev = got.reencode(&scattered, &mut Dither::new(7));
        }
    }

    /// The scale conversions must be `half`'s, bit for bit: every f16, and f32 values around every f16
    /// (ties, the normal range's ends, subnormals, infinities, NaN).
    #[test]
    fn scale_conversions_are_halfs() {
        for h in 0..=u16::MAX {
            let s = f16::from_bits(h);
            assert_eq!(scale_to_f32(s).to_bits(), s.to_f32().to_bits(), "{h:#06x}");
            let x = s.to_f32();
            if x.is_nan() {
                continue;
            }
            let b = x.to_bits();
            for d in [0u32, 1, 0xFFF, 0x1000, 0x1001, 0x1FFF] {
                for v in [b.wrapping_add(d), b.wrapping_sub(d)] {
                    let v = f32::from_bits(v);
                    assert_eq!(
                        scale_from_f32(v).to_bits(),
                        f16::from_f32(v).to_bits(),
                        "{v:e}"
                    );
                }
            }
        }
        for v in [
            0.0,
            -0.0,
            65504.0,
            65519.0,
            65520.0,
            1e9,
            f32::INFINITY,
            f32::NAN,
            6.1e-5,
            1e-9,
        ] {
            assert_eq!(
                scale_from_f32(v).to_bits(),
                f16::from_f32(v).to_bits(),
                "{v:e}"
            );
        }
    }

    #[test]
    fn empty_and_wide_ranges() {
        let mut d = Dither::new(3);
        let z = QuantVoxel::<D, P>::encode(&ObsStats::EMPTY, &mut d).decode();
        assert!(z.mean.iter().all(|&m| m == 0.0) && z.count == 0.0);
        // Ψ spanning 2^20: the largest values keep their precision, the smallest clamp up, never NaN.
        let mut s = ObsStats::<D> {
            count: 3.0,
            mean: [0.0; D],
            scatter: [1.0; D],
        };
        s.scatter[0] = 1e6;
        let b = QuantVoxel::<D, P>::encode(&s, &mut d).decode();
        assert!((b.scatter[0] / 1e6 - 1.0).abs() < 0.2);
        assert!(b.scatter.iter().all(|p| p.is_finite() && *p >= 1.0));
    }
}
