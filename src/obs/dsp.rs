//! Int8 code sums on a Cortex-M4/M7 (Armv7E-M): Σc in 16-bit lanes and Σc² per dimension, updated by the
//! DSP instructions four codes at a time, with the −128 check riding on the same code word.
//!
//! Why: on the M4F the int8 point's sums cost ≈ 6.1 instructions per dimension in safe code (≈ 388 of 848
//! per point, plus ≈ 88 for the code check: byte loads, one add and one multiply-add per dimension, each sum
//! loaded and stored). Per word of four codes the DSP instructions do it in 13: `qsub8` + `orr` (the check:
//! c − (−127), saturated, is negative only for −128), `sxtb16` ×2 (the codes as two pairs of 16-bit lanes),
//! `sadd16` ×2 (Σc of four dimensions, two per word: |Σc| ≤ 255·127 fits 16 bits),
//! `smlabb`/`smlatt` ×4 (Σc²), and one `ldm` and one `stm` of the block's six words. A hot voxel's first
//! point is written over the stale sums (`set`: `sxtb16` ×2, `smulbb`/`smultt` ×4, one `stm`), so a
//! reused entry is never cleared.
//!
//! Why `unsafe`: stable Rust reaches these instructions only through `asm!` (`core::arch::arm`'s DSP
//! intrinsics are unstable), and the block's six words are loaded and stored by the same `asm!` (`ldm`/`stm`:
//! LLVM pairs separate loads at best into `ldrd`, which doubles the memory instructions). This module is the
//! core's only `unsafe` code. Each block's layout, and what the instructions compute, is the portable model
//! below ([`Lanes::add`] off the M4; [`Lanes::undo`] everywhere), which the host tests check against the
//! sums' definition; the firmware's end-to-end test compares the M4F's stream with its host twin's.
//!
//! Layout (private to [`super::CodeSums`]): per block of four dimensions, six words — Σc of dimensions 0
//! and 2 (low and high lane), Σc of 1 and 3, then Σc² of 0, 1, 2, 3 — and, for the `D mod 4` last
//! dimensions, Σc (16 bits) and Σc² (32) each: `D` × 6 bytes (the plain arrays take 8), word-aligned.

/// The sums of one hot voxel's codes (see the module's layout), as `u16` triples so that the size follows
/// `D` (`[u32; 3 * D / 2]` is not a type for a generic `D`); word-aligned for `ldm`/`stm`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(C, align(4))]
pub(super) struct Lanes<const D: usize>([[u16; 3]; D]);

/// −127 in every byte: `qsub8` of a code word and this is negative in a byte exactly where the code is −128.
const MINUS_127: u32 = 0x8181_8181;

impl<const D: usize> Lanes<D> {
    pub(super) const EMPTY: Self = Self([[0; 3]; D]);

    /// Add one point's codes (always, −128 included); returns whether every code is in range, so that a
    /// caller can [`Self::undo`] the point. Inlined, with its blocks unrolled: the per-point path.
    #[inline(always)]
    pub(super) fn add(&mut self, codes: &[i8; D]) -> bool {
        let (blocks, tail) = self.0.as_chunks_mut::<4>();
        let (words, tail_codes) = codes.as_chunks::<4>();
        let bad = add_blocks(blocks, words);
        let tail_ok = step_tail(tail, tail_codes, true);
        bad & 0x8080_8080 == 0 && tail_ok
    }

    /// [`Self::add`] as one function with its loop rolled, for the paths that are not per point (flash: the
    /// unrolled blocks take ≈ 0.8 KB).
    #[inline(never)]
    pub(super) fn add_outlined(&mut self, codes: &[i8; D]) -> bool {
        let (blocks, tail) = self.0.as_chunks_mut::<4>();
        let (words, tail_codes) = codes.as_chunks::<4>();
        let bad = add_blocks(blocks, core::hint::black_box(words));
        let tail_ok = step_tail(tail, tail_codes, true);
        bad & 0x8080_8080 == 0 && tail_ok
    }

