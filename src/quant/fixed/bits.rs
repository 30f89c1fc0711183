//! Integer stand-ins for the float operations the fixed-point cooling needs: an f32's parts, its bit pattern
//! built from an integer, rounded shifts, leading zeros, 32 × 32 → 64-bit products (from 16-bit halves on
//! v6-M), and one packed code at a time.

/// A positive number as m · 2^e with m in [2²³, 2²⁴) (an f32's mantissa and exponent), or zero (m = 0).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct Parts {
    pub(super) m: u32,
    pub(super) e: i32,
}

impl Parts {
    pub(super) const ZERO: Self = Self { m: 0, e: 0 };

    /// From an f32's bits (zero, subnormal, negative and non-finite values give zero).
    pub(super) fn of_bits(bits: u32) -> Self {
        let biased = (bits >> 23) as i32;
        if bits >> 31 != 0 || biased == 0 || biased == 255 {
            return Self::ZERO;
        }
        Self {
            m: (bits & 0x7F_FFFF) | 0x80_0000,
            e: biased - 150,
        }
    }
}

per_dim_step! {
/// Leading zeros of a u32, one copy (riscv32imac has no instruction for it; its expansion is ≈ 20).
pub(super) fn lz(v: u32) -> u32 {
    #[cfg(target_abi = "eabi")]
    return lz_halving(v);
    #[cfg(not(target_abi = "eabi"))]
    return v.leading_zeros();
}
}

/// Leading zeros by halving the range (five steps): v6-M has no `clz`, and its library call
/// (`__clzsi2`) runs ≈ 34 instructions against ≈ 18 here. Tested against `leading_zeros`.
#[cfg(any(target_abi = "eabi", test))]
#[inline(always)]
pub(super) fn lz_halving(mut v: u32) -> u32 {
    if v == 0 {
        return 32;
    }
    let mut n = 0;
    for step in [16, 8, 4, 2, 1] {
        if v >> (32 - step) == 0 {
            n += step;
            v <<= step;
        }
    }
    n
}

/// `p >> s`, saturated to `u32::MAX`, in 32-bit operations (a variable 64-bit shift is a library call on
/// v6-M: `__aeabi_llsr`).
#[inline(always)]
pub(super) fn shr_sat32(p: u64, s: u32) -> u32 {
    let (hi, lo) = ((p >> 32) as u32, p as u32);
    if s >= 32 {
        hi.checked_shr(s - 32).unwrap_or(0)
    } else if s == 0 {
        if hi != 0 {
            u32::MAX
        } else {
            lo
        }
    } else if hi >> s != 0 {
        u32::MAX
    } else {
        (hi << (32 - s)) | (lo >> s)
    }
}

/// a · b, 32 × 32 → 64 bits. v6-M has no long multiply (`umull`): there a 64-bit product is a call to
/// `__aeabi_lmul` (≈ 50 instructions, a 64 × 64 product); four 16 × 16-bit `muls` and the carries are ≈ 15.
#[inline(always)]
pub(super) fn mul32(a: u32, b: u32) -> u64 {
    #[cfg(target_abi = "eabi")]
    {
        mul32_halves(a, b)
    }
    #[cfg(not(target_abi = "eabi"))]
    {
        u64::from(a) * u64::from(b)
    }
}

/// [`mul32`] from 16-bit halves (what a v6-M runs; tested against the 64-bit product on the host).
#[cfg(any(target_abi = "eabi", test))]
#[inline(always)]
pub(super) fn mul32_halves(a: u32, b: u32) -> u64 {
    let (ah, al, bh, bl) = (a >> 16, a & 0xFFFF, b >> 16, b & 0xFFFF);
    let (mid, carry) = (ah * bl).overflowing_add(al * bh);
    let (lo, carry_lo) = (al * bl).overflowing_add(mid << 16);
    let hi = ah * bh + (mid >> 16) + (u32::from(carry) << 16) + u32::from(carry_lo);
    (u64::from(hi) << 32) | u64::from(lo)
}

