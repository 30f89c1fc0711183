//! The check an int8 feature passes before it reaches a voxel: every code within
//! ±[`CODE_MAX`](super::CODE_MAX) (−128 is refused, so the code range is symmetric). Why its own module: it
//! runs on every int8 point, and how fast it is depends on how the codes can be loaded — four at a time as
//! a word, which on v6-M (no unaligned loads) needs codes on a 4-byte boundary and a checked cast to see
//! them so.

/// Whether every code is within ±[`CODE_MAX`](super::CODE_MAX) (−128 is not), four codes at a time (as
/// words; see the module's tests for the word path).
///
/// On v6-M codes on a 4-byte boundary — a firmware's code buffers — are read as words through `bytemuck`'s
/// checked cast; otherwise each word is built from four byte loads, shifts and additions (≈ 15 instructions
/// a word instead of ≈ 6: thumbv6m 2,108 → 1,951 instructions per point). Targets with unaligned loads (or,
/// as on riscv32imac, a buffer the compiler sees aligned) load words either way; on the M4F the checked
/// cast cost 8 instructions per point, so only v6-M takes it.
#[inline]
pub fn code_in_range<const D: usize>(codes: &[i8; D]) -> bool {
    #[cfg(target_abi = "eabi")]
    if let Some(ok) = aligned_in_range(codes) {
        return ok;
    }
    let chunks = codes.chunks_exact(4);
    let tail_ok = chunks.remainder().iter().all(|&c| c != i8::MIN);
    let words =
        chunks.map(|c| u32::from_le_bytes([c[0] as u8, c[1] as u8, c[2] as u8, c[3] as u8]));
    words_in_range(words) && tail_ok
}

/// [`code_in_range`] of codes that lie on a 4-byte boundary and fill whole words, read as words; `None`
/// for any other slice.
#[cfg(any(target_abi = "eabi", test))]
#[inline(always)]
fn aligned_in_range(codes: &[i8]) -> Option<bool> {
    let words = bytemuck::try_cast_slice::<i8, u32>(codes).ok()?;
    Some(words_in_range(words.iter().copied()))
}

/// Whether no byte of these words is 0x80 (a code of −128). A byte is 0x80 exactly when its top bit is
/// set and its low seven are zero; (b & 0x7F) + 0x7F sets the top bit exactly when they are not (at most
/// 0xFE: no carry into the next byte). Four operations a word, the mask once; byte order does not matter.
#[inline(always)]
fn words_in_range(words: impl Iterator<Item = u32>) -> bool {
    let bad = words.fold(0, |bad, w| bad | (w & !((w & 0x7F7F_7F7F) + 0x7F7F_7F7F)));
    bad & 0x8080_8080 == 0
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A code buffer on a 4-byte boundary, as a firmware's are.
    #[repr(C, align(4))]
    struct Aligned([i8; 16]);

    /// The word path v6-M takes: every code value at every position of an aligned buffer, as
    /// [`code_in_range`] on the host reads it; misaligned or partial slices are left to the byte path.
    #[test]
    fn aligned_words_refuse_exactly_minus_128() {
        for pos in 0..16 {
            for v in i8::MIN..=i8::MAX {
                let mut a = Aligned([127; 16]);
                a.0[pos] = v;
                assert_eq!(
                    aligned_in_range(&a.0),
                    Some(v != i8::MIN),
                    "code {v} at {pos}"
                );
                assert_eq!(aligned_in_range(&a.0), Some(code_in_range(&a.0)));
            }
        }
        let a = Aligned([-127; 16]);
        assert_eq!(aligned_in_range(&a.0[1..13]), None);
        assert_eq!(aligned_in_range(&a.0[..14]), None);
        assert_eq!(aligned_in_range(&a.0[4..12]), Some(true));
    }
}