    /// Take one point's codes out again (what [`Self::add`] added): integer sums wrap back exactly. Runs
    /// only for a refused point.
    #[inline(never)]
    pub(super) fn undo(&mut self, codes: &[i8; D]) {
        let (blocks, tail) = self.0.as_chunks_mut::<4>();
        let (words, tail_codes) = codes.as_chunks::<4>();
        sub_blocks(blocks, core::hint::black_box(words));
        step_tail(tail, tail_codes, false);
    }

    /// One point's codes as the sums of a set of one (what [`Self::add`] gives [`Self::EMPTY`]), written
    /// over whatever the lanes held: no clearing first, no reading. A hot voxel's first point: inlined.
    #[inline(always)]
    pub(super) fn set(&mut self, codes: &[i8; D]) {
        let (blocks, tail) = self.0.as_chunks_mut::<4>();
        let (words, tail_codes) = codes.as_chunks::<4>();
        set_blocks(blocks, words);
        for (t, &c) in tail.iter_mut().zip(tail_codes) {
            let q = square(i32::from(c));
            *t = [c as i16 as u16, q as u16, (q >> 16) as u16];
        }
    }

    /// Σc of dimension `i` (0 beyond `D`).
    #[inline]
    pub(super) fn sum(&self, i: usize) -> i32 {
        self.dim(i).0
    }

    /// Σc² of dimension `i` (0 beyond `D`).
    #[inline]
    pub(super) fn square(&self, i: usize) -> u32 {
        self.dim(i).1
    }

    #[inline]
    fn dim(&self, i: usize) -> (i32, u32) {
        let (blocks, tail) = self.0.as_chunks::<4>();
        match blocks.get(i / 4) {
            Some(b) => block_dims(b)[i % 4],
            None => tail
                .get(i - 4 * blocks.len())
                .map_or((0, 0), |&[s, lo, hi]| (i32::from(s as i16), word(lo, hi))),
        }
    }

    /// `f(i, Σc, Σc²)` for every dimension i, in order (a block's four dimensions from its six words).
    #[inline(always)]
    pub(super) fn for_each_dim(&self, mut f: impl FnMut(usize, i32, u32)) {
        let (blocks, tail) = self.0.as_chunks::<4>();
        for (k, b) in blocks.iter().enumerate() {
            for (r, (s, q)) in block_dims(b).into_iter().enumerate() {
                f(4 * k + r, s, q);
            }
        }
        for (j, &[s, lo, hi]) in tail.iter().enumerate() {
            f(4 * blocks.len() + j, i32::from(s as i16), word(lo, hi));
        }
    }

    /// (Σc, Σc²) of every dimension, in order.
    #[inline]
    pub(super) fn dims(&self) -> impl Iterator<Item = (i32, u32)> + '_ {
        let (blocks, tail) = self.0.as_chunks::<4>();
        blocks.iter().flat_map(block_dims).chain(
            tail.iter()
                .map(|&[s, lo, hi]| (i32::from(s as i16), word(lo, hi))),
        )
    }
}

/// Add (or, with `add` false, take out) the codes of the `D mod 4` last dimensions, each kept as Σc (16
/// bits) and Σc² (two halves of a word); returns whether none of them is −128. Empty at D = 64.
#[inline(always)]
fn step_tail(tail: &mut [[u16; 3]], codes: &[i8], add: bool) -> bool {
    let mut ok = true;
    for (t, &c) in tail.iter_mut().zip(codes) {
        ok &= c != i8::MIN;
        let [s, lo, hi] = t;
        let (dc, dq) = (c as i16 as u16, square(i32::from(c)));
        let q = word(*lo, *hi);
        let (s2, q2) = if add {
            (s.wrapping_add(dc), q.wrapping_add(dq))
        } else {
            (s.wrapping_sub(dc), q.wrapping_sub(dq))
        };
        *s = s2;
        (*lo, *hi) = (q2 as u16, (q2 >> 16) as u16);
    }
    ok
}