/// a · b for a signed `a` (|a| < 2³¹), as [`mul32`].
#[inline(always)]
pub(super) fn mul32s(a: i32, b: u32) -> i64 {
    let p = mul32(a.unsigned_abs(), b) as i64;
    if a < 0 {
        -p
    } else {
        p
    }
}

/// a · b for signed `a` and `b` (|a|, |b| < 2³¹), as [`mul32`].
#[inline(always)]
pub(super) fn mul32ss(a: i32, b: i32) -> i64 {
    let p = mul32(a.unsigned_abs(), b.unsigned_abs()) as i64;
    if (a ^ b) < 0 {
        -p
    } else {
        p
    }
}

/// (2³² − 1)/k (k = 0 read as 1): a reciprocal for dividing by multiplying. v6-M has no divide instruction
/// (`__aeabi_uidiv` runs ≈ 200 instructions), so there the counts below 256 — a cooling's new points n₁,
/// a young voxel's n — are read from a table (1 KB of flash).
#[inline(always)]
pub(super) fn recip(k: u32) -> u32 {
    #[cfg(target_abi = "eabi")]
    if let Some(&r) = RECIPS.get(k as usize) {
        return r;
    }
    u32::MAX / k.max(1)
}

/// (2³² − 1)/k for k < 256 (k = 0 as 1), built at compile time.
#[cfg(any(target_abi = "eabi", test))]
pub(super) const RECIPS: [u32; 256] = {
    let mut t = [u32::MAX; 256];
    let mut k = 2;
    while k < 256 {
        t[k] = u32::MAX / k as u32;
        k += 1;
    }
    t
};

inline_with_fpu! {
/// `p · 2^sh`, rounded to nearest when shifting right, saturating at 2³⁰ when shifting left. (32-bit: a
/// 64-bit shift is long on a 32-bit MCU.)
pub(super) fn shift(p: u32, sh: i32) -> u32 {
    if p == 0 {
        0
    } else if sh >= 0 {
        // Saturated when a bit of p reaches bit 30 (lz(p) < 2 + sh), tested without counting zeros.
        if sh >= 30 || p >> (30 - sh) != 0 {
            1 << 30
        } else {
            p << sh
        }
    } else {
        let r = (-sh) as u32;
        if r >= 32 {
            0
        } else {
            (p >> (r - 1)).div_ceil(2)
        }
    }
}
}

inline_with_fpu! {
/// The f32 bit pattern of `v · 2^e` (v > 0), mantissa truncated; 0 if it underflows, f32::MAX if too big.
pub(super) fn f32_bits(v: u32, e: i32) -> u32 {
    if v == 0 {
        return 0;
    }
    let z = lz(v) as i32;
    // v = mant · 2^(8 − z) with mant in [2²³, 2²⁴).
    let mant = (v << z) >> 8;
    let biased = e + (8 - z) + 150;
    if biased <= 0 {
        0
    } else if biased >= 255 {
        f32::MAX.to_bits()
    } else {
        ((biased as u32) << 23) | (mant & 0x7F_FFFF)
    }
}
}

/// The top 16 bits of `v` > 0 and the power of two they stand for: v ≈ t · 2^e with t in [2¹⁵, 2¹⁶).
#[inline]
pub(super) fn top16(v: u32) -> (u32, i32) {
    let z = lz(v) as i32;
    ((v << z) >> 16, 16 - z)
}

/// Code `i` of a section packed by [`super::super::pack`] (`width` ≤ 8 bits), read on its own: the loops here stay
/// rolled (small code) instead of unpacking 8 codes at a time (v6-M with the sparse path linked unpacks:
/// `unpack_codes`).
#[cfg(not(all(feature = "sparse-cooling", target_abi = "eabi")))]
#[inline(always)]
pub(super) fn code_at(data: &[u8], width: u32, i: usize) -> u32 {
    let bit = i * width as usize;
    let lo = u32::from(data.get(bit / 8).copied().unwrap_or(0));
    let hi = u32::from(data.get(bit / 8 + 1).copied().unwrap_or(0));
    ((lo | hi << 8) >> (bit % 8)) & ((1 << width) - 1)
}