/// The six words of a block (the module's layout), as the DSP instructions see them in memory.
#[inline(always)]
fn block_words(b: &[[u16; 3]; 4]) -> [u32; 6] {
    let [[a0, a1, a2], [b0, b1, b2], [c0, c1, c2], [d0, d1, d2]] = *b;
    [
        word(a0, a1),
        word(a2, b0),
        word(b1, b2),
        word(c0, c1),
        word(c2, d0),
        word(d1, d2),
    ]
}

#[inline(always)]
#[cfg(not(latentbki_dsp))]
fn set_block_words(b: &mut [[u16; 3]; 4], w: [u32; 6]) {
    let h = |v: u32| (v as u16, (v >> 16) as u16);
    let [(a0, a1), (a2, b0), (b1, b2), (c0, c1), (c2, d0), (d1, d2)] = w.map(h);
    *b = [[a0, a1, a2], [b0, b1, b2], [c0, c1, c2], [d0, d1, d2]];
}

/// (Σc, Σc²) of a block's four dimensions.
#[inline(always)]
fn block_dims(b: &[[u16; 3]; 4]) -> [(i32, u32); 4] {
    let [s02, s13, q0, q1, q2, q3] = block_words(b);
    [
        (lane(s02, 0), q0),
        (lane(s13, 0), q1),
        (lane(s02, 1), q2),
        (lane(s13, 1), q3),
    ]
}

#[inline(always)]
fn word(lo: u16, hi: u16) -> u32 {
    u32::from(lo) | u32::from(hi) << 16
}

/// Signed 16-bit lane `k` (0 low, 1 high) of `v`.
#[inline(always)]
fn lane(v: u32, k: u32) -> i32 {
    i32::from((v >> (16 * k)) as u16 as i16)
}

#[inline(always)]
fn square(c: i32) -> u32 {
    c.wrapping_mul(c) as u32
}

/// `sxtb16`: bytes 0 and 2 of `v`, sign-extended into the low and high 16-bit lanes.
#[cfg(not(latentbki_dsp))]
fn sxtb16(v: u32) -> u32 {
    u32::from(v as u8 as i8 as i16 as u16) | u32::from((v >> 16) as u8 as i8 as i16 as u16) << 16
}

/// `ssub16`: lane-wise wrapping subtraction.
#[cfg(not(latentbki_dsp))]
fn ssub16(a: u32, b: u32) -> u32 {
    u32::from((a as u16).wrapping_sub(b as u16))
        | u32::from(((a >> 16) as u16).wrapping_sub((b >> 16) as u16)) << 16
}

/// Σc and Σc² of every whole block of four codes; returns the bytes' −128 flags (`qsub8` results ORed).
/// Four blocks a loop iteration: rolled, the loop's counting cost 4 instructions a block.
#[cfg(latentbki_dsp)]
#[inline(always)]
fn add_blocks(blocks: &mut [[[u16; 3]; 4]], words: &[[i8; 4]]) -> u32 {
    // At most one code word per block (both are `D / 4` long): `p` never passes the end of `blocks`.
    let words = words.get(..blocks.len()).unwrap_or(words);
    let mut p: *mut u32 = blocks.as_mut_ptr().cast();
    let mut bad = 0u32;
    let (fours, rest) = words.as_chunks::<4>();
    for four in fours {
        for w in four {
            add_block(&mut p, w, &mut bad);
        }
    }
    for w in rest {
        add_block(&mut p, w, &mut bad);
    }
    bad
}

/// Each whole block's six words as one point's sums (its code word's lanes and squares), written over
/// what they held: `sxtb16` ×2, `smulbb`/`smultt` ×4 and one `stm` a block (the same fields in safe
/// Rust took 22 instructions a block: halfword stores, byte loads).
#[cfg(latentbki_dsp)]
#[inline(always)]
fn set_blocks(blocks: &mut [[[u16; 3]; 4]], words: &[[i8; 4]]) {
    // At most one code word per block (both are `D / 4` long): `p` never passes the end of `blocks`.
    let words = words.get(..blocks.len()).unwrap_or(words);
    let mut p: *mut u32 = blocks.as_mut_ptr().cast();
    for w in words {
        let w = u32::from_le_bytes(w.map(|c| c as u8));
        // SAFETY: as `add_block`'s: `p` points into the `&mut` blocks, word-aligned, at this word's
        // block (never more words than blocks), so `stm` writes exactly its six words and leaves `p` one
        // block further; nothing is read; no stack; r0–r5 declared clobbered; no flags are set.
        unsafe {
            core::arch::asm!(
                "sxtb16 r0, {w}",
                "sxtb16 r1, {w}, ror #8",
                "smulbb r2, r0, r0",
                "smulbb r3, r1, r1",
                "smultt r4, r0, r0",
                "smultt r5, r1, r1",
                "stm {p}!, {{r0, r1, r2, r3, r4, r5}}",
                p = inout(reg) p,
                w = in(reg) w,
                out("r0") _,
                out("r1") _,
                out("r2") _,
                out("r3") _,
                out("r4") _,
                out("r5") _,
                options(nostack, preserves_flags),
            );
        }
    }
}

/// The portable model of [`set_blocks`] (the layout above, in plain stores).
#[cfg(not(latentbki_dsp))]
#[inline(always)]
fn set_blocks(blocks: &mut [[[u16; 3]; 4]], words: &[[i8; 4]]) {
    let lane = |c: i8| c as i16 as u16;
    let sq = |c: i8| square(i32::from(c));
    for (b, &[c0, c1, c2, c3]) in blocks.iter_mut().zip(words) {
        let s02 = word(lane(c0), lane(c2));
        let s13 = word(lane(c1), lane(c3));
        set_block_words(b, [s02, s13, sq(c0), sq(c1), sq(c2), sq(c3)]);
    }
}

/// One block: its code word's check flags into `bad`, its six words updated, `p` advanced past it.
#[cfg(latentbki_dsp)]
#[inline(always)]
fn add_block(p: &mut *mut u32, w: &[i8; 4], bad: &mut u32) {
    let w = u32::from_le_bytes(w.map(|c| c as u8));
    // SAFETY: `*p` points into the `&mut` blocks of [`add_blocks`] (word-aligned: `Lanes` is `align(4)`
    // and a block is six words), at the block of this code word — one block per word, never more words
    // than blocks — so `ldm` reads and `stm` writes exactly that block's six words, which nothing else
    // references meanwhile, and leaves `*p` one block further. No other memory is touched (`w` arrives in
    // a register), no stack is used, r0–r5 are declared clobbered; `sadd16` sets the APSR's GE bits, so
    // the flags are not declared preserved.
    unsafe {
        core::arch::asm!(
            "qsub8 {t}, {w}, {m}",
            "orr {bad}, {bad}, {t}",
            "sxtb16 {t}, {w}",
            "sxtb16 {w}, {w}, ror #8",
            "ldm {p}, {{r0, r1, r2, r3, r4, r5}}",
            "sadd16 r0, r0, {t}",
            "sadd16 r1, r1, {w}",
            "smlabb r2, {t}, {t}, r2",
            "smlabb r3, {w}, {w}, r3",
            "smlatt r4, {t}, {t}, r4",
            "smlatt r5, {w}, {w}, r5",
            "stm {p}!, {{r0, r1, r2, r3, r4, r5}}",
            p = inout(reg) *p,
            w = inout(reg) w => _,
            t = out(reg) _,
            bad = inout(reg) *bad,
            m = in(reg) MINUS_127,
            out("r0") _,
            out("r1") _,
            out("r2") _,
            out("r3") _,
            out("r4") _,
            out("r5") _,
            options(nostack),
        );
    }
}