/// Write code `i` into a zeroed section in [`super::super::pack`]'s layout (the build without the sparse
/// path: `pack_codes` is its faster, larger replacement).
#[cfg(not(feature = "sparse-cooling"))]
#[inline(always)]
pub(super) fn set_code(data: &mut [u8], width: u32, i: usize, code: u8) {
    let bit = i * width as usize;
    let v = u32::from(code) << (bit % 8);
    if let Some(b) = data.get_mut(bit / 8) {
        *b |= v as u8;
    }
    if let Some(b) = data.get_mut(bit / 8 + 1) {
        *b |= (v >> 8) as u8;
    }
}

/// An f32 that holds a whole number (a voxel's point count) as an integer, without a float operation.
#[inline]
pub(super) fn count_of(bits: u32) -> u32 {
    let p = Parts::of_bits(bits);
    shift(p.m, p.e)
}

#[cfg(feature = "sparse-cooling")]
/// Bits of `v` (0 for 0): the position above its highest set bit.
#[inline(always)]
pub(super) fn bit_len(v: u32) -> u32 {
    32 - lz(v)
}

#[cfg(feature = "sparse-cooling")]
/// `x · w / 2¹⁶` for a 16-bit `w`, floored, in 32-bit products (no 64-bit one on v6-M).
#[inline(always)]
pub(super) fn mul_q16(x: u32, w: u32) -> u32 {
    (x >> 16)
        .wrapping_mul(w)
        .wrapping_add((x & 0xFFFF).wrapping_mul(w) >> 16)
}

#[cfg(feature = "sparse-cooling")]
/// min(v · 2^s, 2³⁰) (truncated when shifting right) by a shift fixed for a loop, its direction decided
/// once: `v >> r`, then `<< l` capped (one of them 0; no branch on the sign per value). The cap: two such
/// values and one below 2³⁰ add without overflow (the sparse merge's S, whose table stays below 2³⁰, so
/// a capped S leaves it as a saturated one did). The same as `shl_sat` capped for s ≤ 31.
#[derive(Clone, Copy)]
pub(super) struct Shift {
    l: u32,
    r: u32,
    lim: u32,
}

#[cfg(feature = "sparse-cooling")]
impl Shift {
    pub(super) fn new(s: i32) -> Self {
        let l = s.clamp(0, 31) as u32;
        Self {
            l,
            r: s.min(0).unsigned_abs().min(31),
            lim: (1 << 30) >> l,
        }
    }

    #[inline(always)]
    pub(super) fn apply(self, v: u32) -> u32 {
        let v = v >> self.r;
        if v > self.lim {
            1 << 30
        } else {
            v << self.l
        }
    }
}

#[cfg(all(feature = "sparse-cooling", test))]
/// `v · 2^s`: saturated to `u32::MAX` when shifting left, truncated when shifting right, the sign decided
/// per value (what [`Shift`] replaced; its tests' reference).
pub(super) fn shl_sat(v: u32, s: i32) -> u32 {
    if s >= 0 {
        let s = s as u32;
        if s > 31 || v > u32::MAX >> s {
            u32::MAX
        } else {
            v << s
        }
    } else {
        v >> (s.unsigned_abs()).min(31)
    }
}

#[cfg(feature = "sparse-cooling")]
/// Packed codes read one after another ([`super::super::pack`]'s layout is one little-endian bit stream per
/// section): one byte load per 8 bits, no per-code address arithmetic.
pub(super) struct CodeReader<'a> {
    data: core::slice::Iter<'a, u8>,
    acc: u32,
    bits: u32,
}

#[cfg(feature = "sparse-cooling")]
impl<'a> CodeReader<'a> {
    pub(super) fn new(data: &'a [u8]) -> Self {
        Self {
            data: data.iter(),
            acc: 0,
            bits: 0,
        }
    }