/// Take every whole block's codes out again: [`add_blocks`]' inverse (`ssub16`, and each square
/// subtracted: `smulbb`/`smultt`, `sub`).
#[cfg(latentbki_dsp)]
#[inline(always)]
fn sub_blocks(blocks: &mut [[[u16; 3]; 4]], words: &[[i8; 4]]) {
    let words = words.get(..blocks.len()).unwrap_or(words);
    let mut p: *mut u32 = blocks.as_mut_ptr().cast();
    for w in words {
        let w = u32::from_le_bytes(w.map(|c| c as u8));
        // SAFETY: as in `add_block`: `p` walks the `&mut` blocks one per code word, never more words than
        // blocks, `ldm`/`stm` touch exactly the current block's six words; registers only otherwise.
        unsafe {
            core::arch::asm!(
                "sxtb16 {t}, {w}",
                "sxtb16 {w}, {w}, ror #8",
                "ldm {p}, {{r0, r1, r2, r3, r4, r5}}",
                "ssub16 r0, r0, {t}",
                "ssub16 r1, r1, {w}",
                "smulbb {x}, {t}, {t}",
                "sub r2, r2, {x}",
                "smulbb {x}, {w}, {w}",
                "sub r3, r3, {x}",
                "smultt {x}, {t}, {t}",
                "sub r4, r4, {x}",
                "smultt {x}, {w}, {w}",
                "sub r5, r5, {x}",
                "stm {p}!, {{r0, r1, r2, r3, r4, r5}}",
                p = inout(reg) p,
                w = inout(reg) w => _,
                t = out(reg) _,
                x = out(reg) _,
                out("r0") _,
                out("r1") _,
                out("r2") _,
                out("r3") _,
                out("r4") _,
                out("r5") _,
                options(nostack),
            );
        }
    }
}

/// The portable model of [`sub_blocks`]' `asm!` block (host tests).
#[cfg(not(latentbki_dsp))]
fn sub_blocks(blocks: &mut [[[u16; 3]; 4]], words: &[[i8; 4]]) {
    for (b, w) in blocks.iter_mut().zip(words) {
        let v = u32::from_le_bytes(w.map(|c| c as u8));
        let (t, w) = (sxtb16(v), sxtb16(v.rotate_right(8)));
        let [r0, r1, r2, r3, r4, r5] = block_words(b);
        set_block_words(
            b,
            [
                ssub16(r0, t),
                ssub16(r1, w),
                r2.wrapping_sub(square(lane(t, 0))),
                r3.wrapping_sub(square(lane(w, 0))),
                r4.wrapping_sub(square(lane(t, 1))),
                r5.wrapping_sub(square(lane(w, 1))),
            ],
        );
    }
}

/// The portable model of the `asm!` block above, instruction by instruction (host tests).
#[cfg(not(latentbki_dsp))]
fn add_blocks(blocks: &mut [[[u16; 3]; 4]], words: &[[i8; 4]]) -> u32 {
    let mut bad = 0u32;
    for (b, w) in blocks.iter_mut().zip(words) {
        let w = u32::from_le_bytes(w.map(|c| c as u8));
        bad |= qsub8(w, MINUS_127);
        let (t, w) = (sxtb16(w), sxtb16(w.rotate_right(8)));
        let [r0, r1, r2, r3, r4, r5] = block_words(b);
        set_block_words(
            b,
            [
                sadd16(r0, t),
                sadd16(r1, w),
                smla(t, 0, r2),
                smla(w, 0, r3),
                smla(t, 1, r4),
                smla(w, 1, r5),
            ],
        );
    }
    bad
}

/// `qsub8`: byte-wise signed saturating subtraction.
#[cfg(not(latentbki_dsp))]
fn qsub8(a: u32, b: u32) -> u32 {
    let bytes = |v: u32| v.to_le_bytes().map(|x| x as i8);
    let (a, b) = (bytes(a), bytes(b));
    u32::from_le_bytes(core::array::from_fn(|k| a[k].saturating_sub(b[k]) as u8))
}

/// `sadd16`: lane-wise wrapping addition.
#[cfg(not(latentbki_dsp))]
fn sadd16(a: u32, b: u32) -> u32 {
    u32::from((a as u16).wrapping_add(b as u16))
        | u32::from(((a >> 16) as u16).wrapping_add((b >> 16) as u16)) << 16
}