    /// The next `width`-bit code (`width` ≤ 8; 0 past the end).
    #[inline(always)]
    pub(super) fn next(&mut self, width: u32) -> u32 {
        if self.bits < width {
            self.acc |= u32::from(self.data.next().copied().unwrap_or(0)) << self.bits;
            self.bits += 8;
        }
        let c = self.acc & ((1 << width) - 1);
        self.acc >>= width;
        self.bits -= width;
        c
    }
}

#[cfg(feature = "sparse-cooling")]
/// Codes written one after another into a section, [`CodeReader`]'s inverse.
pub(super) struct CodeWriter<'a> {
    data: core::slice::IterMut<'a, u8>,
    acc: u32,
    bits: u32,
}

#[cfg(feature = "sparse-cooling")]
impl<'a> CodeWriter<'a> {
    pub(super) fn new(data: &'a mut [u8]) -> Self {
        Self {
            data: data.iter_mut(),
            acc: 0,
            bits: 0,
        }
    }

    /// Append a `width`-bit code (`width` ≤ 8, `code` < 2^width).
    #[inline(always)]
    pub(super) fn put(&mut self, width: u32, code: u32) {
        self.acc |= code << self.bits;
        self.bits += width;
        if self.bits >= 8 {
            if let Some(b) = self.data.next() {
                *b = self.acc as u8;
            }
            self.acc >>= 8;
            self.bits -= 8;
        }
    }

    /// Write the last partial byte.
    pub(super) fn finish(mut self) {
        if self.bits > 0 {
            if let Some(b) = self.data.next() {
                *b = self.acc as u8;
            }
        }
    }
}

#[cfg(feature = "sparse-cooling")]
/// A section of `W`-bit codes ([`super::super::pack`]'s layout) unpacked into one byte a code: eight codes
/// (`W` bytes) at a time in straight-line code, constant shifts only (a code at a time through
/// [`CodeReader`] costs an M0 ≈ 23 instructions for a 7-bit code, here ≈ 5); a last partial group through
/// the reader.
pub(super) fn unpack_codes<const W: usize>(data: &[u8], out: &mut [u8]) {
    let rest = data.get(out.len() / 8 * W..).unwrap_or(&[]);
    let mut src = data.chunks_exact(W);
    let mut dst = out.chunks_exact_mut(8);
    for (d, s) in (&mut dst).zip(&mut src) {
        if let (Ok(s), Ok(d)) = (<&[u8; W]>::try_from(s), <&mut [u8; 8]>::try_from(d)) {
            let mut acc = 0u64;
            for (i, &b) in s.iter().enumerate() {
                acc |= u64::from(b) << (8 * i);
            }
            for (j, c) in d.iter_mut().enumerate() {
                *c = (acc >> (j * W)) as u8 & ((1u16 << W) - 1) as u8;
            }
        }
    }
    let mut r = CodeReader::new(rest);
    for c in dst.into_remainder() {
        *c = r.next(W as u32) as u8;
    }
}

#[cfg(feature = "sparse-cooling")]
/// [`unpack_codes`]'s inverse: one byte a code (each below 2^W) packed into a section, eight at a time.
pub(super) fn pack_codes<const W: usize>(codes: &[u8], out: &mut [u8]) {
    let mut src = codes.chunks_exact(8);
    let mut dst = out.chunks_exact_mut(W);
    for (s, d) in (&mut src).zip(&mut dst) {
        if let (Ok(s), Ok(d)) = (<&[u8; 8]>::try_from(s), <&mut [u8; W]>::try_from(d)) {
            let mut acc = 0u64;
            for (j, &c) in s.iter().enumerate() {
                acc |= u64::from(c) << (j * W);
            }
            for (i, b) in d.iter_mut().enumerate() {
                *b = (acc >> (8 * i)) as u8;
            }
        }
    }
    let mut w = CodeWriter::new(out.get_mut(codes.len() / 8 * W..).unwrap_or(&mut []));
    for &c in src.remainder() {
        w.put(W as u32, u32::from(c));
    }
    w.finish();
}