/// `smlabb` (k = 0) and `smlatt` (k = 1) of a value with itself: acc + lane² (wrapping).
#[cfg(not(latentbki_dsp))]
fn smla(v: u32, k: u32, acc: u32) -> u32 {
    acc.wrapping_add(square(lane(v, k)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_check_flags_exactly_minus_128() {
        for pos in 0..4 {
            for v in i8::MIN..=i8::MAX {
                let mut w = [127u8; 4];
                w[pos] = v as u8;
                let flags = qsub8(u32::from_le_bytes(w), MINUS_127) & 0x8080_8080;
                assert_eq!(flags != 0, v == i8::MIN, "code {v} at {pos}");
            }
        }
    }

    /// Lanes against the sums' definition, and `undo` back to the previous state, for a size with whole
    /// blocks only and one with a tail.
    fn lanes_equal_the_definition<const D: usize>() {
        let mut state = 0x1234_5678u32;
        let mut lanes = Lanes::<D>::EMPTY;
        let mut want = ([0i64; D], [0i64; D]);
        for p in 0..255 {
            let codes: [i8; D] = core::array::from_fn(|_| {
                state ^= state << 13;
                state ^= state >> 17;
                state ^= state << 5;
                let c = (state >> 24) as u8 as i8;
                if p % 7 == 0 {
                    c
                } else {
                    c.max(-127)
                }
            });
            let before = lanes;
            let ok = if p % 2 == 0 {
                lanes.add(&codes)
            } else {
                lanes.add_outlined(&codes)
            };
            assert_eq!(ok, !codes.contains(&i8::MIN));
            if !ok {
                lanes.undo(&codes);
                assert_eq!(lanes, before, "undo after point {p}");
                continue;
            }
            for (i, &c) in codes.iter().enumerate() {
                want.0[i] += i64::from(c);
                want.1[i] += i64::from(c) * i64::from(c);
            }
            for i in 0..D {
                assert_eq!(i64::from(lanes.sum(i)), want.0[i], "Σc, dimension {i}");
                assert_eq!(i64::from(lanes.square(i)), want.1[i], "Σc², dimension {i}");
            }
            let mut dims = lanes.dims();
            for i in 0..D {
                let (s, q) = dims.next().unwrap();
                assert_eq!(
                    (i64::from(s), i64::from(q)),
                    (want.0[i], want.1[i]),
                    "dims() at {i}"
                );
            }
            assert_eq!(dims.next(), None);
            let mut i = 0;
            lanes.for_each_dim(|j, s, q| {
                assert_eq!((j, i64::from(s), i64::from(q)), (i, want.0[i], want.1[i]));
                i += 1;
            });
            assert_eq!(i, D);
        }
        assert_eq!((lanes.sum(D), lanes.square(D)), (0, 0));
    }

    #[test]
    fn lanes_hold_the_sums() {
        lanes_equal_the_definition::<64>();
        lanes_equal_the_definition::<6>();
    }

    /// `set` writes what `add` makes of empty lanes, over any old contents, for whole blocks and a tail,
    /// −128 included.
    fn set_is_add_to_empty<const D: usize>() {
        let mut state = 0x9E37_79B9u32;
        let mut stale = Lanes::<D>::EMPTY;
        for _ in 0..300 {
            let codes: [i8; D] = core::array::from_fn(|_| {
                state ^= state << 13;
                state ^= state >> 17;
                state ^= state << 5;
                (state >> 24) as u8 as i8
            });
            let mut want = Lanes::<D>::EMPTY;
            want.add(&codes);
            stale.set(&codes);
            assert_eq!(stale, want);
            stale.add(&codes); // stale contents for the next round
        }
    }

    #[test]
    fn set_writes_one_point() {
        set_is_add_to_empty::<64>();
        set_is_add_to_empty::<7>();
    }

    /// A block's words in memory: Σc of dimensions 0 and 2 in the first word's lanes, 1 and 3 in the
    /// second's, then Σc² in order (what `ldm` hands the `asm!` block).
    #[test]
    fn block_layout() {
        let mut lanes = Lanes::<4>::EMPTY;
        assert!(lanes.add(&[1, -2, 3, -4]));
        let words = block_words(&lanes.0);
        assert_eq!(
            words,
            [
                1 | (3 << 16),
                (-2i16 as u16 as u32) | ((-4i16 as u16 as u32) << 16),
                1,
                4,
                9,
                16
            ]
        );
    }
}
